"""Real processes on 127.0.0.1: a router, two services, tap, list, signals, bad input."""

from __future__ import annotations

import json
import math
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import msgspec
import pytest
import zenoh

from capsd import topics
from capsd.bus import open_session
from capsd.codec import Codec
from capsd.config import BusConfig
from capsd.health import query_health
from capsd.keys import is_concrete
from capsd.latency import percentile_ms
from capsd.payloads import Health, LatencyStats, Log, RovFix, SonarDetections
from tests.conftest import REPO, Proc, capsd_json_lines, joined, relay, wait_for

pytestmark = pytest.mark.integration


def _health(session: zenoh.Session, vehicle: str, service: str) -> Health | None:
    return query_health(session, site="tank", vehicle=vehicle, service=service, timeout_s=1.0)


def test_router_two_services_tap_list_and_sigterm(
    spawn: Callable[..., Proc], router: Proc, endpoint: str, tmp_path: Path
) -> None:
    # The simulator's truth-plus-noise pose and detections on: they go to its own sim/ keys.
    sim_config = tmp_path / "sim.yaml"
    sim_config.write_text(
        Path("deploy/config/sim.yaml")
        .read_text()
        .replace('truth_noise: "off"', 'truth_noise: "on"')
    )
    sim = spawn("run", "sim", "--config", str(sim_config), "--connect", endpoint)
    locator = spawn(
        "run", "locator", "--config", "deploy/config/locator.yaml", "--connect", endpoint
    )
    with joined(BusConfig(connect=(endpoint,))) as session:
        fixes_seen: list[object] = []
        fix_sub = session.declare_subscriber(
            topics.ROV_FIX.key("tank", "topside"), lambda sample: fixes_seen.append(sample)
        )

        def sim_stand_ins_counted() -> bool:
            health = _health(session, "sim", "sim")
            return health is not None and health.counters.get("sim/detections@sim:count", 0) > 20

        wait_for(sim_stand_ins_counted, timeout_s=20, what="the simulator's stand-in detections")
        locator_health = _health(session, "topside", "locator")
        assert locator_health is not None
        # Truth reaches no service: the locator saw none of it, so it has no fix.
        assert sum(s.count for s in locator_health.inputs if "detections" in s.key) == 0
        assert fixes_seen == []
        fix_sub.undeclare()
        # The test plays asv_pose and sonar_detect with them, in the open.
        relays = [
            relay(
                session, topics.SIM_ASV_POSE.key("tank", "sim"), topics.ASV_POSE.key("tank", "asv")
            ),
            relay(
                session,
                topics.SIM_DETECTIONS.key("tank", "sim"),
                topics.SONAR_DETECTIONS.key("tank", "asv"),
            ),
        ]
        _fixes_tapped_and_listed(spawn, endpoint)
        for sub in relays:
            sub.undeclare()
    for proc in (sim, locator, router):
        code, seconds = proc.terminate()
        assert code == 0, proc.output()
        assert seconds < 2.0, f"{proc.args} took {seconds:.2f} s to stop"


