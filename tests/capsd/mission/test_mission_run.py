"""`capsd mission run` end to end: a real router, the bridge process, the ArduSub stand-in.

The test plays the locator (signed fixes that walk to each waypoint) and watches what reaches
the autopilot over MAVLink: GUIDED, position targets in NED, POSHOLD within a second of the
fixes stopping, GUIDED again once they are back, the plan flown and a report written.
"""

from __future__ import annotations

import contextlib
import json
import math
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
import zenoh

from capsd import topics
from capsd.codec import Codec
from capsd.ned import TankToNed
from capsd.payloads import CommandKind, VehicleCommand
from capsd.signing import SiteKey
from capsd.simulator.autopilot import CONFIGURED_PARAMS, AutopilotStandIn, VehicleState
from tests.conftest import Proc, free_port, wait_for
from tests.services.mav_bridge.test_bridge import FixSender, _health, _key_path

pytestmark = pytest.mark.integration

NED = TankToNed(math.radians(30.0), np.array([10.0, -5.0, 0.0]))
WAYPOINTS = [(5.0, 4.0, -3.0), (9.0, 4.0, -3.0)]


@pytest.fixture
def autopilot() -> Iterator[AutopilotStandIn]:
    state = VehicleState(roll=0.0, pitch=0.0, yaw=0.5, depth_m=3.0)
    with AutopilotStandIn(
        free_port(), state=lambda _t: state, mode="MANUAL", params=CONFIGURED_PARAMS
    ) as stand_in:
        yield stand_in


def _configs(tmp_path: Path, endpoint: str, autopilot: AutopilotStandIn) -> tuple[Path, Path]:
    tank = "tank:\n  length_m: 28.0\n  width_m: 16.0\n  depth_m: 8.0\n"
    bridge = tmp_path / "mav_bridge.yaml"
    bridge.write_text(
        f"site: tank\nvehicle: rov\nbus:\n  connect: [{endpoint}]\n"
        f"fix_key: {_key_path(tmp_path)}\n{tank}"
        f"mavlink:\n  connect: tcp:127.0.0.1:{autopilot.port}\n"
        "ned:\n  heading_deg: 30.0\n  origin_ned_m: [10.0, -5.0, 0.0]\n"
        "mission_commands: accept\n"
    )
    locator = tmp_path / "locator.yaml"
    locator.write_text(f"site: tank\nfix_key: {_key_path(tmp_path)}\n{tank}")
    return bridge, locator


class Vehicle:
    """Stands in for the ROV and the locator: signed fixes at 20 Hz from `position`."""

    def __init__(self, sender: FixSender):
        self.sender = sender
        self.position = np.array([4.0, 4.0, -3.0])
        self.sending = threading.Event()
        self.sending.set()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            if self.sending.is_set():
                x, y, z = (float(v) for v in self.position)
                self.sender.send(position=(x, y, z))
            time.sleep(0.05)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self.sender.publisher.undeclare()


def _targets_tank(autopilot: AutopilotStandIn) -> list[tuple[float, float, float]]:
    with autopilot.lock:
        targets = [t for _, t in autopilot.recorded.position_targets]
    out = []
    for t in targets:
        x, y, z = NED.position_to_tank(np.array([t.north_m, t.east_m, t.down_m]))
        out.append((float(x), float(y), float(z)))
    return out


def _modes(autopilot: AutopilotStandIn) -> list[tuple[float, str, bool]]:
    with autopilot.lock:
        return list(autopilot.recorded.modes)


