"""`capsd bench search`: how soon the ASV's follower sees a lost ROV again, in the mockup.

A ROV that lost its fix holds without positions and wanders; the follower does not know
where to. Here the follower (services/asv_follow, the demo's mockup settings: a small ASV, the
sonar 45 deg down, the tank's fixtures) gets one last fix at a stop point, its ASV going where
it is told (the carrot: a perfect autopilot), while the true ROV starts `offsets` off that fix
in one of 8 directions and drifts on at 1 cm/s (the simulated ArduSub's dead reckoning).
Seen: inside the vertical aperture, within 45 deg of the boresight, in the station's range
band. Printed: how many of the losses were seen within the horizon, within 60 s, and the
median time. Geometry only (no detector, no locator): what the search's choice of looks gives.
"""

from __future__ import annotations

import math
import statistics

import numpy as np

from capsd.harness import FOLLOW_STATION, SONAR_PITCH_DEG
from capsd.mounts import SonarMountConfig
from capsd.progress import Progress
from capsd.services.asv_follow.follower import Follower, FollowSettings
from capsd.services.asv_follow.station import StationPlanner, StationSettings
from capsd.simulator.world import make_tank, tank_bounds

STOPS_M = ((3.0, 1.8, -1.0), (2.2, 2.4, -1.0), (3.6, 1.2, -1.0))  # the lawnmower's depth
OFFSETS_M = (0.3, 0.6)
DIRECTIONS = 8
DRIFT_M_S = 0.01
HORIZON_S = 150.0
STEP_S = 0.1
HALF_FAN_RAD = math.radians(45.0)


def planner() -> StationPlanner:
    """The demo's follower geometry for the mockup."""
    demo = FOLLOW_STATION["mockup"]
    settings = StationSettings(
        min_range_m=demo["min_range_m"],
        max_range_m=demo["max_range_m"],
        hull_radius_m=demo["hull_radius_m"],
        tracking_margin_m=demo["tracking_margin_m"],
    )
    return StationPlanner(
        SonarMountConfig(pitch_deg=SONAR_PITCH_DEG["mockup"]),
        tank_bounds(make_tank("mockup")),
        settings,
    )


def seen_after(
    stations: StationPlanner, stop_m: np.ndarray, heading_rad: float, offset_m: float
) -> float | None:
    """Seconds until the drifting ROV is seen (None: not within HORIZON_S)."""
    follower = Follower(stations, FollowSettings())
    tank = stations.tank
    first = stations.choose(stop_m, np.array([tank.length_m / 2, tank.width_m / 2]), 0.0)
    if first is None:
        raise ValueError(f"no station sees the stop point {stop_m}")
    follower.on_pose(first.position_xy, first.heading_rad)
    follower.on_mode("GUIDED")
    follower.on_fix(0.0, stop_m)
    follower.step(0.0)
    away = np.array([math.cos(heading_rad), math.sin(heading_rad), 0.0])
    for k in range(1, int(HORIZON_S / STEP_S) + 1):
        t = k * STEP_S
        rov = stop_m + (offset_m + DRIFT_M_S * t) * away
        rov[:2] = tank.within_walls_xy(rov, 0.3)
        target = follower.step(t)
        assert target is not None  # GUIDED, with a pose
        follower.on_pose(target.position_xy, target.heading_rad)
        view = stations.view(target.position_xy, target.heading_rad, rov)
        s = stations.settings
        if (
            abs(view.elevation_rad) <= stations.half_aperture
            and abs(view.azimuth_rad) <= HALF_FAN_RAD
            and s.min_range_m <= view.range_m <= s.max_range_m
        ):
            return t
    return None


def run() -> int:
    stations = planner()
    trials = [
        (np.array(stop), math.tau * k / DIRECTIONS, offset)
        for stop in STOPS_M
        for offset in OFFSETS_M
        for k in range(DIRECTIONS)
    ]
    progress = Progress(len(trials), label="bench search", unit=" losses")
    times: list[float | None] = []
    for i, (stop, heading, offset) in enumerate(trials):
        times.append(seen_after(stations, stop, heading, offset))
        progress.update(i + 1)
    progress.close()
    seen = [t for t in times if t is not None]
    print(
        f"mockup, {len(trials)} losses ({len(STOPS_M)} stop points, {DIRECTIONS} directions, "
        f"{' or '.join(f'{o:g}' for o in OFFSETS_M)} m off the last fix, drifting "
        f"{DRIFT_M_S * 100:g} cm/s): seen again within {HORIZON_S:g} s: {len(seen)}; within "
        f"60 s: {sum(t <= 60.0 for t in seen)}; median {statistics.median(seen):.1f} s"
        if seen
        else "never seen again"
    )
    for point in STOPS_M:
        row = [
            "-" if t is None else f"{t:.0f}"
            for (s, _, _), t in zip(trials, times, strict=True)
            if tuple(s) == point
        ]
        print(f"  stop {point}: seconds per loss {' '.join(row)}")
    return 0