def _fixes_tapped_and_listed(spawn: Callable[..., Proc], endpoint: str) -> None:
    # A payload crosses: sim -> detections -> locator -> fix; tap prints it decoded.
    tap = spawn(
        "tap",
        "cap/tank/topside/locator/fix",
        "--connect",
        endpoint,
        "--count",
        "10",
        "--duration",
        "30",
    )
    assert tap.popen.wait(timeout=40) == 0
    lines = capsd_json_lines(tap.output())
    # The first pings may come before two samples of every input (causal matching needs two).
    assert len(lines) == 10
    assert {line["schema"] for line in lines} == {"RovFix"}
    fixes = [msgspec.convert(line["payload"], RovFix) for line in lines]
    assert any(fix.quality == "good" and fix.raw_position_m is not None for fix in fixes)

    listing = subprocess.run(
        [sys.executable, "-m", "capsd", "list", "--json", "--connect", endpoint],
        capture_output=True,
        text=True,
        timeout=30,
        cwd=REPO,
        check=True,
    )
    rows = [json.loads(line) for line in listing.stdout.splitlines()]
    services = {(row["vehicle"], row["service"]): row for row in rows}
    assert ("sim", "sim") in services
    assert ("topside", "locator") in services
    # The real-time simulator publishes every stream (its Health counts each one).
    sim_counters = services[("sim", "sim")]["health"]["counters"]
    for stream in (
        "sonar/frame@asv",
        "asv/imu@asv",
        "asv/scan@asv",
        "rov/depth@rov",
        "rov/attitude@rov",
        "sim/label@sim",
        "sim/truth@sim",
        "sim/asv_pose@sim",
        "sim/detections@sim",
    ):
        assert sim_counters.get(f"{stream}:count", 0) > 0, stream
    locator_health = services[("topside", "locator")]["health"]
    assert locator_health["state"] == "ok"
    assert sum(s["count"] for s in locator_health["inputs"]) > 0
    # Every input's transport and the locator's own stage are timed (put time attachment).
    latencies = {
        stats["name"]: msgspec.convert(stats, LatencyStats, strict=False)
        for stats in locator_health["latencies"]
    }
    for name in ("transport sonar/detections", "transport asv/pose", "fix"):
        assert latencies[name].count > 0, name
        median = percentile_ms(latencies[name], 50)
        assert median is not None, name
        assert 0.0 < median < 500.0, (name, median)

    human = subprocess.run(
        [sys.executable, "-m", "capsd", "list", "--connect", endpoint],
        capture_output=True,
        text=True,
        timeout=30,
        cwd=REPO,
        check=True,
    )
    assert "locator" in human.stdout
    assert "sim" in human.stdout


def test_bad_input_is_counted_and_dropped_while_serving(
    spawn: Callable[..., Proc], client: zenoh.Session, endpoint: str
) -> None:
    locator = spawn(
        "run", "locator", "--config", "deploy/config/locator.yaml", "--connect", endpoint
    )
    key = topics.SONAR_DETECTIONS.key("tank", "asv")
    wait_for(
        lambda: _health(client, "topside", "locator") is not None,
        timeout_s=15,
        what="locator health",
    )

    fixes: list[RovFix] = []
    codec = Codec(RovFix)

    def on_fix(sample: zenoh.Sample) -> None:
        if is_concrete(str(sample.key_expr)):  # `cap/**` below reaches this test's input too
            fixes.append(
                codec.decode(
                    sample.payload.to_bytes(),
                    encoding=str(sample.encoding),
                    key_expr=str(sample.key_expr),
                )
            )

    sub = client.declare_subscriber(topics.ROV_FIX.key("tank", "topside"), on_fix)
    good = Codec(SonarDetections).encode(
        SonarDetections(stamp_ns=time.time_ns(), seq=0, ping_id=0, detector="test")
    )
    json_enc = zenoh.Encoding("application/json;SonarDetections")
    bad_inputs: list[tuple[str, bytes]] = [
        (key, b"\x00\x01garbage"),  # garbage bytes
        (key, b'{"stamp_ns": "now", "seq": 0, "ping_id": 0, "detector": "x"}'),  # wrong type
        (
            key,
            b'{"stamp_ns": 1, "seq": 0, "ping_id": 0, "detector": "x", "detections": '
            b'[{"range_m": NaN, "azimuth_rad": 0, "range_sigma_m": 0, '
            b'"azimuth_sigma_rad": 0, "confidence": 1}]}',
        ),  # NaN where forbidden
        (
            key,
            b'{"stamp_ns": 1, "seq": 0, "ping_id": 0, "detector": "x", "detections": '
            b'[{"range_m": 1e999, "azimuth_rad": 0, "range_sigma_m": 0, '
            b'"azimuth_sigma_rad": 0, "confidence": 1}]}',
        ),  # infinity where forbidden
        ("cap/tank/*/sonar/detections", good),  # wildcard key: refused even if well formed
        ("cap/**", good),
    ]

    # A good input first, again until it is answered: its fix proves the route to the
    # locator's input stands (a put before the route is up is lost, and then a bad one would
    # go uncounted; health answering does not prove that route: this failed twice so).
    def good_answered() -> bool:
        client.put(key, good, encoding=json_enc)
        time.sleep(0.5)
        return len(fixes) >= 1

    wait_for(good_answered, timeout_s=15, what="a fix for the good input")
    time.sleep(0.5)
    answered = len(fixes)
    # No pose or depth yet: the locator answers honestly that it cannot fix.
    assert fixes[0].quality == "invalid"
    assert fixes[0].no_fix_reason is not None

    for bad_key, data in bad_inputs:
        client.put(bad_key, data, encoding=json_enc)
    time.sleep(0.5)
    assert len(fixes) == answered, "no bad input may produce an output"

    def detection_errors() -> int:
        health = _health(client, "topside", "locator")
        assert health is not None
        return next(s.errors for s in health.inputs if s.key == key)

    wait_for(
        lambda: detection_errors() == len(bad_inputs),
        timeout_s=5,
        what="decode errors counted in health",
    )
    # `cap/**` also reached every other input (pose, depth, ...), and was refused there too.

    health = _health(client, "topside", "locator")
    assert health is not None
    assert health.state == "ok"
    assert health.decode_errors == len(bad_inputs) + len(health.inputs) - 1
    assert health.last_error is not None
    assert "wildcard" in locator.output()
    assert locator.popen.poll() is None, "the service must keep running"
    sub.undeclare()
    assert locator.terminate()[0] == 0


