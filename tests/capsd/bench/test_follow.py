"""`capsd bench follow`: what counts as in view, and a mission flown on it."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

import numpy as np

from capsd.bench.follow import FollowRun, _in_view, run_mission
from capsd.geometry import Transform
from capsd.mounts import SonarMountConfig

REPO = Path(__file__).resolve().parents[3]


def test_in_view_is_the_aperture_and_the_fan() -> None:
    mount = SonarMountConfig()  # 30 deg down, 20 deg aperture
    sonar = Transform.from_euler_zyx((0.0, 0.0, 0.0), yaw_rad=0.0, pitch_rad=0.0, roll_rad=0.0)
    sonar = sonar.compose(mount.transform())
    z = float(sonar.translation[2])

    def at(distance_m: float, bearing_deg: float) -> np.ndarray:
        b = math.radians(bearing_deg)
        return np.array([distance_m * math.cos(b), distance_m * math.sin(b), z - 3.0])

    mid = 3.0 / math.tan(math.radians(30.0))
    assert _in_view(mount, sonar, at(mid, 0.0))
    assert not _in_view(mount, sonar, at(mid * 0.6, 0.0))  # under the aperture
    assert not _in_view(mount, sonar, at(mid * 2.0, 0.0))  # above it
    assert not _in_view(mount, sonar, at(mid, 90.0))  # off the fan
    # A detector that misses a near ROV (`--detect-from`): the ROV is 5.74 m off.
    assert _in_view(mount, sonar, at(mid, 0.0), from_m=5.7)
    assert not _in_view(mount, sonar, at(mid, 0.0), from_m=5.8)
    # One that misses it off the boresight (`--detect-within`).
    assert _in_view(mount, sonar, at(mid, 12.0))
    assert _in_view(mount, sonar, at(mid, 12.0), within_deg=15.0)
    assert not _in_view(mount, sonar, at(mid, 12.0), within_deg=10.0)


def _fly(tank: Literal["nfp", "mockup"], duration_s: float, **options: object) -> FollowRun:
    plan = REPO / "deploy" / "missions" / f"{tank}-lawnmower.yaml"
    return run_mission(tank, plan, drive="steered", duration_s=duration_s, **options)  # type: ignore[arg-type]


def test_a_mockup_mission_starts_in_view_and_is_scored() -> None:
    run = _fly("mockup", 40.0)
    assert run.state in ("running", "paused", "done")
    assert run.steps > 300  # the mission started within a few seconds
    assert 0 < run.in_view <= run.steps
    assert run.waypoints[0] >= 1
    assert run.nearest_wall_m > 1.0
    # The ROV's true path against the plan: a perfect fix keeps it within centimetres.
    assert 0.0 < math.sqrt(run.cross_track_sq_m2 / run.steps) < 0.15
    # The mockup's lanes run 1 m from the sonar: the ROV waits for the ASV within seconds,
    # and its waits are part of the mission's time.
    assert run.waits >= 1
    assert 0.0 < run.waited_s < run.mission_s
    # Each step in view has the ROV's elevation, inside the 20 deg aperture.
    assert len(run.elevations_deg) == run.in_view
    assert max(abs(e) for e in run.elevations_deg) <= 10.0
    # ... and its range from the sonar: the ROV 1 m deep under a sonar 0.2 m deep, in a 4.8 m tank.
    assert len(run.ranges_m) == run.in_view
    assert 0.7 < min(run.ranges_m) <= max(run.ranges_m) < 4.8


def test_an_asv_held_at_its_start_does_not_move() -> None:
    """The stationary comparison: no follower, the ASV where the pilot put it."""
    held = _fly("nfp", 30.0, asv_mode="station")
    assert held.stations == 0
    assert held.steps > 0
    assert held.in_view > 0  # it starts where the pilot's station sees it


def test_a_sonar_on_a_tilt_servo_keeps_the_rov_centred() -> None:
    """The follower drives the servo: the ROV sits nearer the boresight than on a fixed mount."""
    fixed = _fly("mockup", 40.0)
    servo = _fly("mockup", 40.0, tilt="servo")
    assert servo.steps > 300
    assert servo.in_view > 0
    spread = [float(np.percentile(np.abs(r.elevations_deg), 90)) for r in (fixed, servo)]
    assert spread[1] < spread[0]
    assert spread[1] < 4.0


def test_a_pan_servo_keeps_the_rov_in_view_where_a_steered_hull_turns_off_it() -> None:
    """The mockup, seed 0: the hull's one crossing of the run no longer loses the ROV."""
    tilt_only = _fly("mockup", 900.0, tilt="servo")
    panned = _fly("mockup", 900.0, tilt="pan-tilt")
    assert tilt_only.losses  # the crossing (the hull's way across the ROV's bearing)
    assert panned.state == "done"
    assert panned.in_view / panned.steps >= 0.99 > tilt_only.in_view / tilt_only.steps
    assert not panned.losses
