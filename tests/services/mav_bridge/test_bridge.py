"""The bridge process against an ArduSub stand-in on loopback TCP, with a real router."""

from __future__ import annotations

import math
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TypeVar

import numpy as np
import pytest
import yaml
import zenoh

from capsd import topics
from capsd.bench.footprint import _heavy_mapped
from capsd.bus import open_session
from capsd.codec import Codec
from capsd.config import BusConfig
from capsd.geometry import matrix_to_quat
from capsd.health import query_health
from capsd.keys import is_concrete
from capsd.mounts import SonarPanConfig, SonarTiltConfig
from capsd.ned import TankToNed
from capsd.payloads import (
    AsvPose,
    AutopilotStatus,
    Health,
    Payload,
    RovAttitude,
    RovDepth,
    RovFix,
    SonarTilt,
    VehicleCommand,
)
from capsd.signing import SiteKey, write_key
from capsd.simulator.autopilot import (
    CONFIGURED_PARAMS,
    ROVER_CONFIGURED_PARAMS,
    ROVER_DEFAULT_PARAMS,
    AutopilotStandIn,
    VehicleState,
)
from capsd.simulator.guided import AsvLimits
from capsd.simulator.tilt_servo import TiltServo
from tests.conftest import REPO, Proc, free_port, wait_for

P = TypeVar("P", bound=Payload)

pytestmark = pytest.mark.integration

STATE = VehicleState(roll=0.05, pitch=-0.1, yaw=1.0, depth_m=2.5)
COV_W = np.array([[0.010, 0.002, 0.0], [0.002, 0.020, 0.0], [0.0, 0.0, 0.030]])


@pytest.fixture
def autopilot() -> Iterator[AutopilotStandIn]:
    with AutopilotStandIn(
        free_port(), state=lambda _t: STATE, params=CONFIGURED_PARAMS
    ) as stand_in:
        yield stand_in


def _start_bridge(
    spawn: Callable[..., Proc],
    tmp_path: Path,
    endpoint: str,
    autopilot: AutopilotStandIn,
    *,
    heading_deg: float,
    output: str = "vision_position_estimate",
) -> Proc:
    config = tmp_path / "mav_bridge.yaml"
    config.write_text(
        f"site: tank\nvehicle: rov\nbus:\n  connect: [{endpoint}]\n"
        f"fix_key: {_key_path(tmp_path)}\n"
        "tank:\n  length_m: 28.0\n  width_m: 16.0\n  depth_m: 8.0\n"
        f"mavlink:\n  connect: tcp:127.0.0.1:{autopilot.port}\n"
        f"ned:\n  heading_deg: {heading_deg}\n  origin_ned_m: [10.0, -5.0, 0.0]\n"
        "ekf_origin:\n  lat_deg: 54.42\n  lon_deg: -3.5\n  alt_m: 0.0\n"
        f"output: {output}\n"
    )
    return spawn("run", "mav_bridge", "--config", str(config))


def _assert_told_and_degraded(
    autopilot: AutopilotStandIn, client: zenoh.Session, *, told: str, reason: str
) -> None:
    """The pilot got a STATUSTEXT containing `told`; the bridge's health names `reason`."""
    wait_for(
        lambda: any(told in s.text for s in autopilot.recorded.statustexts),
        timeout_s=15,
        what=f"the pilot told '{told}'",
    )
    health = _health(client)
    assert health.state == "degraded"
    assert reason in (health.state_reason or "")


def _key_path(tmp_path: Path) -> Path:
    """The site's fix key for this test (made once, owner-only)."""
    path = tmp_path / "fix.key"
    if not path.exists():
        write_key(path, SiteKey.generate())
    return path


class FixSender:
    """Publishes RovFix payloads like the locator does: tagged with `key` (None: unsigned)."""

    def __init__(self, session: zenoh.Session, key: SiteKey | None):
        self.key = key
        self.key_expr = topics.ROV_FIX.key("tank", "topside")
        self.codec = Codec(RovFix)
        self.publisher = session.declare_publisher(
            topics.ROV_FIX.key("tank", "topside"), encoding=zenoh.Encoding(self.codec.encoding)
        )
        self.seq = 0

    def send(
        self,
        *,
        stamp_ns: int | None = None,
        position: tuple[float, float, float] = (1.0, 2.0, -3.0),
        cov: np.ndarray = COV_W,
        quality: str = "good",
        resets: int = 3,
    ) -> RovFix:
        fix = RovFix(
            stamp_ns=time.time_ns() if stamp_ns is None else stamp_ns,
            seq=self.seq,
            method="capsd",
            quality=quality,  # type: ignore[arg-type]
            position_m=position,
            velocity_m_s=(0.0, 0.0, 0.0),
            covariance_m2=tuple(float(v) for v in cov.ravel()),
            track_state="tracking",
            track_resets=resets,
        )
        self.seq += 1
        self.put_bytes(self.codec.encode(fix))
        return fix

    def put_bytes(self, data: bytes) -> None:
        attachment = time.time_ns().to_bytes(8, "little")
        if self.key is not None:
            attachment += self.key.tag(self.key_expr, data)
        self.publisher.put(data, attachment=attachment)


def _wait_ready(autopilot: AutopilotStandIn, sender: FixSender) -> None:
    """Until the bridge has a link and an attitude, estimates are (correctly) held back."""

    def one_through() -> bool:
        sender.send()
        time.sleep(0.05)
        return len(autopilot.recorded.estimates) > 0

    wait_for(one_through, timeout_s=20, what="the first estimate at the autopilot")


def _health(client: zenoh.Session) -> Health:
    # A query is best effort: on a loaded machine one reply can miss its 2 s; three in a row
    # cannot.
    for _ in range(3):
        health = query_health(client, site="tank", vehicle="rov", service="mav_bridge")
        if health is not None:
            return health
    raise AssertionError("no health from the mav_bridge (3 queries)")