def test_bad_config_exits_non_zero_naming_file_and_key(tmp_path: Path) -> None:
    bad = tmp_path / "locator.yaml"
    bad.write_text("site: tank\nsonar:\n  pitch_deg: 30\n  beam_modle: conical\n")
    result = subprocess.run(
        [sys.executable, "-m", "capsd", "run", "locator", "--config", str(bad)],
        capture_output=True,
        text=True,
        timeout=30,
        cwd=REPO,
    )
    assert result.returncode == 2
    assert f"{bad}:4" in result.stderr
    assert "sonar.beam_modle" in result.stderr

    out_of_range = tmp_path / "range.yaml"
    out_of_range.write_text("max_conditioning: -1\n")
    result = subprocess.run(
        [sys.executable, "-m", "capsd", "run", "locator", "--config", str(out_of_range)],
        capture_output=True,
        text=True,
        timeout=30,
        cwd=REPO,
    )
    assert result.returncode == 2
    assert "max_conditioning" in result.stderr

    bad_flag = subprocess.run(
        [sys.executable, "-m", "capsd", "run", "locator", "--connect", "localhost"],
        capture_output=True,
        text=True,
        timeout=30,
        cwd=REPO,
    )
    assert bad_flag.returncode == 2
    assert "not a Zenoh endpoint" in bad_flag.stderr


def test_sd_notify_and_bus_logs_from_a_real_service(
    spawn: Callable[..., Proc], client: zenoh.Session, endpoint: str, tmp_path: Path
) -> None:
    notify_path = tmp_path / "notify.sock"
    messages: list[str] = []
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as server:
        server.bind(str(notify_path))
        server.settimeout(0.2)
        stop = threading.Event()

        def listen() -> None:
            while not stop.is_set():
                try:
                    messages.append(server.recv(4096).decode())
                except TimeoutError:
                    continue

        thread = threading.Thread(target=listen, daemon=True)
        thread.start()
        logs: list[Log] = []
        log_codec = Codec(Log)
        sub = client.declare_subscriber(
            "services/*/log",
            lambda s: logs.append(
                log_codec.decode(
                    s.payload.to_bytes(), encoding=str(s.encoding), key_expr=str(s.key_expr)
                )
            ),
        )
        proc = spawn(
            "run",
            "locator",
            "--connect",
            endpoint,
            env={"NOTIFY_SOCKET": str(notify_path), "WATCHDOG_USEC": "1000000"},
        )
        wait_for(lambda: any("READY=1" in m for m in messages), timeout_s=15, what="READY=1")
        wait_for(lambda: any("WATCHDOG=1" in m for m in messages), timeout_s=5, what="WATCHDOG=1")
        code, seconds = proc.terminate()
        assert code == 0
        assert seconds < 2.0
        wait_for(lambda: any("STOPPING=1" in m for m in messages), timeout_s=2, what="STOPPING=1")
        stop.set()
        thread.join()
        sub.undeclare()
    stop_logs = [log for log in logs if log.message.startswith("stop requested")]
    assert stop_logs, [log.message for log in logs]
    assert stop_logs[0].name == "locator"
    assert stop_logs[0].level == 2