class Commands:
    """The bridge under test, a stand-in locator's fixes, and a publisher of mission commands."""

    def __init__(
        self,
        spawn: Callable[..., Proc],
        client: zenoh.Session,
        endpoint: str,
        tmp_path: Path,
        autopilot: AutopilotStandIn,
    ):
        bridge_config, _ = _configs(tmp_path, endpoint, autopilot)
        spawn("run", "mav_bridge", "--config", str(bridge_config))
        self.key = SiteKey.load(_key_path(tmp_path), config_key="fix_key")
        self.vehicle = Vehicle(FixSender(client, self.key))
        self.key_expr = topics.ROV_COMMAND.key("tank", "topside")
        self.codec = Codec(VehicleCommand)
        self.publisher = client.declare_publisher(
            self.key_expr, encoding=zenoh.Encoding(self.codec.encoding)
        )
        wait_for(lambda: autopilot.recorded.estimates, timeout_s=20, what="estimates flowing")

    def put(
        self,
        kind: CommandKind,
        position: tuple[float, float, float] | None,
        *,
        age_s: float = 0.0,
        signed: bool = True,
    ) -> None:
        command = VehicleCommand(
            stamp_ns=time.time_ns() - int(age_s * 1e9), seq=0, mission="test", kind=kind,
            position_m=position,
        )  # fmt: skip
        data = self.codec.encode(command)
        attachment = time.time_ns().to_bytes(8, "little")
        if signed:
            attachment += self.key.tag(self.key_expr, data)
        self.publisher.put(data, attachment=attachment)

    def close(self) -> None:
        self.vehicle.close()
        self.publisher.undeclare()


def test_mission_flies_pauses_on_lost_fix_resumes_and_reports(
    spawn: Callable[..., Proc],
    client: zenoh.Session,
    endpoint: str,
    tmp_path: Path,
    autopilot: AutopilotStandIn,
) -> None:
    bridge_config, locator_config = _configs(tmp_path, endpoint, autopilot)
    spawn("run", "mav_bridge", "--config", str(bridge_config))
    vehicle = Vehicle(FixSender(client, SiteKey.load(_key_path(tmp_path), config_key="fix_key")))
    try:
        wait_for(lambda: autopilot.recorded.estimates, timeout_s=20, what="estimates flowing")
        plan = tmp_path / "plan.yaml"
        plan.write_text(
            "name: test\nresume_after_s: 1.0\nfix_timeout_s: 0.5\npoints:\n"
            "  - {position_m: [5.0, 4.0], depth_m: 3.0}\n"
            "  - {position_m: [9.0, 4.0], depth_m: 3.0, dwell_s: 1.0}\n"
        )
        out = tmp_path / "report"
        mission = spawn(
            "mission", "run", str(plan), "--locator-config", str(locator_config),
            "--connect", endpoint, "--out", str(out),
        )  # fmt: skip
        # Engaged: GUIDED asked and taken, the first waypoint as the target, in NED.
        wait_for(lambda: _targets_tank(autopilot), timeout_s=20, what="a position target")
        assert _modes(autopilot)[0][1:] == ("GUIDED", True)
        assert _targets_tank(autopilot)[0] == pytest.approx(WAYPOINTS[0], abs=1e-4)

        # The fix is lost: POSHOLD within a second of the last fix.
        vehicle.sending.clear()
        lost_at = time.time()
        wait_for(
            lambda: [m for m in _modes(autopilot) if m[1] == "POSHOLD"],
            timeout_s=5,
            what="POSHOLD after the fix was lost",
        )
        hold_at = next(t for t, m, _ in _modes(autopilot) if m == "POSHOLD")
        assert hold_at - lost_at < 1.0
        assert autopilot.mode == "POSHOLD"

        # Fixes back: GUIDED again after they have been good for resume_after_s; then fly on.
        vehicle.sending.set()
        back_at = time.time()
        wait_for(lambda: autopilot.mode == "GUIDED", timeout_s=10, what="GUIDED again")
        guided_again = [t for t, m, _ in _modes(autopilot) if m == "GUIDED"][-1]
        assert guided_again - back_at >= 0.9
        vehicle.position = np.array(WAYPOINTS[0])
        # On the leg: the target runs ahead of the ROV on the line (the plan's 0.25 m/s x 2 s).
        carrot = (5.5, 4.0, -3.0)
        wait_for(
            lambda: any(np.allclose(t, carrot, atol=1e-3) for t in _targets_tank(autopilot)),
            timeout_s=10,
            what="a target on the second leg, 0.5 m ahead",
        )
        for x in np.linspace(5.0, 9.0, 20):
            vehicle.position = np.array([x, 4.05, -3.0])
            time.sleep(0.05)
        mission.popen.wait(timeout=20)
        on_leg = [t for t in _targets_tank(autopilot) if t[0] > 5.0 + 1e-6]
        assert all(t[1:] == pytest.approx((4.0, -3.0), abs=1e-4) for t in on_leg)  # on the line
        assert on_leg[-1] == pytest.approx(WAYPOINTS[1], abs=1e-4)  # and its end last
        assert mission.popen.returncode == 0, mission.output()[-3000:]
        figures = json.loads((out / "mission.json").read_text())
        assert figures["state"] == "done"
        assert figures["pauses"] == 1
        assert figures["cross_track_max_m"] == pytest.approx(0.05, abs=1e-6)
        assert (out / "mission.png").stat().st_size > 10_000
        assert autopilot.mode == "POSHOLD"  # the mission ends holding
        assert "done" in mission.output()
    finally:
        vehicle.close()