@pytest.mark.parametrize("heading_deg", [0.0, 90.0, -135.0])
def test_estimates_arrive_with_exact_fields(
    spawn: Callable[..., Proc],
    client: zenoh.Session,
    endpoint: str,
    tmp_path: Path,
    autopilot: AutopilotStandIn,
    heading_deg: float,
) -> None:
    _start_bridge(spawn, tmp_path, endpoint, autopilot, heading_deg=heading_deg)
    sender = FixSender(client, SiteKey.load(_key_path(tmp_path), config_key="fix_key"))
    _wait_ready(autopilot, sender)
    before = len(autopilot.recorded.estimates)
    sent = []
    for k in range(15):
        sent.append(sender.send(position=(1.0 + 0.1 * k, 2.0, -3.0), resets=4))
        time.sleep(0.05)
    wait_for(
        lambda: len(autopilot.recorded.estimates) >= before + 15, timeout_s=5, what="15 estimates"
    )
    got = [e for _, e in autopilot.recorded.estimates[before:]]
    ned = TankToNed(math.radians(heading_deg), np.array([10.0, -5.0, 0.0]))
    by_usec = {fix.stamp_ns // 1000: fix for fix in sent}
    cov_ned = ned.covariance(COV_W)
    for estimate in got:
        fix = by_usec[estimate.usec]  # usec is the estimate's measurement time
        assert fix.position_m is not None
        expected = ned.position(np.array(fix.position_m))
        assert (estimate.x, estimate.y, estimate.z) == pytest.approx(tuple(expected), abs=1e-5)
        assert (estimate.roll, estimate.pitch, estimate.yaw) == pytest.approx(
            (STATE.roll, STATE.pitch, STATE.yaw), abs=1e-6
        )
        cov = estimate.covariance
        assert [cov[0], cov[1], cov[2], cov[6], cov[7], cov[11]] == pytest.approx(
            [
                cov_ned[0, 0],
                cov_ned[0, 1],
                cov_ned[0, 2],
                cov_ned[1, 1],
                cov_ned[1, 2],
                cov_ned[2, 2],
            ],
            abs=1e-7,
        )
        assert cov[15] == pytest.approx(math.radians(3.0) ** 2, rel=1e-5)
        assert estimate.reset_counter == 4
    usecs = [e.usec for e in got]
    assert usecs == sorted(usecs)
    assert len(set(usecs)) == len(usecs)
    wait_for(lambda: autopilot.origin is not None, timeout_s=10, what="the EKF origin taken")
    origin = autopilot.recorded.origins[-1]
    assert (origin.lat_e7, origin.lon_e7) == (544_200_000, -35_000_000)


def test_gate_rate_limit_and_silence(
    spawn: Callable[..., Proc],
    client: zenoh.Session,
    endpoint: str,
    tmp_path: Path,
    autopilot: AutopilotStandIn,
) -> None:
    _start_bridge(spawn, tmp_path, endpoint, autopilot, heading_deg=0.0)
    sender = FixSender(client, SiteKey.load(_key_path(tmp_path), config_key="fix_key"))
    _wait_ready(autopilot, sender)

    def count() -> int:
        return len(autopilot.recorded.estimates)

    # Refused: stale, not good, too uncertain (apart: the bridge takes only the newest fix).
    before = count()
    sender.send(stamp_ns=time.time_ns() - 1_000_000_000)
    time.sleep(0.05)
    sender.send(quality="unsure")
    time.sleep(0.05)
    sender.send(cov=np.diag([1.0, 1.0, 1.0]))
    time.sleep(0.5)
    assert count() == before, "stale, unsure or uncertain estimates must never be sent"

    # 200 Hz in, at most 50 Hz out.
    start, before = time.monotonic(), count()
    while time.monotonic() - start < 1.0:
        sender.send()
        time.sleep(0.005)
    time.sleep(0.3)
    arrived = [t for t, _ in autopilot.recorded.estimates[before:]]
    assert 20 <= len(arrived) <= 52
    gaps = np.diff(arrived)
    assert np.median(gaps) >= 0.018

    # Input stops: output stops, and the pilot is told.
    time.sleep(0.3)
    silent_from = count()
    time.sleep(1.5)
    assert count() == silent_from
    wait_for(
        lambda: any("lost" in s.text for s in autopilot.recorded.statustexts),
        timeout_s=5,
        what="a 'position lost' STATUSTEXT",
    )
    assert any("OK" in s.text for s in autopilot.recorded.statustexts)

    counters = _health(client).counters
    for reason in (
        "gate_stale",
        "gate_not_good",
        "gate_uncertain",
        "gate_rate_limited",
        "gate_sent",
    ):
        assert counters.get(reason, 0) >= 1, counters


def test_telemetry_reaches_the_bus(
    spawn: Callable[..., Proc],
    client: zenoh.Session,
    endpoint: str,
    tmp_path: Path,
    autopilot: AutopilotStandIn,
) -> None:
    depths: list[RovDepth] = []
    attitudes: list[RovAttitude] = []
    depth_codec, attitude_codec = Codec(RovDepth), Codec(RovAttitude)

    def on_depth(sample: zenoh.Sample) -> None:
        if is_concrete(str(sample.key_expr)):
            depths.append(
                depth_codec.decode(
                    sample.payload.to_bytes(), encoding=str(sample.encoding), key_expr="d"
                )
            )

    def on_attitude(sample: zenoh.Sample) -> None:
        if is_concrete(str(sample.key_expr)):
            attitudes.append(
                attitude_codec.decode(
                    sample.payload.to_bytes(), encoding=str(sample.encoding), key_expr="a"
                )
            )

    subs = [
        client.declare_subscriber(topics.ROV_DEPTH.key("tank", "rov"), on_depth),
        client.declare_subscriber(topics.ROV_ATTITUDE.key("tank", "rov"), on_attitude),
    ]
    bridge = _start_bridge(spawn, tmp_path, endpoint, autopilot, heading_deg=90.0)
    wait_for(
        lambda: len(depths) >= 10 and len(attitudes) >= 10,
        timeout_s=20,
        what="depth and attitude on the bus",
    )
    # The ROV's Pi install has no torch, scipy or OpenCV: the bridge must not load them.
    assert _heavy_mapped(bridge.popen.pid) == ()
    now = time.time_ns()
    assert depths[-1].depth_m == pytest.approx(STATE.depth_m, abs=1e-3)
    assert depths[-1].pressure_pa == pytest.approx(101_325.0 + 2.5 * 1000.0 * 9.80665, abs=1.0)
    for series in (depths, attitudes):
        stamps = [p.stamp_ns for p in series]
        assert stamps == sorted(stamps)
        assert 0 <= now - stamps[-1] < 500_000_000  # measurement time, mapped from boot time
    ned = TankToNed(math.radians(90.0), np.zeros(3))
    expected = ned.attitude_to_tank(STATE.roll, STATE.pitch, STATE.yaw)
    from capsd.geometry import quat_to_matrix

    assert np.allclose(
        quat_to_matrix(np.array(attitudes[-1].orientation_xyzw)), expected, atol=1e-6
    )
    for sub in subs:
        sub.undeclare()


def test_link_loss_and_return(
    spawn: Callable[..., Proc],
    client: zenoh.Session,
    endpoint: str,
    tmp_path: Path,
    autopilot: AutopilotStandIn,
) -> None:
    bridge = _start_bridge(spawn, tmp_path, endpoint, autopilot, heading_deg=0.0)
    sender = FixSender(client, SiteKey.load(_key_path(tmp_path), config_key="fix_key"))
    _wait_ready(autopilot, sender)
    import threading

    stop = threading.Event()

    def keep_sending() -> None:
        while not stop.is_set():
            sender.send()
            time.sleep(0.05)

    statuses: list[AutopilotStatus] = []
    status_codec = Codec(AutopilotStatus)
    status_sub = client.declare_subscriber(
        topics.ROV_STATUS.key("tank", "rov"),
        lambda s: statuses.append(
            status_codec.decode(s.payload.to_bytes(), encoding=None, key_expr=str(s.key_expr))
        ),
    )
    thread = threading.Thread(target=keep_sending, daemon=True)
    sent_before = _health(client).counters.get("gate_sent", 0)
    arrived_before = len(autopilot.recorded.estimates)
    log_before = bridge.output().count("\n")
    thread.start()
    try:
        autopilot.restart(down_s=2.5)
        back = time.monotonic()
        before = len(autopilot.recorded.estimates)
        wait_for(
            lambda: len(autopilot.recorded.estimates) > before,
            timeout_s=3.0,
            what="estimates after the link returned",
        )
        recovery_s = time.monotonic() - back
    finally:
        stop.set()
        thread.join()
    time.sleep(0.5)
    status_sub.undeclare()
    print(f"link recovery {recovery_s:.2f} s")
    assert recovery_s <= 2.0
    assert bridge.popen.poll() is None, "the bridge recovers without a restart"
    counters = _health(client).counters
    assert counters.get("link_lost", 0) >= 1
    # Nothing counted as sent that did not arrive (but the one written as the link died).
    sent = counters.get("gate_sent", 0) - sent_before
    arrived = len(autopilot.recorded.estimates) - arrived_before
    assert sent - arrived <= 1, (sent, arrived)
    # Over the ~3.5 s: a few lines, not a storm (state changes, link lost, link open).
    logged = bridge.output().count("\n") - log_before
    assert logged <= 15, bridge.output()[-3000:]
    assert "Attempting reconnect" not in bridge.output()  # pymavlink's own chatter
    # The vehicle state was published as unknown while the link was down.
    assert any(st.link == "lost" and st.mode == "unknown" for st in statuses)


def _capsd(*args: str) -> subprocess.CompletedProcess[str]:
    """`capsd ARGS` as a person runs it, from the repository root."""
    return subprocess.run(
        [sys.executable, "-m", "capsd", *args], capture_output=True, text=True, timeout=60, cwd=REPO
    )


def test_mav_check_applies_and_tracks_a_pending_reboot_through_the_autopilot(
    spawn: Callable[..., Proc], client: zenoh.Session, endpoint: str, tmp_path: Path
) -> None:
    """A fresh ArduSub: set up, reboot pending (this run, then seen in the autopilot), rebooted."""
    with AutopilotStandIn(
        free_port(), state=lambda _t: STATE, armed=False, gcs_port=free_port()
    ) as fresh:
        assert fresh.gcs_port is not None

        def check(*extra: str) -> subprocess.CompletedProcess[str]:
            return _capsd(
                "mav", "check", "--connect", f"tcp:127.0.0.1:{fresh.gcs_port}",
                "--bus", endpoint, "--delay-ms", "10", *extra,
            )  # fmt: skip

        first = check()
        assert first.returncode == 1, first.stdout
        assert "CHANGE" in first.stdout
        assert "--apply" in first.stdout
        applied = check("--apply")
        assert applied.returncode == 3, applied.stdout
        pending_line = next(x for x in applied.stdout.splitlines() if "REBOOT PENDING" in x)
        assert "VISO_TYPE" in pending_line
        assert "GPS1_TYPE" in pending_line
        assert fresh.params["VISO_TYPE"] == 1.0
        assert fresh.params["GPS1_TYPE"] == 0.0
        # No estimates arriving yet: the autopilot's state cannot tell, and the check says so.
        unverified = check()
        assert unverified.returncode == 0, unverified.stdout
        assert "not verified" in unverified.stdout
        assert "CHANGE" not in unverified.stdout

        bridge = _start_bridge(spawn, tmp_path, endpoint, fresh, heading_deg=0.0)
        sender = FixSender(client, SiteKey.load(_key_path(tmp_path), config_key="fix_key"))
        stop = threading.Event()

        def send_fixes() -> None:
            while not stop.is_set():
                sender.send(position=(20.0, 0.0, -2.0))
                stop.wait(0.05)

        feeder = threading.Thread(target=send_fixes, daemon=True)
        feeder.start()
        try:
            wait_for(lambda: len(fresh.recorded.estimates) > 10, timeout_s=15, what="estimates")
            # The bridge sees it too: health degraded, the pilot told once.
            _assert_told_and_degraded(
                fresh, client, told="ignores fixes", reason="does not use our estimates"
            )
            # A later run, no memory of the first: estimates arrive, the firmware ignores them.
            pending = check()
            assert pending.returncode == 3, pending.stdout
            assert "estimates are arriving" in pending.stdout
            rebooted = check("--reboot")
            assert rebooted.returncode == 0, rebooted.stdout
            assert fresh.boots == 2
            wait_for(
                lambda: fresh.sys_status().health != 0,
                timeout_s=15,
                what="the rebooted autopilot taking the bridge's estimates",
            )
            done = check()
            assert done.returncode == 0, done.stdout
            assert "External position in use" in done.stdout
            wait_for(
                lambda: _health(client).state == "ok",
                timeout_s=15,
                what="the bridge's health ok once the autopilot uses the estimates",
            )
            told = [t for t in fresh.recorded.statustexts if "ignores fixes" in t.text]
            assert len(told) == 1
        finally:
            stop.set()
            feeder.join(timeout=2)
        assert bridge.popen.poll() is None


def _fresh_ardurover() -> AutopilotStandIn:
    """A disarmed ArduRover stand-in at its defaults, with a ground-station port."""
    return AutopilotStandIn(
        free_port(),
        state=lambda _t: STATE,
        armed=False,
        mode="HOLD",
        autopilot="ardurover",
        params=ROVER_DEFAULT_PARAMS,
        gcs_port=free_port(),
    )


def test_mav_check_for_the_asv_sets_how_ardurover_drives_to_a_station() -> None:
    """A fresh ArduRover stops 2 m short of a GUIDED target: `--role asv` wants it within 0.2 m.

    Found with ArduRover SITL (README): WP_RADIUS 2 left the follower's stations up to 2 m off,
    so the bridge's turn to the station's heading (within 0.3 m) never came.
    """
    with _fresh_ardurover() as rover:

        def check(*extra: str) -> subprocess.CompletedProcess[str]:
            return _capsd(
                "mav", "check", "--connect", f"tcp:127.0.0.1:{rover.gcs_port}", "--role", "asv",
                "--delay-ms", "10", "--bus", "tcp/127.0.0.1:1", *extra,
            )  # fmt: skip

        first = check()
        assert first.returncode == 1, first.stdout
        wrong = {line.split()[0] for line in first.stdout.splitlines() if "CHANGE" in line}
        assert {"WP_RADIUS", "LOIT_RADIUS", "WP_SPEED", "EK3_SRC1_YAW"} <= wrong
        # An ArduSub is not asked about ArduRover's GUIDED.
        assert "WP_RADIUS" not in _capsd(
            "mav", "check", "--connect", f"tcp:127.0.0.1:{rover.gcs_port}",
            "--delay-ms", "10", "--bus", "tcp/127.0.0.1:1",
        ).stdout  # fmt: skip
        applied = check("--apply", "--max-speed-m-s", "0.4")
        assert applied.returncode == 3, applied.stdout  # VISO_TYPE: a reboot is pending
        assert rover.params["WP_RADIUS"] == pytest.approx(0.2)
        assert rover.params["LOIT_RADIUS"] == pytest.approx(0.3)
        assert rover.params["WP_SPEED"] == pytest.approx(0.4)
        assert rover.params["EK3_SRC1_YAW"] == 6.0  # the ASV's own heading, not its compass
        # A smaller radius or speed is as good: "at most".
        rover.params["WP_RADIUS"] = 0.1
        again = check("--max-speed-m-s", "0.4")
        assert "CHANGE" not in again.stdout, again.stdout


def _servo_configs(tmp_path: Path, *, follower_tilt: bool = True) -> tuple[Path, Path]:
    """The shipped ASV bridge and follower configs with the sonar on a tilt servo."""
    bridge = yaml.safe_load((REPO / "deploy/config/asv_bridge.yaml").read_text())
    bridge["sonar_tilt"] = {"zero_pitch_deg": -30.0}
    follow = yaml.safe_load((REPO / "deploy/config/asv_follow.yaml").read_text())
    if follower_tilt:
        follow["sonar"]["tilt"] = {"min_deg": -15.0, "max_deg": 55.0}
    paths = (tmp_path / "asv_bridge.yaml", tmp_path / "asv_follow.yaml")
    for path, config in zip(paths, (bridge, follow), strict=True):
        path.write_text(yaml.safe_dump(config))
    return paths


def test_mav_check_for_the_asv_sets_up_the_sonars_tilt_servo(tmp_path: Path) -> None:
    """A fresh ArduRover has no mount: the check wants a servo mount that allows every angle.

    Zero at -30 deg (MAVLink's pitch, up +), tilts -15..+55 deg down: the mount must reach
    -85 and -15 deg. MNT1_TYPE is read at boot and its MNT1_* listed once set; the output
    the servo is wired to (SERVOn_FUNCTION 7) and the pitch at its pulse limits (the servo's
    calibration) only a person knows: never applied.
    """
    bridge, follow = _servo_configs(tmp_path)
    with _fresh_ardurover() as rover:
        # A fresh ArduRover never answers for the MNT1_* it does not list yet: each check waits
        # out its timeout for them (2 s: loopback; a field link keeps the default 5 s).
        def check(*extra: str) -> subprocess.CompletedProcess[str]:
            return _capsd(
                "mav", "check", "--connect", f"tcp:127.0.0.1:{rover.gcs_port}", "--role", "asv",
                "--delay-ms", "10", "--bus", "tcp/127.0.0.1:1", "--bridge-config", str(bridge),
                "--follow-config", str(follow), "--timeout", "2", *extra,
            )  # fmt: skip

        def status(result: subprocess.CompletedProcess[str], name: str) -> str:
            """The parameter's status in the last table printed (after --apply's, if any)."""
            line = [x for x in result.stdout.splitlines() if x.startswith(name + " ")][-1]
            return "CHANGE" if "CHANGE" in line else "ok"

        first = check()
        assert first.returncode == 1, first.stdout
        assert status(first, "MNT1_TYPE") == "CHANGE"
        assert status(first, "SERVOn_FUNCTION") == "CHANGE"
        assert "SERVOn_FUNCTION by hand" in first.stdout
        applied = check("--apply")
        assert applied.returncode == 1, applied.stdout  # the servo's output: by hand
        assert rover.params["MNT1_TYPE"] == 1.0
        assert "SERVOn_FUNCTION: only a person can set these" in applied.stdout
        assert rover.params["SERVO9_FUNCTION"] == 0.0  # never guessed
        # Listed now, at ArduPilot's defaults (-90..20): 20 > -15 is fine, -90 < -85 too.
        assert status(applied, "MNT1_PITCH_MIN") == "ok", applied.stdout
        rover.params["SERVO9_FUNCTION"] = 7.0
        rover.params["MNT1_PITCH_MIN"] = -60.0  # a servo measured with too little travel
        again = check("--apply")
        assert again.returncode == 1, again.stdout
        assert status(again, "SERVO9_FUNCTION") == "ok", again.stdout  # the one found
        assert status(again, "MNT1_PITCH_MIN") == "CHANGE", again.stdout
        assert rover.params["MNT1_PITCH_MIN"] == -60.0  # its calibration: never applied
        rover.params["MNT1_PITCH_MIN"] = -88.0  # re-measured after moving the linkage
        final = check()
        assert "CHANGE" not in final.stdout, final.stdout
        # Without the bridge's config the mount is not the check's business.
        plain = _capsd(
            "mav", "check", "--connect", f"tcp:127.0.0.1:{rover.gcs_port}", "--role", "asv",
            "--delay-ms", "10", "--bus", "tcp/127.0.0.1:1",
        ).stdout  # fmt: skip
        assert not [x for x in plain.splitlines() if x.startswith(("MNT1_", "SERVO"))], plain


def test_mav_check_refuses_a_servo_the_follower_does_not_know(tmp_path: Path) -> None:
    """The bridge drives a servo and the follower's sonar has no tilt: refused, both named."""
    bridge, follow = _servo_configs(tmp_path, follower_tilt=False)
    result = _capsd("mav", "check", "--connect", "tcp:127.0.0.1:1", "--role", "asv",
                    "--bridge-config", str(bridge), "--follow-config", str(follow))  # fmt: skip
    assert result.returncode == 2, result.stderr
    assert "asv_follow.yaml" in result.stderr
    assert "sonar.tilt" in result.stderr
    alone = _capsd("mav", "check", "--connect", "tcp:127.0.0.1:1", "--role", "asv",
                   "--bridge-config", str(bridge))  # fmt: skip
    assert alone.returncode == 2, alone.stderr
    assert "--follow-config" in alone.stderr
    rov = _capsd("mav", "check", "--connect", "tcp:127.0.0.1:1", "--bridge-config", str(bridge))
    assert rov.returncode == 2, rov.stderr
    assert "--role asv" in rov.stderr


def test_the_simulated_ardurover_is_configured_as_the_check_wants() -> None:
    """The demo's ArduRover stand-in reports (and drives by) what `--role asv --apply` sets."""
    from capsd.services.mav_bridge.check import MountRange, evaluate, rules

    mount = MountRange.of(zero_pitch_deg=-45.0, tilt_min_deg=-15.0, tilt_max_deg=40.0)
    wanted = rules(
        yaw_source="vision",
        position_noise_m=0.05,
        delay_ms=None,
        autopilot="ardurover",
        mount=mount,  # the demo's servo (`capsd demo --sonar-tilt servo`, the mockup's 45 deg)
    )
    assert [f.name for f in evaluate(ROVER_CONFIGURED_PARAMS, wanted) if not f.ok] == []
    assert AsvLimits().arrive_radius_m == ROVER_CONFIGURED_PARAMS["WP_RADIUS"]


def test_mav_check_wants_a_pan_servos_output_and_its_yaw_travel() -> None:
    """A pan of +-90 deg (left +): MNT1_YAW_MIN at most -90, MAX at least 90, an output on 6."""
    from capsd.services.mav_bridge.check import MountRange, evaluate, rules

    mount = MountRange.of(
        zero_pitch_deg=-45.0, tilt_min_deg=-15.0, tilt_max_deg=40.0, pan_deg=(-90.0, 90.0)
    )
    assert mount.yaws_deg == (-90.0, 90.0)

    def failing(params: dict[str, float]) -> list[str]:
        wanted = rules(yaw_source="vision", position_noise_m=0.05, delay_ms=None,
                       autopilot="ardurover", mount=mount)  # fmt: skip
        return [f.name for f in evaluate(params, wanted) if not f.ok]

    assert failing(ROVER_CONFIGURED_PARAMS) == []  # the demo's stand-in (`--sonar-tilt pan-tilt`)
    narrow = ROVER_CONFIGURED_PARAMS | {"MNT1_YAW_MAX": 60.0}  # a linkage with too little travel
    assert failing(narrow) == ["MNT1_YAW_MAX"]
    unwired = ROVER_CONFIGURED_PARAMS | {"SERVO10_FUNCTION": 0.0}
    assert failing(unwired) == ["SERVOn_FUNCTION (pan)"]


def test_mav_check_refuses_a_pan_the_bridge_and_the_follower_disagree_on(tmp_path: Path) -> None:
    """The follower aims a pan the bridge would never send (or the other way): refused."""
    bridge, follow = _servo_configs(tmp_path)
    config = yaml.safe_load(follow.read_text())
    config["sonar"]["pan"] = {}
    follow.write_text(yaml.safe_dump(config))
    result = _capsd("mav", "check", "--connect", "tcp:127.0.0.1:1", "--role", "asv",
                    "--bridge-config", str(bridge), "--follow-config", str(follow))  # fmt: skip
    assert result.returncode == 2, result.stderr
    assert "sonar_tilt.pan" in result.stderr
    assert "asv_bridge.yaml" in result.stderr


def test_gps_input_output_and_requested_rates(
    spawn: Callable[..., Proc],
    client: zenoh.Session,
    endpoint: str,
    tmp_path: Path,
    autopilot: AutopilotStandIn,
) -> None:
    _start_bridge(spawn, tmp_path, endpoint, autopilot, heading_deg=0.0, output="gps_input")
    sender = FixSender(client, SiteKey.load(_key_path(tmp_path), config_key="fix_key"))

    def one_through() -> bool:
        sender.send(position=(20.0, 0.0, -2.0))
        time.sleep(0.05)
        return len(autopilot.recorded.gps_inputs) > 0

    wait_for(one_through, timeout_s=20, what="a GPS_INPUT at the autopilot")
    assert autopilot.recorded.estimates == []
    _, gps = autopilot.recorded.gps_inputs[-1]
    # Heading 0: W x is north; origin_ned_m puts W's origin 10 m north, 5 m west of the EKF origin.
    north_m, east_m = 20.0 + 10.0, -5.0
    lat = 54.42 + math.degrees(north_m / 6_378_137.0)
    lon = -3.5 + math.degrees(east_m / (6_378_137.0 * math.cos(math.radians(54.42))))
    assert gps.lat_e7 == pytest.approx(lat * 1e7, abs=2)
    assert gps.lon_e7 == pytest.approx(lon * 1e7, abs=2)
    assert gps.alt_m == pytest.approx(-2.0, abs=1e-4)
    assert gps.fix_type == 3
    assert gps.horiz_accuracy_m == pytest.approx(math.sqrt(0.020), rel=1e-3)
    # The bridge asked for its message rates (MAV_CMD_SET_MESSAGE_INTERVAL) and got them.
    from capsd.protocols.mavlink import message_id

    assert autopilot.rates_hz()[message_id("ATTITUDE")] == pytest.approx(20.0)
    assert autopilot.rates_hz()[message_id("SCALED_PRESSURE2")] == pytest.approx(20.0)


def test_only_fixes_signed_with_the_site_key_move_the_rov(
    spawn: Callable[..., Proc],
    client: zenoh.Session,
    endpoint: str,
    tmp_path: Path,
    autopilot: AutopilotStandIn,
) -> None:
    _start_bridge(spawn, tmp_path, endpoint, autopilot, heading_deg=0.0)
    site = FixSender(client, SiteKey.load(_key_path(tmp_path), config_key="fix_key"))
    _wait_ready(autopilot, site)
    time.sleep(0.2)
    before = len(autopilot.recorded.estimates)
    unsigned = FixSender(client, None)
    forged = FixSender(client, SiteKey.generate())  # a key, but not the site's
    for k in range(20):
        unsigned.send(position=(5.0, 5.0, -1.0 - 0.01 * k))
        forged.send(position=(6.0, 6.0, -1.0 - 0.01 * k))
        time.sleep(0.03)
    # Replays of a genuine fix: its exact bytes and tag, again and again.
    genuine = site.codec.encode(site.send(position=(2.0, 2.0, -2.0)))
    time.sleep(0.1)
    for _ in range(5):
        site.put_bytes(genuine)
        time.sleep(0.03)
    # Absurd and future-stamped fixes, properly signed (a locator gone wrong, a skewed clock).
    site.send(position=(1e30, 2.0, -3.0))
    time.sleep(0.05)  # apart: the bridge takes only the newest fix
    site.send(position=(50.0, 2.0, -3.0))  # outside the 28 x 16 m tank
    time.sleep(0.05)
    site.send(stamp_ns=time.time_ns() + 250_000_000)
    time.sleep(0.5)
    got = [e for _, e in autopilot.recorded.estimates[before:]]
    assert len(got) == 1, [(e.x, e.y, e.z) for e in got]  # the genuine fix, once
    expected = TankToNed(0.0, np.array([10.0, -5.0, 0.0])).position(np.array([2.0, 2.0, -2.0]))
    assert (got[0].x, got[0].y, got[0].z) == pytest.approx(tuple(expected), abs=1e-5)
    health = _health(client)
    assert health.counters["fixes_unauthenticated"] >= 40
    assert health.counters["gate_outside_tank"] == 2
    assert health.counters["gate_from_future"] == 1
    replays = ("gate_not_monotonic", "gate_rate_limited", "fixes_dropped_for_newer")
    assert sum(health.counters.get(name, 0) for name in replays) >= 5
    wait_for(
        lambda: any("unsigned" in s.text for s in autopilot.recorded.statustexts),
        timeout_s=5,
        what="the pilot told of unsigned fixes",
    )


def test_the_bridge_refuses_to_start_without_the_site_key(
    spawn: Callable[..., Proc], endpoint: str, tmp_path: Path
) -> None:
    config = tmp_path / "mav_bridge.yaml"
    config.write_text(f"bus:\n  connect: [{endpoint}]\n")
    proc = spawn("run", "mav_bridge", "--config", str(config))
    assert proc.popen.wait(timeout=30) == 2
    assert "fix_key" in proc.output()
    loose = tmp_path / "loose.key"
    loose.write_text(SiteKey.generate().hex())
    loose.chmod(0o644)
    config.write_text(f"bus:\n  connect: [{endpoint}]\nfix_key: {loose}\n")
    proc = spawn("run", "mav_bridge", "--config", str(config))
    assert proc.popen.wait(timeout=30) == 2
    assert "readable by others" in proc.output()


def test_a_flood_of_forged_fixes_does_not_age_the_genuine_ones(
    spawn: Callable[..., Proc],
    client: zenoh.Session,
    endpoint: str,
    tmp_path: Path,
    autopilot: AutopilotStandIn,
) -> None:
    import threading

    bridge = _start_bridge(spawn, tmp_path, endpoint, autopilot, heading_deg=0.0)
    site = FixSender(client, SiteKey.load(_key_path(tmp_path), config_key="fix_key"))
    _wait_ready(autopilot, site)
    stop = threading.Event()
    lines_before = len(bridge.output().splitlines())

    def flood() -> None:
        # Its own session, as an attacker's would be: unsigned fixes as fast as it can put.
        with open_session(BusConfig(connect=(endpoint,))) as session:
            forged = FixSender(session, None)
            for _ in range(20_000):
                if stop.is_set():
                    return
                forged.send(position=(5.0, 5.0, -1.0))

    attacker = threading.Thread(target=flood, daemon=True)
    before = len(autopilot.recorded.estimates)
    attacker.start()
    sent = 0
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline:
        site.send(position=(2.0, 2.0, -2.0))
        sent += 1
        time.sleep(0.05)
    stop.set()
    attacker.join(timeout=10)
    time.sleep(0.3)
    got = [e for _, e in autopilot.recorded.estimates[before:]]
    print(f"{len(got)} of {sent} genuine fixes reached the autopilot during the flood")
    assert len(got) >= 0.9 * sent
    assert all(abs(e.x - got[0].x) < 1e-6 for e in got)  # none of the forged ones
    assert _health(client).counters["fixes_unauthenticated"] > 1000
    # No log storm: thousands refused, a few lines a second.
    flood_lines = bridge.output().splitlines()[lines_before:]
    assert len(flood_lines) <= 12, flood_lines


@pytest.mark.parametrize("heading_deg", [0.0, 90.0])
def test_a_wrong_heading_is_told_to_the_pilot(
    spawn: Callable[..., Proc],
    client: zenoh.Session,
    endpoint: str,
    tmp_path: Path,
    heading_deg: float,
) -> None:
    # The vehicle truly runs north at 0.3 m/s; W's x axis truly points north (heading 0).
    # The bridge is told `heading_deg`: at 90 its estimates run east while the vehicle goes
    # north, and the stand-in's EKF model sees the test ratio climb, as EKF3 does.
    t0 = time.time()

    def x_at(t: float) -> float:
        return 1.0 + 0.3 * (t - t0)

    def truth(t: float) -> VehicleState:
        # W to NED with heading 0 and origin (10, -5): north = x + 10, east = -y - 5.
        return VehicleState(depth_m=2.0, north_m=x_at(t) + 10.0, east_m=-2.0 - 5.0)

    with AutopilotStandIn(free_port(), state=truth, params=CONFIGURED_PARAMS) as autopilot:
        bridge = _start_bridge(spawn, tmp_path, endpoint, autopilot, heading_deg=heading_deg)
        sender = FixSender(client, SiteKey.load(_key_path(tmp_path), config_key="fix_key"))
        deadline = time.monotonic() + 14.0
        warned_at = None
        started = None
        while time.monotonic() < deadline:
            sender.send(position=(x_at(time.time()), 2.0, -2.0))
            if started is None and autopilot.recorded.estimates:
                started = time.monotonic()
            if warned_at is None and any("EKF" in s.text for s in autopilot.recorded.statustexts):
                warned_at = time.monotonic()
            time.sleep(0.05)
        health = _health(client)
    assert started is not None
    if heading_deg == 0.0:
        assert warned_at is None
        assert health.state == "ok", health.state_reason
    else:
        assert warned_at is not None
        assert warned_at - started <= 10.0
        assert health.state == "degraded"
        assert "heading" in (health.state_reason or "")
        assert health.counters["ekf_disagreement_episodes"] == 1  # once per episode
    assert bridge.popen.poll() is None


def test_a_vehicle_booted_under_water_is_noticed_and_zeroed(
    spawn: Callable[..., Proc], client: zenoh.Session, endpoint: str, tmp_path: Path
) -> None:
    # Booted 0.17 m under water, then surfaced: depth reads -0.17 m from the boot reference.
    with AutopilotStandIn(
        free_port(),
        state=lambda _t: VehicleState(depth_m=0.0),
        boot_depth_m=0.17,
        params=CONFIGURED_PARAMS,
    ) as autopilot:
        bridge = _start_bridge(spawn, tmp_path, endpoint, autopilot, heading_deg=0.0)
        _assert_told_and_degraded(autopilot, client, told="zero-depth", reason="zero-depth")
        # The stand-in serves one client at a time (BlueOS's MAVLink router serves many):
        # the bridge steps aside while a person runs the tool, then comes back.
        code, _ = bridge.terminate()
        assert code == 0
        connect = f"tcp:127.0.0.1:{autopilot.port}"

        def zero(*extra: str) -> subprocess.CompletedProcess[str]:
            return _capsd("mav", "zero-depth", "--connect", connect, *extra)

        shown = zero()
        assert shown.returncode == 0, shown.stdout + shown.stderr
        assert "-0.17" in shown.stdout
        applied = zero("--apply")
        assert applied.returncode == 0, applied.stdout + applied.stderr
        assert "+0.000 m deep" in applied.stdout
        # The bridge reads the new reference and is not degraded for it any more.
        _start_bridge(spawn, tmp_path, endpoint, autopilot, heading_deg=0.0)
        time.sleep(4.0)
        wait_for(
            lambda: "zero-depth" not in (_health(client).state_reason or ""),
            timeout_s=20,
            what="the bridge to take the new surface pressure",
        )


def test_mav_check_wants_the_delay_the_bridge_measures(
    spawn: Callable[..., Proc],
    client: zenoh.Session,
    endpoint: str,
    tmp_path: Path,
    autopilot: AutopilotStandIn,
) -> None:
    _start_bridge(spawn, tmp_path, endpoint, autopilot, heading_deg=0.0)
    sender = FixSender(client, SiteKey.load(_key_path(tmp_path), config_key="fix_key"))
    _wait_ready(autopilot, sender)
    for _ in range(20):
        # Measured 30 ms old when they leave (a ping's age at the bridge, as live).
        sender.send(stamp_ns=time.time_ns() - 30_000_000)
        time.sleep(0.05)
    stats = next(s for s in _health(client).latencies if s.name == "end to end")
    from capsd.latency import percentile_ms

    median = percentile_ms(stats, 50)
    assert median is not None
    # The stand-in serves one client (the bridge): the check talks to a second autopilot.
    with AutopilotStandIn(free_port()) as other:
        out = _capsd(
            "mav", "check", "--connect", f"tcp:127.0.0.1:{other.port}",
            "--bus", endpoint, "--site", "tank", "--vehicle", "rov",
        )  # fmt: skip
    assert "the bridge measures" in out.stdout, out.stdout + out.stderr
    row = next(line for line in out.stdout.splitlines() if line.startswith("VISO_DELAY_MS "))
    wanted = float(row.split()[2])
    assert wanted == max(5.0, 5.0 * round(median / 5.0))
    assert 25.0 <= wanted <= 60.0
    assert "CHANGE" in row  # the stand-in's 10 ms is not what this system needs


def _collect(
    client: zenoh.Session, key: str, payload: type[P]
) -> tuple[list[P], zenoh.Subscriber[None]]:
    """Every `payload` put on `key`, decoded, in arrival order (and the subscriber)."""
    received: list[P] = []
    codec = Codec(payload)
    subscriber = client.declare_subscriber(
        key,
        lambda s: received.append(
            codec.decode(s.payload.to_bytes(), encoding=str(s.encoding), key_expr=str(s.key_expr))
        ),
    )
    return received, subscriber


def _asv_bridge_config(tmp_path: Path, endpoint: str, port: int, extra: str) -> Path:
    """The ASV's bridge (role asv) on the stand-in at `port`, with `extra` YAML lines."""
    config = tmp_path / "asv_bridge.yaml"
    config.write_text(
        f"site: tank\nvehicle: asv\nrole: asv\nbus:\n  connect: [{endpoint}]\n"
        f"fix_key: {_key_path(tmp_path)}\nmission_commands: accept\n"
        "tank:\n  length_m: 28.0\n  width_m: 16.0\n  depth_m: 8.0\n"
        f"mavlink:\n  connect: tcp:127.0.0.1:{port}\n"
        "ekf_origin:\n  lat_deg: 54.42\n  lon_deg: -3.5\n  alt_m: 0.0\n" + extra
    )
    return config


def test_the_asv_role_feeds_its_pose_and_passes_follow_targets_only_in_guided(
    spawn: Callable[..., Proc], client: zenoh.Session, endpoint: str, tmp_path: Path
) -> None:
    """ArduRover: the ASV's pose in, follow targets with a heading out while GUIDED.

    The pose's own attitude goes with it; never an engage; its status on asv/autopilot.
    """
    heading_deg = 30.0
    directions: list[str] = []  # MAV_CMD_DO_SET_REVERSE as ArduRover heard it
    with AutopilotStandIn(
        free_port(),
        mode="MANUAL",
        autopilot="ardurover",
        params=CONFIGURED_PARAMS,
        on_direction=directions.append,
    ) as rover:
        config = _asv_bridge_config(
            tmp_path,
            endpoint,
            rover.port,
            "geofence_clearance_m: 1.0\n"
            f"ned:\n  heading_deg: {heading_deg}\n  origin_ned_m: [0.0, 0.0, 0.0]\n",
        )
        spawn("run", "mav_bridge", "--config", str(config))
        key = SiteKey.load(_key_path(tmp_path), config_key="fix_key")
        poses = client.declare_publisher(
            topics.ASV_POSE.key("tank", "asv"), encoding=zenoh.Encoding(Codec(AsvPose).encoding)
        )
        commands = client.declare_publisher(
            topics.ASV_COMMAND.key("tank", "topside"),
            encoding=zenoh.Encoding(Codec(VehicleCommand).encoding),
        )
        statuses, status_sub = _collect(
            client, topics.ASV_AUTOPILOT.key("tank", "asv"), AutopilotStatus
        )
        yaw_w = 0.4  # the ASV's heading in W (ccw from x)
        r_w_b = np.array(
            [[math.cos(yaw_w), -math.sin(yaw_w), 0.0], [math.sin(yaw_w), math.cos(yaw_w), 0.0],
             [0.0, 0.0, 1.0]]
        )  # fmt: skip
        q = matrix_to_quat(r_w_b)
        cov6 = tuple(float(i == j) * 1e-4 for i in range(6) for j in range(6))

        def put_pose() -> None:
            pose = AsvPose(
                stamp_ns=time.time_ns(), seq=0, position_m=(9.0, 8.0, 0.01),
                orientation_xyzw=(float(q[0]), float(q[1]), float(q[2]), float(q[3])),
                covariance=cov6,
            )  # fmt: skip
            poses.put(Codec(AsvPose).encode(pose), attachment=time.time_ns().to_bytes(8, "little"))

        def put_command(
            kind: str, position: tuple[float, float, float], direction: str = "forward"
        ) -> None:
            command = VehicleCommand(
                stamp_ns=time.time_ns(), seq=0, mission="follow", kind=kind,  # type: ignore[arg-type]
                position_m=position, heading_rad=yaw_w, direction=direction,  # type: ignore[arg-type]
            )  # fmt: skip
            data = Codec(VehicleCommand).encode(command)
            key_expr = topics.ASV_COMMAND.key("tank", "topside")
            tag = key.tag(key_expr, data)
            commands.put(data, attachment=time.time_ns().to_bytes(8, "little") + tag)

        def estimate_arrived() -> bool:
            put_pose()
            time.sleep(0.05)
            return bool(rover.recorded.estimates)

        wait_for(estimate_arrived, timeout_s=20, what="the ASV's pose at ArduRover")
        ned = TankToNed(math.radians(heading_deg), np.zeros(3))
        estimate = rover.recorded.estimates[-1][1]
        assert (estimate.x, estimate.y, estimate.z) == pytest.approx(
            tuple(ned.position(np.array([9.0, 8.0, 0.01]))), abs=1e-5
        )
        assert estimate.yaw == pytest.approx(ned.attitude_to_ned(r_w_b)[2], abs=1e-6)
        # MANUAL (the pilot's): a goto is not passed on, an engage is refused outright.
        for _ in range(5):
            put_command("goto", (10.0, 8.0, 0.0))
            put_command("engage", (10.0, 8.0, 0.0))
            time.sleep(0.1)
        assert rover.recorded.position_targets == []
        assert rover.recorded.targets_refused == 0  # nothing was even sent
        assert not [m for m in rover.recorded.modes if m[1] == "GUIDED"]
        # The pilot hands over: targets with the heading, in NED, reach the autopilot.
        rover.mode = "GUIDED"

        def target_arrived() -> bool:
            put_pose()
            put_command("goto", (10.0, 8.0, 0.0))
            time.sleep(0.1)
            return bool(rover.recorded.position_targets)

        wait_for(target_arrived, timeout_s=10, what="a follow target at ArduRover")
        assert rover.origin is not None  # without one ArduRover would ignore every target
        target = rover.recorded.position_targets[-1][1]
        assert (target.north_m, target.east_m) == pytest.approx(
            tuple(ned.position(np.array([10.0, 8.0, 0.0]))[:2]), abs=1e-4
        )
        assert target.yaw_rad == pytest.approx(ned.attitude_to_ned(r_w_b)[2], abs=1e-5)
        assert not target.position_ignored  # 1 m to go: a position target
        # At the station (the pose 0.1 m from the goto): the heading alone, which ArduRover's
        # GUIDED turns to (it ignores a position target's yaw).
        before = len(rover.recorded.position_targets)

        def heading_arrived() -> bool:
            put_pose()
            put_command("goto", (9.1, 8.0, 0.0))
            time.sleep(0.1)
            return any(t.position_ignored for _, t in rover.recorded.position_targets[before:])

        wait_for(heading_arrived, timeout_s=10, what="a heading-only target at the station")
        turn = next(t for _, t in rover.recorded.position_targets[before:] if t.position_ignored)
        assert turn.yaw_rad == pytest.approx(ned.attitude_to_ned(r_w_b)[2], abs=1e-5)
        # The station moves 0.15 m (still 0.25 m from the ASV): ArduRover's target is where
        # the old one was, so the new one is driven to first, not turned at.
        before = len(rover.recorded.position_targets)

        def moved_station_sent() -> bool:
            put_pose()
            put_command("goto", (9.25, 8.0, 0.0))
            time.sleep(0.1)
            return len(rover.recorded.position_targets) > before

        wait_for(moved_station_sent, timeout_s=10, what="a target for the moved station")
        moved = rover.recorded.position_targets[before][1]
        assert not moved.position_ignored
        assert (moved.north_m, moved.east_m) == pytest.approx(
            tuple(ned.position(np.array([9.25, 8.0, 0.0]))[:2]), abs=1e-4
        )
        # Astern (a steered hull backing off the ROV): ArduRover is told once, before the
        # target it is for; ahead again once. (It took GUIDED set to ahead: told ahead first.)
        assert directions == ["forward"]
        before = len(rover.recorded.position_targets)

        def astern_sent() -> bool:
            put_pose()
            put_command("goto", (8.0, 8.0, 0.0), direction="reverse")
            time.sleep(0.1)
            return len(rover.recorded.position_targets) > before + 2

        wait_for(astern_sent, timeout_s=10, what="targets astern")
        assert directions == ["forward", "reverse"]

        def ahead_again() -> bool:
            put_pose()
            put_command("goto", (9.0, 9.0, 0.0))
            time.sleep(0.1)
            return directions[-1] == "forward"

        wait_for(ahead_again, timeout_s=10, what="ahead again")
        assert directions == ["forward", "reverse", "forward"]
        # Fenced out (0.5 m from a wall, the fence is 1 m): refused.
        before = len(rover.recorded.position_targets)
        for _ in range(5):
            put_command("goto", (0.5, 8.0, 0.0))
            time.sleep(0.05)
        time.sleep(0.3)
        assert all(t.north_m != pytest.approx(ned.position(np.array([0.5, 8.0, 0.0]))[0])
                   for _, t in rover.recorded.position_targets[before:])  # fmt: skip
        wait_for(lambda: any(s.mode == "GUIDED" for s in statuses), timeout_s=5,
                 what="GUIDED on asv/autopilot")  # fmt: skip
        health = query_health(client, site="tank", vehicle="asv", service="mav_bridge")
        assert health is not None
        assert health.counters.get("commands_refused_engage_is_the_pilots", 0) >= 1
        assert health.counters.get("commands_refused_outside_geofence", 0) >= 1
        status_sub.undeclare()
        poses.undeclare()
        commands.undeclare()


def test_the_asv_role_drives_the_sonar_tilt_servo_in_guided_and_publishes_its_angle(
    spawn: Callable[..., Proc], client: zenoh.Session, endpoint: str, tmp_path: Path
) -> None:
    """The follower's angle to ArduRover's mount (GUIDED only), the mount's report back.

    The mount reports MAVLink's pitch (up +) against the horizon, as ArduPilot's does: the
    sonar's zero at -45 deg, a tilt of 10 deg down goes out as -55 deg, and with the ASV
    pitched 2 deg nose up (its ATTITUDE) comes back as 12 deg on the hull, stamped.
    """
    nose_up = math.radians(2.0)
    servo = TiltServo(SonarTiltConfig(), zero_pitch_deg=-45.0)
    told: list[float] = []

    def on_pitch(pitch_deg: float, yaw_deg: float) -> None:
        told.append(pitch_deg)
        assert yaw_deg == 0.0  # no pan: ahead
        servo.command(time.monotonic(), pitch_deg, yaw_deg)

    with AutopilotStandIn(
        free_port(),
        mode="MANUAL",
        autopilot="ardurover",
        params=CONFIGURED_PARAMS,
        on_gimbal_pitch=on_pitch,
        gimbal_pitch_rad=servo.reported_pitch_rad,
        state=lambda _t: VehicleState(pitch=nose_up),
    ) as rover:
        config = _asv_bridge_config(
            tmp_path, endpoint, rover.port, "sonar_tilt:\n  zero_pitch_deg: -45.0\n"
        )
        tilts, tilt_sub = _collect(client, topics.SONAR_TILT.key("tank", "asv"), SonarTilt)
        spawn("run", "mav_bridge", "--config", str(config))
        key = SiteKey.load(_key_path(tmp_path), config_key="fix_key")
        commands = client.declare_publisher(
            topics.ASV_COMMAND.key("tank", "topside"),
            encoding=zenoh.Encoding(Codec(VehicleCommand).encoding),
        )

        def put_command(tilt_deg: float) -> None:
            command = VehicleCommand(
                stamp_ns=time.time_ns(), seq=0, mission="follow", kind="goto",
                position_m=(10.0, 8.0, 0.0), sonar_tilt_rad=math.radians(tilt_deg),
            )  # fmt: skip
            data = Codec(VehicleCommand).encode(command)
            tag = key.tag(topics.ASV_COMMAND.key("tank", "topside"), data)
            commands.put(data, attachment=time.time_ns().to_bytes(8, "little") + tag)

        # The mount's reports reach the bus from the start (the servo at its zero).
        wait_for(lambda: len(tilts) >= 3, timeout_s=20, what="the mount's angle on the bus")
        assert tilts[-1].tilt_rad == pytest.approx(nose_up, abs=1e-6)
        assert abs(tilts[-1].stamp_ns - time.time_ns()) < 2e9  # the autopilot's clock, mapped
        # MANUAL: the servo is left alone.
        for _ in range(5):
            put_command(10.0)
            time.sleep(0.1)
        assert told == []
        rover.mode = "GUIDED"

        def tilted() -> bool:
            put_command(10.0)
            time.sleep(0.1)
            return bool(tilts) and tilts[-1].tilt_rad == pytest.approx(
                math.radians(10.0) + nose_up, abs=1e-6
            )

        wait_for(tilted, timeout_s=10, what="the servo tilted 10 deg down, reported")
        assert told[0] == pytest.approx(-55.0)
        # The same angle again within the dead band is not re-sent every command.
        sent = len(told)
        for _ in range(3):
            put_command(10.1)
            time.sleep(0.05)
        assert len(told) <= sent + 1

        # Beyond the servo's range (+40 deg): the mount stops there and says so.
        def at_limit() -> bool:
            put_command(60.0)
            time.sleep(0.1)
            return tilts[-1].tilt_rad == pytest.approx(math.radians(40.0) + nose_up, abs=1e-6)

        wait_for(at_limit, timeout_s=10, what="the servo at its limit")
        health = query_health(client, site="tank", vehicle="asv", service="mav_bridge")
        assert health is not None
        sent, reported = (health.counters.get(k, 0) for k in ("commands_sent_tilt", "tilt_reports"))
        assert sent >= 2  # 10 deg, then the limit
        assert reported >= 3
        tilt_sub.undeclare()
        commands.undeclare()


def test_the_asv_role_drives_a_pan_servo_with_the_tilt_and_publishes_both_angles(
    spawn: Callable[..., Proc], client: zenoh.Session, endpoint: str, tmp_path: Path
) -> None:
    """A mount with a pan (`sonar_tilt.pan: servo`): both angles out and back.

    The follower's pan (left +) goes out as MAVLink's yaw in the vehicle's frame (right +) and
    comes back as `pan_rad`.
    """
    servo = TiltServo(SonarTiltConfig(), zero_pitch_deg=-45.0, pan=SonarPanConfig())
    told: list[tuple[float, float]] = []

    def on_gimbal(pitch_deg: float, yaw_deg: float) -> None:
        told.append((pitch_deg, yaw_deg))
        servo.command(time.monotonic(), pitch_deg, yaw_deg)

    with AutopilotStandIn(
        free_port(),
        mode="GUIDED",
        autopilot="ardurover",
        params=CONFIGURED_PARAMS,
        on_gimbal_pitch=on_gimbal,
        gimbal_pitch_rad=servo.reported_pitch_rad,
        gimbal_yaw_rad=servo.reported_yaw_rad,
    ) as rover:
        config = _asv_bridge_config(
            tmp_path, endpoint, rover.port, "sonar_tilt:\n  zero_pitch_deg: -45.0\n  pan: servo\n"
        )
        tilts, tilt_sub = _collect(client, topics.SONAR_TILT.key("tank", "asv"), SonarTilt)
        spawn("run", "mav_bridge", "--config", str(config))
        key = SiteKey.load(_key_path(tmp_path), config_key="fix_key")
        commands = client.declare_publisher(
            topics.ASV_COMMAND.key("tank", "topside"),
            encoding=zenoh.Encoding(Codec(VehicleCommand).encoding),
        )

        def panned() -> bool:
            command = VehicleCommand(
                stamp_ns=time.time_ns(), seq=0, mission="follow", kind="goto",
                position_m=(10.0, 8.0, 0.0), sonar_tilt_rad=math.radians(10.0),
                sonar_pan_rad=math.radians(70.0),
            )  # fmt: skip
            data = Codec(VehicleCommand).encode(command)
            tag = key.tag(topics.ASV_COMMAND.key("tank", "topside"), data)
            commands.put(data, attachment=time.time_ns().to_bytes(8, "little") + tag)
            time.sleep(0.1)
            return bool(tilts) and tilts[-1].pan_rad == pytest.approx(math.radians(70.0), abs=1e-6)

        wait_for(panned, timeout_s=20, what="the pan at 70 deg to port, reported")
        assert told[-1] == pytest.approx((-55.0, -70.0))
        assert tilts[-1].tilt_rad == pytest.approx(math.radians(10.0), abs=1e-6)
        tilt_sub.undeclare()
        commands.undeclare()
