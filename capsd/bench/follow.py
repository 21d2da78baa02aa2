"""`capsd bench follow`: the closed loop's geometry alone, a mission in seconds, not minutes.

What the follower's choices give, apart from the detector: the ROV flies a mission plan
(capsd.mission's controller, the simulated ArduSub) on fixes that are its true position
(plus 2 cm of noise) whenever it is in the sonar's view from the ASV's true pose (inside the
vertical aperture, within `HALF_FAN_DEG` of the boresight, in range: what a perfect detector
and locator would fix), ten a second; the follower (services/asv_follow, the demo's settings
for the tank) drives the simulated ArduRover (the demo's stand-in, steered or lateral)
through the ASV bridge's rules (a heading alone at the station). The mission pauses and
waits as it does in the demo (its view guard from the ASV's pose). Printed: whether the
mission was done and when, the share of its time the ROV was in view, how much of that a
mapped fixture shared the ROV's range cell (where a real detector may miss it), the ASV's
nearest approach to a wall, the stations chosen, the ROV's elevation in the sonar while in
view (how near the aperture's edges it is kept) and its range (how much of it nearer than
NEAR_M, where the detector misses it often), and each loss of 5 s or more (where, and the
hull's heading off the ROV's bearing). The demo's figures (`capsd demo --mission ... --asv
follow`) add the detector's misses and the locator's refusals to these.

With `--sonar-tilt pan-tilt` the tilt servo sits on a pan servo (the mount's `pan`) that the
follower aims at the ROV with the tilt: a steered hull's moves across the line of sight
(ArduRover's GUIDED turns the hull to its way) then leave the sonar on the ROV; the mission's
view guard judges the view where the pan is, as `capsd mission run` does.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from capsd.geometry import Transform, distance_to_segment, wrap_angle
from capsd.harness import AsvMode, SonarTilt, follow_config, start_station
from capsd.mission.controller import MissionController
from capsd.mission.plan import load_plan
from capsd.mission.view_guard import view_margin_rad
from capsd.mounts import AsvDrive, SonarMountConfig
from capsd.progress import Progress
from capsd.services.asv_follow.follower import Follower
from capsd.services.asv_follow.station import StationPlanner
from capsd.simulator.guided import AsvLimits, GuidedAsv, GuidedRov
from capsd.simulator.tilt_servo import TiltServo
from capsd.simulator.world import TankName, Waves
from capsd.sonar_geometry import to_polar

STEP_S = 0.1  # fixes, the mission and the view: ten a second
FOLLOW_EVERY = 2  # the follower's commands: five a second (its command_rate_hz)
FIX_NOISE_M = 0.02
HALF_FAN_DEG = 60.0  # the fan is 130 deg wide; its edges are weak
MIN_RANGE_M = 0.3
MAX_RANGE_M = 20.0
HEADING_ONLY_WITHIN_M = 0.3  # the ASV bridge's `heading_only_within_m`
LOSS_REPORTED_S = 5.0
OFF_BINS_DEG = (15.0, 45.0)
EDGE_DEG = 2.0  # the ROV this near the aperture's edge: in view, but barely
# Nearer than this the shipped detector lost 25-45 % of the pings in the mockup pan-tilt
# demo's recordings (`capsd losses`), about 1 % beyond 1.0 m (docs/JOURNAL.md, session 45).
NEAR_M = 0.95


@dataclass
class Loss:
    """A stretch of the mission's time with the ROV out of view."""

    start_s: float
    end_s: float
    rov_m: tuple[float, float, float]
    asv_xy: tuple[float, float]
    hull_off_deg: tuple[float, float]  # the hull's heading off the ROV's bearing, min and max


@dataclass
class FollowRun:
    """One mission's figures."""

    tank: str
    drive: str
    state: str
    waypoints: tuple[int, int]  # reached, of
    mission_s: float
    steps: int = 0
    in_view: int = 0
    in_view_masked: int = 0
    nearest_wall_m: float = math.inf
    stations: int = 0
    # The ROV waiting for the ASV (the plan's view guard): legs held, seconds, waits that
    # ran out (max_wait_s) with the ROV still near the view's edge.
    waits: int = 0
    waited_s: float = 0.0
    waits_timed_out: int = 0
    # The ROV's true horizontal distance from the plan's path (its nearest leg), each step
    # from the mission's start: the squares' sum, for the RMS.
    cross_track_sq_m2: float = 0.0
    # The ROV's elevation in the sonar (deg, + above the boresight) at each step in view: how
    # near the aperture's edges the follower keeps it (where a real detector and the locator's
    # aperture test lose it first).
    elevations_deg: list[float] = field(default_factory=list)
    # ... and its range from the sonar (m): nearer than NEAR_M a real detector loses it often.
    ranges_m: list[float] = field(default_factory=list)
    losses: list[Loss] = field(default_factory=list)
    # Steps out of view by the hull's heading off the ROV's bearing (OFF_BINS_DEG's bins):
    # facing it (the ROV under or over the aperture), part turned (a move), turned away.
    out_by_off: list[int] = field(default_factory=lambda: [0] * (len(OFF_BINS_DEG) + 1))


