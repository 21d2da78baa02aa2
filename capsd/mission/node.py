"""`capsd mission run PLAN.yaml`: fly a plan on CAP-SD fixes, through the ROV's bridge.

The mission joins the bus as a service does (`mission`, in the topside namespace, where the
site's access control lets the locator's computer write), reads the fixes and the vehicle's
mode, and puts signed RovCommands (the site's fix key, from the locator config) that the
bridge turns into GUIDED targets and POSHOLD holds (capsd.mission.controller has the logic).
A line every `progress_period_s` shows where it stands; at the end (the plan flown, the pilot
taking over, or Ctrl-C, which leaves the ROV holding) the report folder gets mission.json
(planned against flown: cross-track error, pauses) and mission.png.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Annotated, Literal, TextIO

import msgspec
import numpy as np

from capsd import topics
from capsd.accuracy import fix_estimate
from capsd.config import ServiceConfig, load_config
from capsd.errors import ConfigError
from capsd.geometry import Transform
from capsd.keys import check_name
from capsd.mission.controller import Command, MissionController
from capsd.mission.plan import Plan, Waypoint, load_plan, path_length_m
from capsd.mission.view_guard import view_margin_rad
from capsd.mounts import SonarMountConfig
from capsd.payloads import AsvPose, AutopilotStatus, RovFix, SonarTilt, VehicleCommand
from capsd.runner import Publisher, ServiceRunner
from capsd.services.locator.service import Config as LocatorConfig
from capsd.signing import SiteKey
from capsd.tank import TankBounds

logger = logging.getLogger(__name__)


class Config(ServiceConfig, frozen=True, kw_only=True):
    """The mission's bus settings (the plan is its own file)."""

    vehicle: str = "topside"  # the namespace its commands are put in (the locator's computer)
    locator_vehicle: str = "topside"  # where the fixes come from
    rov_vehicle: str = "rov"  # where the bridge reports the vehicle's mode (AutopilotStatus)
    asv_vehicle: str = "asv"  # where the ASV's pose is (the plan's view_guard needs it)
    # required: commands carry the site's fix key's tag (the bridge refuses untagged ones).
    command_auth: Literal["required", "off"] = "required"
    progress_period_s: Annotated[float, msgspec.Meta(gt=0.0, le=60.0)] = 2.0

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("locator_vehicle", "rov_vehicle", "asv_vehicle"):
            try:
                check_name("vehicle", getattr(self, name))
            except ValueError as exc:
                raise ValueError(f"`{name}`: {exc}") from None


def site_tank(locator_config: Path) -> tuple[LocatorConfig, TankBounds]:
    """The site's locator config and its tank (the mission's geofence)."""
    locator = load_config(locator_config, LocatorConfig)
    if locator.tank is None:
        raise ConfigError(
            str(locator_config), "tank", "a mission needs the tank's bounds (its geofence)"
        )
    return locator, locator.tank


def command_signer(
    locator: LocatorConfig, locator_config: Path, *, command_auth: str
) -> SiteKey | None:
    """The site's fix key, which signs the commands (None with `command_auth: off`)."""
    if command_auth == "off":
        return None
    if locator.fix_key is None:
        raise ConfigError(
            str(locator_config),
            "fix_key",
            "mission commands are signed with the site's fix key and this config has none "
            "(or run the mission with `command_auth: off` on a bench)",
        )
    # Read as the locator reads it (a relative path from the working directory).
    return SiteKey.load(Path(locator.fix_key), config_key="fix_key")


