"""Record the bus into MCAP, read it with the mcap reader, replay it into a fresh locator."""

from __future__ import annotations

import math
import subprocess
import sys
import threading
from collections.abc import Callable
from pathlib import Path

import msgspec
import pytest
import zenoh
from mcap.reader import make_reader

from capsd import topics
from capsd.codec import Codec
from capsd.errors import CapsdError
from capsd.keys import is_concrete
from capsd.payloads import RovFix
from capsd.recording import channel_counts, read
from tests.conftest import REPO, Proc, wait_for

pytestmark = pytest.mark.integration
FIX_KEY = topics.ROV_FIX.key("tank", "topside")


def _capsd(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "capsd", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=REPO,
    )


def test_record_then_replay_into_a_fresh_locator_gives_the_same_fixes(
    spawn: Callable[..., Proc], router: Proc, endpoint: str, client: zenoh.Session, tmp_path: Path
) -> None:
    sim = spawn("run", "sim", "--config", "deploy/config/sim.yaml", "--connect", endpoint)
    locator = spawn(
        "run", "locator", "--config", "deploy/config/locator.yaml", "--connect", endpoint
    )
    got: list[RovFix] = []
    codec = Codec(RovFix)
    lock = threading.Lock()

    def on_fix(sample: zenoh.Sample) -> None:
        if is_concrete(str(sample.key_expr)):
            fix = codec.decode(
                sample.payload.to_bytes(),
                encoding=str(sample.encoding),
                key_expr=str(sample.key_expr),
            )
            with lock:
                got.append(fix)

    sub = client.declare_subscriber(FIX_KEY, on_fix)
    wait_for(lambda: len(got) > 5, timeout_s=30, what="fixes before recording")
    mcap_file = tmp_path / "run.mcap"
    # Everything but the sonar images (big, and the locator does not read them).
    rec = _capsd(
        "record", "cap/tank/**", "-o", str(mcap_file), "--duration", "6", "--connect", endpoint
    )
    assert rec.returncode == 0, rec.stderr
    sim.terminate()
    locator.terminate()

    # The file opens with the mcap reader; every channel has its JSON schema.
    with mcap_file.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    schemas = {s.name: s.encoding for s in summary.schemas.values()}
    assert schemas["RovFix"] == "jsonschema"
    counts = channel_counts(mcap_file)
    assert counts[FIX_KEY] >= 60  # 6 s at 20 Hz, less start-up
    info = _capsd("replay", str(mcap_file), "--info")
    assert info.returncode == 0
    assert FIX_KEY in info.stdout

    recorded = {
        f.stamp_ns: f
        for f in (
            msgspec.json.decode(r.data, type=RovFix) for r in read(mcap_file) if r.key == FIX_KEY
        )
    }
    with lock:
        got.clear()
    fresh = spawn("run", "locator", "--config", "deploy/config/locator.yaml", "--connect", endpoint)
    wait_for(
        lambda: _capsd("list", "--connect", endpoint).stdout.count("locator") >= 1,
        timeout_s=20,
        what="the fresh locator",
    )
    rep = _capsd(
        "replay",
        str(mcap_file),
        "--exclude",
        FIX_KEY,
        "--exclude",
        "cap/*/*/health/*",
        "--speed",
        "2",
        "--connect",
        endpoint,
        timeout=60,
    )
    assert rep.returncode == 0, rep.stderr
    wait_for(lambda: len(got) >= 0.9 * len(recorded), timeout_s=10, what="replayed fixes")
    with lock:
        replayed = {f.stamp_ns: f for f in got}
    common = [s for s in recorded if s in replayed]
    assert len(common) >= 0.9 * len(recorded)
    # Same inputs: the replay carries every recorded input, so the fresh locator uses the very
    # same samples (its fixes name their stamps). Same outputs: exactly, where the input arrived
    # in the same order as live; within the pose noise where the live locator had to
    # extrapolate an input that, replayed, arrived before the ping was solved (arrival order
    # on a live bus is not part of the recording). The first pings warm the fresh buffers up.
    settled = sorted(common)[10:]
    same_inputs = same_quality = exact = 0
    diffs = []
    for stamp in settled:
        a, b = recorded[stamp], replayed[stamp]
        if (a.asv_pose_stamp_ns, a.depth_stamp_ns) == (b.asv_pose_stamp_ns, b.depth_stamp_ns):
            same_inputs += 1
        same_quality += a.quality == b.quality
        if a.raw_position_m and b.raw_position_m:
            d = math.dist(a.raw_position_m, b.raw_position_m)
            diffs.append(d)
            exact += d < 1e-6
    assert same_inputs >= 0.95 * len(settled)
    assert same_quality >= 0.95 * len(settled)
    diffs.sort()
    assert exact >= 0.5 * len(diffs)
    assert diffs[len(diffs) // 2] < 0.01
    assert diffs[-1] < 0.1
    fresh.terminate()
    sub.undeclare()


def test_bad_recordings_are_named(tmp_path: Path) -> None:
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file" * 10)
    with pytest.raises(CapsdError, match=r"junk\.mcap: not a readable MCAP"):
        channel_counts(junk)
    proc = _capsd("replay", str(tmp_path / "missing.mcap"))
    assert proc.returncode == 2
    assert "no such recording" in proc.stderr