def _in_view(
    mount: SonarMountConfig,
    sonar: Transform,
    rov_m: np.ndarray,
    *,
    from_m: float = MIN_RANGE_M,
    within_deg: float = HALF_FAN_DEG,
) -> bool:
    """Whether a perfect detector would see the ROV from this sonar pose."""
    return _view(mount, sonar, rov_m, from_m=from_m, within_deg=within_deg) is not None


def _view(
    mount: SonarMountConfig,
    sonar: Transform,
    rov_m: np.ndarray,
    *,
    from_m: float = MIN_RANGE_M,
    within_deg: float = HALF_FAN_DEG,
) -> tuple[float, float] | None:
    """The ROV's elevation (rad) and range (m) where a perfect detector would see it, else None.

    Seen from `from_m` out (a detector that misses a near ROV: `--detect-from`) and within
    `within_deg` of the boresight (one that misses it off the boresight: `--detect-within`).
    """
    p = sonar.inverse().apply(rov_m)
    try:
        r, azimuth, elevation = to_polar(mount.beam_model, p)
    except ValueError:
        return None
    seen = (
        abs(elevation) <= math.radians(mount.vertical_aperture_deg) / 2.0
        and abs(azimuth) <= math.radians(within_deg)
        and from_m <= r <= MAX_RANGE_M
    )
    return (elevation, r) if seen else None