class MissionNode:
    """Bus in, controller, bus out; every command logged."""

    def __init__(
        self,
        plan: Plan,
        points: list[Waypoint],
        runner: ServiceRunner,
        commands: Publisher[VehicleCommand],
        stream: TextIO,
        *,
        sonar: SonarMountConfig,
        progress_period_s: float = 2.0,
    ):
        self.plan = plan
        self.sonar = sonar
        self._asv: AsvPose | None = None
        self._pan_rad = 0.0  # a pan servo's newest reported angle (the mount's `pan`)
        self.progress_period_s = progress_period_s
        self.controller = MissionController(plan, points)
        self.runner = runner
        self.commands = commands
        self.stream = stream
        self.lock = threading.Lock()
        self.sent: Counter[str] = Counter()  # commands put, by kind
        self.mode = "unknown"
        self.started = time.monotonic()
        self._last_line = -math.inf

    def on_fix(self, fix: RovFix) -> None:
        position, _ = fix_estimate(fix)
        now = time.monotonic()
        good = fix.quality == "good"
        with self.lock:
            self.controller.on_fix(good=good, position_m=position, now=now)
            pose = self._asv
            pan = self._pan_rad
        if good and position is not None and pose is not None:
            margin = view_margin_rad(
                asv=Transform.from_quat(pose.position_m, pose.orientation_xyzw),
                mount=self.sonar,
                rov_m=np.array(position),
                velocity_m_s=None if fix.velocity_m_s is None else np.array(fix.velocity_m_s),
                lookahead_s=self.plan.view_guard.lookahead_s,
                pan_rad=pan,
            )
            with self.lock:
                self.controller.on_view(margin, now=now)

    def on_sonar_tilt(self, servos: SonarTilt) -> None:
        """The sonar's servos: the pan turns its look off the bow (the guard's view)."""
        with self.lock:
            self._pan_rad = servos.pan_rad

    def on_asv_pose(self, pose: AsvPose) -> None:
        # 200 poses a second: kept as they came, turned into a transform only for a fix.
        with self.lock:
            self._asv = pose

    def on_status(self, status: AutopilotStatus) -> None:
        mode = status.mode if status.link == "ok" else "link lost"
        with self.lock:
            self.mode = mode
            self.controller.on_mode(mode, now=time.monotonic())

    def step(self) -> None:
        now = time.monotonic()
        with self.lock:
            commands = self.controller.step(now)
            state = self.controller.progress.state
        for command in commands:
            self.put(command)
        if now - self._last_line >= self.progress_period_s:
            self._last_line = now
            self.print_line(now)
        if state in ("done", "aborted"):
            self.runner.stop_event.set()

    def stop(self) -> None:
        """Ctrl-C or the end: a last hold if the mission still owned the vehicle."""
        now = time.monotonic()
        with self.lock:
            commands = self.controller.stop(now)
        for command in commands:
            self.put(command)

    def put(self, command: Command) -> None:
        self.commands.put(
            VehicleCommand(
                stamp_ns=time.time_ns(),
                seq=self.commands.next_seq(),
                mission=self.plan.name,
                kind=command.kind,
                waypoint=command.waypoint,
                position_m=command.position_m,
                reason=command.reason,
                leg_end_m=self.controller.leg_end(command),
                next_leg_end_m=self.controller.next_leg_end(command),
            )
        )
        self.sent[command.kind] += 1
        if command.kind != "goto" or command.reason != "repeat":
            logger.info(
                "mission command",
                extra={
                    "fields": {
                        "kind": command.kind,
                        "waypoint": command.waypoint,
                        "reason": command.reason,
                    }
                },
            )

    def print_line(self, now: float) -> None:
        p = self.controller.progress
        xt = p.cross_track_m
        rms = f"{math.sqrt(float(np.mean(np.square(xt)))) * 1000:.0f} mm" if xt else "-"
        print(
            f"  {now - self.started:6.1f} s  {p.state:<8} waypoint {p.waypoint + 1}/"
            f"{len(self.controller.points)}  mode {self.mode:<8} cross-track rms {rms}  "
            f"pauses {p.pauses}  waits {p.waits}"
            + (" (waiting for the ASV)" if self.controller.waiting() else ""),
            file=self.stream,
            flush=True,
        )


