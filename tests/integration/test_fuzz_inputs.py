"""Fuzzed payloads on every input of every service (real processes): counted, never a crash."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgspec
import pytest
import zenoh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from capsd import topics
from capsd.codec import Codec
from capsd.health import query_health
from capsd.payloads import Payload
from capsd.signing import SiteKey, write_key
from capsd.topics import Topic
from tests.capsd.samples import SAMPLES
from tests.conftest import REPO, Proc, wait_for

pytestmark = pytest.mark.integration

CASES_PER_INPUT = 300
# service -> (vehicle, config, its inputs as (topic, publishing vehicle))
SERVICES: dict[str, tuple[str, str, tuple[tuple[Topic[Any], str], ...]]] = {
    "asv_pose": (
        "asv",
        "deploy/config/asv_pose.yaml",
        ((topics.ASV_IMU, "asv"), (topics.ASV_SCAN, "asv")),
    ),
    "sonar_detect": ("asv", "deploy/config/sonar_detect.yaml", ((topics.SONAR_FRAME, "asv"),)),
    "locator": (
        "topside",
        "deploy/config/locator.yaml",
        (
            (topics.ASV_POSE, "asv"),
            (topics.ROV_DEPTH, "rov"),
            (topics.ROV_ATTITUDE, "rov"),
            (topics.ROV_VELOCITY, "rov"),
            (topics.SONAR_DETECTIONS, "asv"),
        ),
    ),
    "mav_bridge": ("rov", "deploy/config/mav_bridge.yaml", ((topics.ROV_FIX, "topside"),)),
    "sim": ("sim", "deploy/config/sim.yaml", ((topics.SIM_CONTROL, "sim"),)),
}

ODD_VALUES = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=12),
    st.binary(max_size=12),
    st.lists(st.floats(allow_nan=True), max_size=4),
    st.dictionaries(st.text(max_size=4), st.integers(), max_size=2),
)


def _sample_of(payload_type: type[Payload]) -> Payload:
    return next(s for s in SAMPLES if type(s) is payload_type)


def _encode_like(codec: Codec[Any], value: Any) -> bytes:
    if codec.encoding.startswith("application/msgpack"):
        return msgspec.msgpack.encode(value)
    return msgspec.json.encode(value)


@st.composite
def fuzzed(draw: st.DrawFn, codec: Codec[Any], valid: bytes, fields: dict[str, Any]) -> bytes:
    """Random bytes, a valid payload cut, flipped or doubled, or one field made odd."""
    kind = draw(st.sampled_from(["bytes", "truncate", "flip", "double", "field", "drop"]))
    if kind == "bytes":
        return draw(st.binary(max_size=512))
    if kind == "truncate":
        return valid[: draw(st.integers(min_value=0, max_value=max(len(valid) - 1, 0)))]
    if kind == "flip":
        data = bytearray(valid)
        for _ in range(draw(st.integers(min_value=1, max_value=4))):
            i = draw(st.integers(min_value=0, max_value=len(data) - 1))
            data[i] = draw(st.integers(min_value=0, max_value=255))
        return bytes(data)
    if kind == "double":
        return valid + valid
    name = draw(st.sampled_from(sorted(fields)))
    changed = dict(fields)
    if kind == "drop":
        del changed[name]
    else:
        changed[name] = draw(ODD_VALUES)
    try:
        return _encode_like(codec, changed)
    except (TypeError, ValueError, OverflowError):
        return valid[:-1]


def _with_key(config: str, key: Path, tmp_path: Path) -> str:
    """The bridge's example config with this test's fix key in place of the site's."""
    text = (REPO / config).read_text().replace("/etc/capsd/certs/fix.key", str(key))
    out = tmp_path / Path(config).name
    out.write_text(text)
    return str(out)


def test_fuzzed_payloads_on_every_input_never_crash_a_service(
    spawn: Callable[..., Proc], router: Proc, endpoint: str, client: zenoh.Session, tmp_path: Path
) -> None:
    key_path = tmp_path / "fix.key"
    site_key = SiteKey.generate()
    write_key(key_path, site_key)
    configs = {
        name: _with_key(config, key_path, tmp_path) if name == "mav_bridge" else config
        for name, (_, config, _) in SERVICES.items()
    }
    procs = {
        name: spawn("run", name, "--config", configs[name], "--connect", endpoint)
        for name in SERVICES
    }

    def answering(name: str, vehicle: str) -> bool:
        health = query_health(client, site="tank", vehicle=vehicle, service=name, timeout_s=0.5)
        return health is not None

    for name, (vehicle, _, _) in SERVICES.items():
        wait_for(lambda: answering(name, vehicle), timeout_s=30, what=f"{name} answering")  # noqa: B023
    sent = 0
    for name, (_, _, inputs) in SERVICES.items():
        for topic, publisher_vehicle in inputs:
            codec = Codec(topic.payload)
            key = topic.key("tank", publisher_vehicle)
            sample = _sample_of(topic.payload)
            valid = codec.encode(sample)
            fields = msgspec.to_builtins(sample)
            publisher = client.declare_publisher(key, encoding=zenoh.Encoding(codec.encoding))
            # Fixes are signed, as the locator's are: the fuzz reaches the decoder behind the
            # bridge's authentication (unsigned ones are refused before it: another test).
            signer = site_key if topic is topics.ROV_FIX else None

            @settings(
                max_examples=CASES_PER_INPUT,
                database=None,
                deadline=None,
                derandomize=True,
                suppress_health_check=list(HealthCheck),
            )
            @given(fuzzed(codec, valid, fields))
            def put_one(data: bytes) -> None:
                # Called right here, before the next loop (noqa: B023 on the loop's names).
                tag = b"" if signer is None else signer.tag(key, data)  # noqa: B023
                stamp = time.time_ns().to_bytes(8, "little")
                publisher.put(data, attachment=stamp + tag)  # noqa: B023

            put_one()
            publisher.undeclare()
            sent += CASES_PER_INPUT
            alive = procs[name].popen.poll() is None
            assert alive, f"{name} died on {key}:\n{procs[name].output()[-4000:]}"
    time.sleep(1.0)
    for name, (vehicle, _, _) in SERVICES.items():
        proc = procs[name]
        assert proc.popen.poll() is None, f"{name} died:\n{proc.output()[-4000:]}"
        health = query_health(client, site="tank", vehicle=vehicle, service=name, timeout_s=2.0)
        assert health is not None, name
        assert health.decode_errors > 0, name  # the bad ones were counted, not swallowed
        assert health.state != "error", (name, health.last_error)
    for proc in procs.values():
        code, _ = proc.terminate()
        assert code == 0, proc.output()[-4000:]
    assert sent == CASES_PER_INPUT * sum(len(inputs) for _, _, inputs in SERVICES.values())