def run_mission(
    tank_name: TankName,
    plan_path: Path,
    *,
    drive: AsvDrive,
    duration_s: float,
    seed: int = 0,
    asv_mode: AsvMode = "follow",
    tilt: SonarTilt = "fixed",
    detect_from_m: float = MIN_RANGE_M,
    detect_within_deg: float = HALF_FAN_DEG,
    progress: Progress | None = None,
) -> FollowRun:
    """Fly the plan once with the follower (or the ASV held at its start); see the module."""
    rng = np.random.default_rng(seed)
    config = follow_config(tank_name, drive=drive, tilt=tilt)
    bounds = config.tank
    plan, points = load_plan(plan_path, tank=bounds)
    mount = config.sonar
    planner = StationPlanner(
        mount, config.tank, config.motion.drive_settings(config.station.settings())
    )
    follower = Follower(planner, config.motion.settings())
    start = np.array(points[0].position_m)
    chosen = start_station(tank_name, points[0].position_m, tilt=tilt)
    if chosen is None:
        raise ValueError(f"no ASV station in the {tank_name} tank sees the plan's start")
    (sx, sy), heading_deg = chosen
    asv = GuidedAsv(
        (sx, sy),
        math.radians(heading_deg),
        waves=Waves(),
        mode="GUIDED",
        limits=AsvLimits(drive=drive),
    )
    rov = GuidedRov(start)
    rov.set_mode("POSHOLD")
    mission = MissionController(plan, points)
    follower.on_mode("GUIDED")
    # The simulator's servo (its angle on a level hull); the pilot tilts the sonar onto the ROV
    # at the start, as they turn the hull to it.
    servo = (
        None
        if mount.tilt is None
        else TiltServo(
            mount.tilt,
            zero_pitch_deg=-mount.pitch_deg,
            start_rad=planner.tilt_rad(np.array([sx, sy]), math.radians(heading_deg), start),
            pan=mount.pan,
        )
    )
    out = FollowRun(tank_name, drive, "waiting", (0, len(points)), 0.0)
    legs = [
        (np.array(p.position_m[:2]), np.array(q.position_m[:2]))
        for p, q in itertools.pairwise(points)
    ]
    last_target: np.ndarray | None = None
    lost_from: float | None = None
    lost_rows: list[tuple[np.ndarray, np.ndarray, float]] = []
    started: float | None = None
    steps = int(duration_s / STEP_S)
    for k in range(1, steps + 1):
        t = k * STEP_S
        rotation, translation = asv.pose(t)
        body = Transform(rotation, translation)
        state = rov.state(t)
        rov_m = state.position_m
        servo_rad = 0.0 if servo is None else servo.tilt_rad(t)
        pan_rad = 0.0 if servo is None else servo.pan_rad(t)
        sonar_pose = body.compose(mount.transform(tilt_rad=servo_rad, pan_rad=pan_rad))
        view = _view(mount, sonar_pose, rov_m, from_m=detect_from_m, within_deg=detect_within_deg)
        seen = view is not None
        yaw = math.atan2(float(rotation[1, 0]), float(rotation[0, 0]))
        asv_xy = np.array(translation[:2])
        follower.on_pose(asv_xy, yaw)
        asv.on_estimate(t, asv_xy)
        if seen:
            fix = rov_m + rng.normal(0.0, FIX_NOISE_M, 3)
            rov.on_estimate(t, fix)
            follower.on_fix(t, fix, state.velocity_m_s)
            mission.on_fix(good=True, position_m=(fix[0], fix[1], fix[2]), now=t)
        margin = view_margin_rad(
            asv=body,
            mount=mount,
            rov_m=rov_m,
            velocity_m_s=state.velocity_m_s,
            lookahead_s=1.5,
            pan_rad=pan_rad,
        )
        mission.on_view(margin, now=t)
        mission.on_mode(rov.mode, now=t)
        for command in mission.step(t):
            if command.kind == "hold":
                rov.set_mode("POSHOLD")
                follower.on_leg_end(t, None)
                continue
            if command.kind == "engage":
                rov.set_mode("GUIDED")
            assert command.position_m is not None
            rov.set_target(np.array(command.position_m))
            leg_end, after = mission.leg_end(command), mission.next_leg_end(command)
            follower.on_leg_end(
                t,
                None if leg_end is None else np.array(leg_end),
                None if after is None else np.array(after),
            )
        if asv_mode == "follow" and k % FOLLOW_EVERY == 0:
            target = follower.step(t)
            if servo is not None and target is not None and target.sonar_tilt_rad is not None:
                servo.aim(t, target.sonar_tilt_rad)
                if target.sonar_pan_rad is not None:
                    servo.aim_pan(t, target.sonar_pan_rad)
            if target is not None:
                at_goal = float(np.linalg.norm(asv_xy - target.position_xy))
                steady = (
                    last_target is not None
                    and float(np.linalg.norm(last_target - target.position_xy))
                    <= HEADING_ONLY_WITHIN_M / 3.0
                )
                if at_goal <= HEADING_ONLY_WITHIN_M and steady:
                    asv.set_heading(target.heading_rad)
                else:
                    asv.set_direction(target.direction)
                    asv.set_target(target.position_xy)
                    last_target = target.position_xy.copy()
        running = mission.progress.state in ("running", "paused")
        if running and started is None:
            started = t
        if started is not None and (running or mission.progress.state == "done"):
            if mission.progress.state == "done":
                break
            out.steps += 1
            off_plan = min(distance_to_segment(rov_m[:2], a, b) for a, b in legs)
            out.cross_track_sq_m2 += off_plan**2
            out.nearest_wall_m = min(
                out.nearest_wall_m,
                float(asv_xy[0]),
                float(asv_xy[1]),
                bounds.length_m - float(asv_xy[0]),
                bounds.width_m - float(asv_xy[1]),
            )
            if view is not None:
                out.in_view += 1
                out.elevations_deg.append(math.degrees(view[0]))
                out.ranges_m.append(view[1])
                if planner.masked(asv_xy, yaw, rov_m):
                    out.in_view_masked += 1
            bearing = math.atan2(float(rov_m[1] - asv_xy[1]), float(rov_m[0] - asv_xy[0]))
            off = math.degrees(wrap_angle(bearing - yaw - math.radians(mount.yaw_deg)))
            if not seen:
                out.out_by_off[int(np.searchsorted(OFF_BINS_DEG, abs(off)))] += 1
                if lost_from is None:
                    lost_from, lost_rows = t, []
                lost_rows.append((rov_m.copy(), asv_xy.copy(), off))
            elif lost_from is not None:
                _close_loss(out, lost_from, t, lost_rows)
                lost_from = None
        if progress is not None and k % 50 == 0:
            progress.update(t)
    if lost_from is not None:
        _close_loss(out, lost_from, steps * STEP_S, lost_rows)
    out.state = mission.progress.state
    reached = mission.progress.waypoint + (1 if out.state == "done" else 0)
    out.waypoints = (reached, len(points))
    out.mission_s = out.steps * STEP_S
    out.stations = follower.replans
    out.waits = mission.progress.waits
    out.waited_s = mission.progress.waited_s
    out.waits_timed_out = mission.progress.waits_timed_out
    return out