def report(node: MissionNode, out: Path) -> dict[str, object]:
    """mission.json and mission.png in `out`: the plan against what was flown."""
    out.mkdir(parents=True, exist_ok=True)
    p = node.controller.progress
    xt = np.array(p.cross_track_m)
    figures: dict[str, object] = {
        "mission": node.plan.name,
        "state": p.state,
        "why": p.why,
        "waypoints": len(node.controller.points),
        "waypoint_reached": p.waypoint + (1 if p.state == "done" else 0),
        "planned_length_m": round(path_length_m(node.controller.points), 3),
        "cross_track_rms_m": round(float(np.sqrt(np.mean(xt**2))), 4) if len(xt) else None,
        "cross_track_p95_m": round(float(np.percentile(xt, 95)), 4) if len(xt) else None,
        "cross_track_max_m": round(float(np.max(xt)), 4) if len(xt) else None,
        "fixes_on_legs": len(xt),
        "pauses": p.pauses,
        "paused_s": round(p.paused_s, 2),
        "waits_for_the_asv": p.waits,
        "waited_s": round(p.waited_s, 2),
        "waits_timed_out": p.waits_timed_out,
        "engages_refused": p.engages_refused,
        "pause_after_last_good_fix_max_s": (
            round(max(p.pause_latency_s), 3) if p.pause_latency_s else None
        ),
        "commands": {kind: node.sent[kind] for kind in ("engage", "goto", "hold")},
        "elapsed_s": round(time.monotonic() - node.started, 1),
    }
    (out / "mission.json").write_text(json.dumps(figures, indent=1) + "\n")
    _plot(node, out / "mission.png")
    return figures


def _plot(node: MissionNode, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    planned = np.array([w.position_m for w in node.controller.points])
    flown = np.array(node.controller.progress.flown_m).reshape(-1, 3)
    xt = np.array(node.controller.progress.cross_track_m) * 1000
    fig, (top, hist) = plt.subplots(1, 2, figsize=(12, 5), width_ratios=(3, 2))
    top.plot(planned[:, 0], planned[:, 1], "o--", color="0.4", label="planned")
    if len(flown):
        top.plot(flown[:, 0], flown[:, 1], "-", color="tab:blue", lw=1, label="flown (fixes)")
    top.set_aspect("equal")
    top.set_xlabel("x (m, tank frame)")
    top.set_ylabel("y (m)")
    top.set_title(f"mission {node.plan.name}: planned against flown")
    top.legend(loc="best")
    if len(xt):
        hist.hist(xt, bins=30, color="tab:blue")
        hist.axvline(float(np.sqrt(np.mean(xt**2))), color="k", ls="--", label="rms")
        hist.legend()
    hist.set_xlabel("cross-track error (mm)")
    hist.set_ylabel("fixes")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(
    config: Config,
    *,
    plan_path: Path,
    locator_config: Path,
    out: Path,
    stream: TextIO,
) -> int:
    """Fly the plan; 0 when done or stopped by the user, 1 when aborted (the pilot took over)."""
    locator, tank = site_tank(locator_config)
    plan, points = load_plan(plan_path, tank=tank)  # the file just written: checked first
    signer = command_signer(locator, locator_config, command_auth=config.command_auth)
    print(
        f"capsd mission: {plan.name}, {len(points)} waypoints, "
        f"{path_length_m(points):.1f} m planned; waiting for a good fix",
        file=stream,
        flush=True,
    )
    with ServiceRunner("mission", config) as runner:
        commands = runner.publisher(topics.ROV_COMMAND, signer=signer)
        node = MissionNode(
            plan,
            points,
            runner,
            commands,
            stream,
            sonar=locator.sonar,
            progress_period_s=config.progress_period_s,
        )
        runner.subscribe(topics.ROV_FIX, node.on_fix, vehicle=config.locator_vehicle)
        if plan.view_guard.mode != "off":
            runner.subscribe(topics.ASV_POSE, node.on_asv_pose, vehicle=config.asv_vehicle)
            if locator.sonar.pan is not None:
                runner.subscribe(topics.SONAR_TILT, node.on_sonar_tilt, vehicle=config.asv_vehicle)
        runner.subscribe(topics.ROV_STATUS, node.on_status, vehicle=config.rov_vehicle)
        try:
            runner.run(node.step, period_s=0.05)
        finally:
            node.stop()
            time.sleep(0.2)  # let the last hold leave before the session closes
    figures = report(node, out)
    print(
        f"capsd mission: {figures['state']} ({figures['why']}); cross-track rms "
        f"{figures['cross_track_rms_m']} m; report: {out}/mission.json, mission.png",
        file=stream,
        flush=True,
    )
    return 1 if figures["state"] == "aborted" else 0