def test_service_waits_for_a_late_router(spawn: Callable[..., Proc], endpoint: str) -> None:
    locator = spawn("run", "locator", "--connect", endpoint)
    wait_for(
        lambda: "waiting for Zenoh router" in locator.output(),
        timeout_s=15,
        what="the waiting message",
    )
    assert locator.popen.poll() is None
    spawn("router", "--listen", endpoint)
    wait_for(lambda: "service started" in locator.output(), timeout_s=15, what="late join")
    assert locator.terminate()[0] == 0


def test_help_on_every_command() -> None:
    for args in (
        ["--help"],
        ["run", "--help"],
        ["router", "--help"],
        ["tap", "--help"],
        ["list", "--help"],
    ):
        result = subprocess.run(
            [sys.executable, "-m", "capsd", *args],
            capture_output=True,
            text=True,
            timeout=30,
            cwd=REPO,
        )
        assert result.returncode == 0, args
        assert "usage: capsd" in result.stdout


def test_services_rejoin_a_restarted_router(
    spawn: Callable[..., Proc], router: Proc, endpoint: str
) -> None:
    locator = spawn("run", "locator", "--connect", endpoint)
    with open_session(BusConfig(connect=(endpoint,))) as session:
        wait_for(
            lambda: _health(session, "topside", "locator") is not None,
            timeout_s=15,
            what="locator health",
        )
    assert router.terminate()[0] == 0
    spawn("router", "--listen", endpoint)
    start = time.monotonic()
    with open_session(BusConfig(connect=(endpoint,), connect_timeout_s=5.0)) as session:
        wait_for(
            lambda: _health(session, "topside", "locator") is not None,
            timeout_s=10,
            what="locator back after the router restart",
        )
    assert time.monotonic() - start < 5.0
    assert locator.popen.poll() is None


def test_two_publishers_on_one_input_are_flagged(
    spawn: Callable[..., Proc], client: zenoh.Session, endpoint: str
) -> None:
    from capsd.payloads import RovDepth

    spawn("run", "locator", "--connect", endpoint)
    wait_for(
        lambda: _health(client, "topside", "locator") is not None,
        timeout_s=15,
        what="locator health",
    )
    codec = Codec(RovDepth)
    key = topics.ROV_DEPTH.key("tank", "rov")
    encoding = zenoh.Encoding(codec.encoding)
    # Two sources of "the ROV's depth", each with its own seq from 0: a real mix-up.
    for i in range(40):
        for depth in (1.0, 2.4):
            client.put(
                key,
                codec.encode(RovDepth(stamp_ns=time.time_ns(), seq=i, depth_m=depth)),
                encoding=encoding,
            )
        time.sleep(0.05)

    def flagged() -> bool:
        health = _health(client, "topside", "locator")
        return (
            health is not None
            and health.state == "degraded"
            and (health.last_error is not None and "more than one publisher" in health.last_error)
        )

    wait_for(flagged, timeout_s=5, what="the shared input flagged")
    health = _health(client, "topside", "locator")
    assert health is not None
    depth_input = next(s for s in health.inputs if s.key == key)
    assert depth_input.seq_regressions >= 30