def _close_loss(
    out: FollowRun, start_s: float, end_s: float, rows: list[tuple[np.ndarray, np.ndarray, float]]
) -> None:
    if end_s - start_s < LOSS_REPORTED_S or not rows:
        return
    rov_m, asv_xy, _ = rows[len(rows) // 2]
    offs = [r[2] for r in rows]
    out.losses.append(
        Loss(
            start_s,
            end_s,
            (float(rov_m[0]), float(rov_m[1]), float(rov_m[2])),
            (float(asv_xy[0]), float(asv_xy[1])),
            (min(offs), max(offs)),
        )
    )


def run(
    tank: TankName,
    plan_path: Path,
    *,
    drive: AsvDrive,
    duration_s: float,
    seeds: int,
    asv_mode: AsvMode = "follow",
    tilt: SonarTilt = "fixed",
    detect_from_m: float = MIN_RANGE_M,
    detect_within_deg: float = HALF_FAN_DEG,
) -> int:
    """Print one line per seed and the losses; the median, mean and lowest share in view."""
    shares = []
    mount_half_deg = follow_config(tank, drive=drive).sonar.vertical_aperture_deg / 2.0
    for seed in range(seeds):
        progress = Progress(duration_s, label=f"bench follow seed {seed}", unit=" s")
        r = run_mission(tank, plan_path, drive=drive, duration_s=duration_s, seed=seed,
                        asv_mode=asv_mode, tilt=tilt, detect_from_m=detect_from_m,
                        detect_within_deg=detect_within_deg, progress=progress)  # fmt: skip
        progress.close()
        share = r.in_view / r.steps if r.steps else 0.0
        shares.append(share)
        masked = r.in_view_masked / r.steps if r.steps else 0.0
        asv: str = "held" if asv_mode == "station" else drive
        if tilt != "fixed":
            asv += ", sonar on a tilt servo" + (" on a pan servo" if tilt == "pan-tilt" else "")
        print(
            f"{tank} {plan_path.name} (ASV {asv}) seed {seed}: mission {r.state}, waypoint "
            f"{r.waypoints[0]} of {r.waypoints[1]}, {r.mission_s:.0f} s; ROV in view "
            f"{100 * share:.1f} % of it ({100 * masked:.1f} % with a fixture in its range "
            f"cell); ASV origin nearest a wall {r.nearest_wall_m:.2f} m; {r.stations} stations; "
            f"the ROV waited for the ASV {r.waits} times, {r.waited_s:.0f} s "
            f"({r.waits_timed_out} ran out); the ROV's true cross-track RMS "
            f"{1000 * math.sqrt(r.cross_track_sq_m2 / max(r.steps, 1)):.0f} mm"
        )
        if r.elevations_deg:
            e = np.array(r.elevations_deg)
            edge = mount_half_deg - EDGE_DEG
            print(
                f"  the ROV's elevation in the sonar while in view: median {np.median(e):+.1f} "
                f"deg (p10 {np.percentile(e, 10):+.1f}, p90 {np.percentile(e, 90):+.1f}), "
                f"{100 * np.mean(np.abs(e) > edge):.1f} % within {EDGE_DEG:g} deg of an edge; "
                f"its range median {np.median(r.ranges_m):.2f} m, "
                f"{100 * np.mean(np.array(r.ranges_m) < NEAR_M):.1f} % nearer than {NEAR_M:g} m"
            )
        bins = [0.0, *OFF_BINS_DEG, 180.0]
        print(
            "  out of view, by the hull's heading off the ROV's bearing: "
            + ", ".join(
                f"{lo:g}-{hi:g} deg {n * STEP_S:.0f} s"
                for lo, hi, n in zip(bins[:-1], bins[1:], r.out_by_off, strict=True)
            )
        )
        for loss in r.losses:
            print(
                f"  out of view {loss.start_s:6.1f}-{loss.end_s:6.1f} s "
                f"({loss.end_s - loss.start_s:4.1f} s): ROV ({loss.rov_m[0]:.1f}, "
                f"{loss.rov_m[1]:.1f}, {loss.rov_m[2]:.1f}), ASV ({loss.asv_xy[0]:.1f}, "
                f"{loss.asv_xy[1]:.1f}), hull {loss.hull_off_deg[0]:.0f} to "
                f"{loss.hull_off_deg[1]:.0f} deg off the ROV's bearing"
            )
    if seeds > 1:
        print(
            f"median in view over {seeds} seeds: {100 * float(np.median(shares)):.1f} % "
            f"(mean {100 * float(np.mean(shares)):.2f} %, lowest {100 * min(shares):.1f} %)"
        )
    return 0