def test_the_bridge_refuses_unsigned_stale_and_fenced_out_commands(
    spawn: Callable[..., Proc],
    client: zenoh.Session,
    endpoint: str,
    tmp_path: Path,
    autopilot: AutopilotStandIn,
) -> None:
    bridge = Commands(spawn, client, endpoint, tmp_path, autopilot)
    try:
        bridge.put("engage", (5.0, 4.0, -3.0), signed=False)
        bridge.put("engage", (5.0, 4.0, -3.0), age_s=5.0)
        bridge.put("engage", (27.9, 4.0, -3.0))  # 0.1 m from the wall
        bridge.put("engage", (5.0, 4.0, 1.0))  # above the surface

        def counted() -> bool:
            c = _health(client).counters
            return (
                c.get("commands_unauthenticated", 0) == 1
                and c.get("commands_refused_stale", 0) == 1
                and c.get("commands_refused_outside_geofence", 0) == 2
            )

        wait_for(counted, timeout_s=10, what="the four refusals counted")
        time.sleep(0.5)
        assert _modes(autopilot) == []
        assert autopilot.recorded.position_targets == []
        # A signed, fresh command inside the fence is acted on: the path is not just closed.
        bridge.put("engage", (5.0, 4.0, -3.0))
        wait_for(lambda: autopilot.mode == "GUIDED", timeout_s=10, what="GUIDED")
        wait_for(lambda: _targets_tank(autopilot), timeout_s=10, what="the target")
        assert _targets_tank(autopilot)[0] == pytest.approx((5.0, 4.0, -3.0), abs=1e-4)
    finally:
        bridge.close()