@pytest.mark.parametrize(("skew_ms", "words"), [(500, "ahead of this computer"), (-800, "after")])
def test_skewed_input_stamps_are_flagged(
    spawn: Callable[..., Proc], client: zenoh.Session, endpoint: str, skew_ms: int, words: str
) -> None:
    from capsd.payloads import RovDepth

    spawn("run", "locator", "--connect", endpoint)
    wait_for(
        lambda: _health(client, "topside", "locator") is not None,
        timeout_s=15,
        what="locator health",
    )
    codec = Codec(RovDepth)
    key = topics.ROV_DEPTH.key("tank", "rov")
    # The ROV's clock runs `skew_ms` ahead of the locator's (negative: behind).
    for i in range(30):
        stamp = time.time_ns() + skew_ms * 1_000_000
        client.put(
            key,
            codec.encode(RovDepth(stamp_ns=stamp, seq=i, depth_m=1.0)),
            encoding=zenoh.Encoding(codec.encoding),
        )
        time.sleep(0.02)

    def flagged() -> bool:
        health = _health(client, "topside", "locator")
        return (
            health is not None
            and health.state == "degraded"
            and health.last_error is not None
            and key in health.last_error
            and words in health.last_error
        )

    wait_for(flagged, timeout_s=5, what="the skewed input flagged")
    health = _health(client, "topside", "locator")
    assert health is not None
    age = next(s.age_ms for s in health.inputs if s.key == key)
    assert age is not None
    assert abs(age + skew_ms) < 100


def test_asv_pose_service_tracks_the_simulated_asv(
    spawn: Callable[..., Proc], client: zenoh.Session, endpoint: str, tmp_path: Path
) -> None:
    from capsd.payloads import AsvPose, GroundTruth

    sim_config = tmp_path / "sim.yaml"
    sim_config.write_text(
        f"bus: {{connect: [{endpoint}]}}\nasv_mode: stationary\nasv_start_xy: [14.0, 8.0]\n"
        "streams: {sonar_frames: 'off', asv_pose_truth_noise: 'off', "
        "detections_truth_noise: 'off'}\n"
    )
    pose_config = tmp_path / "asv_pose.yaml"
    # Stationary at the tank centre; the ASV faces the ROV's start (the heading prior).
    from capsd.simulator.config import Config as SimConfig
    from capsd.simulator.sim import Simulation

    start = Simulation(
        msgspec.convert({"asv_mode": "stationary", "asv_start_xy": [14.0, 8.0]}, SimConfig),
        horizon_s=5,
    ).asv_pose(0.0)
    from capsd.geometry import matrix_to_euler_zyx

    yaw_deg = math.degrees(matrix_to_euler_zyx(start.rotation)[0])
    pose_config.write_text(
        f"bus: {{connect: [{endpoint}]}}\n"
        f"heading_prior_deg: {yaw_deg + 20.0:.2f}\n"  # no position: the global search finds it
    )
    poses: list[AsvPose] = []
    truths: list[GroundTruth] = []
    pose_codec, truth_codec = Codec(AsvPose), Codec(GroundTruth)
    subs = [
        client.declare_subscriber(
            topics.ASV_POSE.key("tank", "asv"),
            lambda s: poses.append(
                pose_codec.decode(s.payload.to_bytes(), encoding=str(s.encoding), key_expr="p")
            ),
        ),
        client.declare_subscriber(
            topics.SIM_TRUTH.key("tank", "sim"),
            lambda s: truths.append(
                truth_codec.decode(s.payload.to_bytes(), encoding=str(s.encoding), key_expr="t")
            ),
        ),
    ]
    spawn("run", "sim", "--config", str(sim_config))
    spawn("run", "asv_pose", "--config", str(pose_config))
    wait_for(lambda: len(poses) > 600 and len(truths) > 40, timeout_s=30, what="poses and truth")
    last = poses[-1]
    assert last.status == "ok"
    assert last.source == "scan_match"
    truth = min(truths, key=lambda t: abs(t.stamp_ns - last.stamp_ns))
    assert abs(truth.stamp_ns - last.stamp_ns) < 60_000_000
    assert math.dist(last.position_m[:2], truth.asv_position_m[:2]) < 0.05
    for sub in subs:
        sub.undeclare()