def test_bad_invocations_exit_2_naming_what(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    from capsd.cli import main

    locator = tmp_path / "locator.yaml"
    locator.write_text("site: tank\ntank:\n  length_m: 28.0\n  width_m: 16.0\n  depth_m: 8.0\n")
    plan = tmp_path / "plan.yaml"
    plan.write_text("points:\n  - {position_m: [5.0, 4.0], depth_m: 3.0}\n")
    # No fix key in the site's locator config: commands could not be signed.
    assert main(["mission", "run", str(plan), "--locator-config", str(locator)]) == 2
    assert "fix_key" in capfd.readouterr().err
    # A plan that does not exist.
    missing = tmp_path / "nope.yaml"
    assert main(["mission", "run", str(missing), "--locator-config", str(locator)]) == 2
    assert "nope.yaml" in capfd.readouterr().err


@contextlib.contextmanager
def _bridge_to(
    spawn: Callable[..., Proc], client: zenoh.Session, endpoint: str, tmp_path: Path, *, mode: str
) -> Iterator[tuple[AutopilotStandIn, Commands]]:
    """A stand-in ArduSub in `mode`, the bridge to it, and the commands' publisher."""
    state = VehicleState(roll=0.0, pitch=0.0, yaw=0.5, depth_m=3.0)
    with AutopilotStandIn(
        free_port(), state=lambda _t: state, mode=mode, params=CONFIGURED_PARAMS
    ) as autopilot:
        bridge = Commands(spawn, client, endpoint, tmp_path, autopilot)
        try:
            yield autopilot, bridge
        finally:
            bridge.close()


def test_a_hold_is_sent_again_to_a_holding_vehicle_but_never_over_the_pilots_mode(
    spawn: Callable[..., Proc], client: zenoh.Session, endpoint: str, tmp_path: Path
) -> None:
    # A HEARTBEAT from before the autopilot took the mission's GUIDED can still say POSHOLD
    # when the mission's next hold arrives: that hold must go out, not be dropped.
    with _bridge_to(spawn, client, endpoint, tmp_path, mode="POSHOLD") as (holding, bridge):
        time.sleep(1.5)  # a HEARTBEAT (1 Hz) has told the bridge the mode
        bridge.put("hold", None)
        wait_for(lambda: [m for _, m, _ in _modes(holding) if m == "POSHOLD"],
                 timeout_s=10, what="POSHOLD sent again")  # fmt: skip
        # The pilot takes MANUAL: a hold now is not acted on.
        holding.mode = "MANUAL"
        time.sleep(1.5)
        before = len(_modes(holding))
        bridge.put("hold", None)
        wait_for(lambda: _health(client).counters.get("commands_hold_not_guided", 0) >= 1,
                 timeout_s=10, what="the hold refused in MANUAL")  # fmt: skip
        assert len(_modes(holding)) == before
        assert holding.mode == "MANUAL"


def test_an_engage_asks_for_guided_whatever_the_last_heartbeat_said(
    spawn: Callable[..., Proc], client: zenoh.Session, endpoint: str, tmp_path: Path
) -> None:
    # The HEARTBEAT comes at 1 Hz: the mode it told the bridge can be older than a change since
    # (found with ArduSub SITL: a resume after a pause was not passed on as a mode, the vehicle
    # stayed in POSHOLD and the mission ended).
    with _bridge_to(spawn, client, endpoint, tmp_path, mode="GUIDED") as (guided, bridge):
        time.sleep(1.5)  # a HEARTBEAT has told the bridge GUIDED
        wait_for(lambda: time.monotonic() - guided.heartbeat_sent_s < 0.1, timeout_s=2,
                 what="a HEARTBEAT just sent")  # fmt: skip
        guided.mode = "POSHOLD"  # not heard till the next HEARTBEAT, 0.9 s away
        bridge.put("engage", (5.0, 4.0, -3.0))
        wait_for(lambda: guided.mode == "GUIDED", timeout_s=0.8, what="GUIDED asked again")
        assert ("GUIDED", True) in [(m, taken) for _, m, taken in _modes(guided)]


def test_a_position_hold_the_autopilot_refuses_becomes_a_depth_hold(
    spawn: Callable[..., Proc],
    client: zenoh.Session,
    endpoint: str,
    tmp_path: Path,
    autopilot: AutopilotStandIn,
) -> None:
    # The fixes stopped a while before the hold: ArduSub has no position and refuses POSHOLD.
    # Left in GUIDED the ROV would fly on to its target on a coasting estimate.
    bridge = Commands(spawn, client, endpoint, tmp_path, autopilot)
    try:
        bridge.put("engage", (5.0, 4.0, -3.0))
        wait_for(lambda: autopilot.mode == "GUIDED", timeout_s=10, what="GUIDED")
        bridge.vehicle.sending.clear()
        time.sleep(1.5)  # the stand-in's position is gone after 1 s without estimates
        bridge.put("hold", None)
        wait_for(lambda: autopilot.mode == "ALT_HOLD", timeout_s=10, what="ALT_HOLD")
        asked = [(m, taken) for _, m, taken in _modes(autopilot)]
        assert asked[-2:] == [("POSHOLD", False), ("ALT_HOLD", True)]
        wait_for(lambda: _health(client).counters.get("commands_sent_alt_hold", 0) == 1,
                 timeout_s=10, what="the fallback counted")  # fmt: skip
    finally:
        bridge.close()
