"""A mission plan: waypoints and hover points in tank coordinates, read from YAML and checked.

A plan is either a lawnmower over a rectangle at one depth (lanes `spacing_m` apart, run back
and forth) or a list of inspection points, each with a dwell time. Positions are in the tank
frame W (docs/CONVENTIONS.md: z up, a submerged point has z = -depth); plans give depths as
positive metres. Every waypoint must lie inside the tank less the geofence margin: a plan that
would send the ROV into a wall fails before anything is sent, naming the point.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import msgspec
import numpy as np
import numpy.typing as npt

from capsd.config import ConfigSection, load_config
from capsd.errors import ConfigError
from capsd.geometry import distance_to_segment
from capsd.tank import TankBounds

Floats = npt.NDArray[np.float64]
Metres = Annotated[float, msgspec.Meta(ge=-10_000.0, le=10_000.0)]
MAX_WAYPOINTS = 10_000


class Lawnmower(ConfigSection, frozen=True, kw_only=True):
    """Lanes over the rectangle between two corners, at one depth."""

    corner_a_m: tuple[Metres, Metres]
    corner_b_m: tuple[Metres, Metres]
    depth_m: Annotated[float, msgspec.Meta(gt=0.0, le=11_000.0)]
    spacing_m: Annotated[float, msgspec.Meta(gt=0.05, le=100.0)] = 1.0
    along: Literal["x", "y"] = "x"  # the lanes' direction

    def __post_init__(self) -> None:
        super().__post_init__()
        # Refused before any waypoint is made: a huge area at a fine spacing is a typo.
        if 2 * lane_count(self) > MAX_WAYPOINTS:
            raise ValueError(
                f"{lane_count(self)} lanes at {self.spacing_m:g} m spacing "
                f"(at most {MAX_WAYPOINTS // 2})"
            )


class Point(ConfigSection, frozen=True, kw_only=True):
    """An inspection point: go there, hover `dwell_s`."""

    position_m: tuple[Metres, Metres]
    depth_m: Annotated[float, msgspec.Meta(gt=0.0, le=11_000.0)]
    dwell_s: Annotated[float, msgspec.Meta(ge=0.0, le=3600.0)] = 0.0


class ViewGuard(ConfigSection, frozen=True, kw_only=True):
    """The ROV waits for the ASV near the edge of the sonar's view (capsd.mission.view_guard).

    wait: while the ROV, now or `lookahead_s` ahead, is within `edge_margin_deg` of the
    vertical aperture's edge, the leg waits where the ROV is (the follower re-stations for a
    ROV that stopped), until it is `resume_margin_deg` inside again or `max_wait_s` passed;
    off: legs are flown whatever the view (a fixed sonar that cannot move).
    """

    mode: Literal["wait", "off"] = "wait"
    # Resuming 3 deg inside the edge: where the follower's stations may keep the ROV (its
    # `elevation_margin_deg`, steeper than mid aperture where a rack would mask the view); a
    # resume further in would wait out `max_wait_s` at every such station (a recorded nfp run:
    # stations at -5.8 deg, the first lane not flown in 400 s).
    edge_margin_deg: Annotated[float, msgspec.Meta(ge=0.0, le=45.0)] = 1.5
    resume_margin_deg: Annotated[float, msgspec.Meta(ge=0.0, le=45.0)] = 3.0
    lookahead_s: Annotated[float, msgspec.Meta(ge=0.0, le=10.0)] = 1.5
    max_wait_s: Annotated[float, msgspec.Meta(gt=0.0, le=600.0)] = 30.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.resume_margin_deg < self.edge_margin_deg:
            raise ValueError(
                f"`resume_margin_deg` ({self.resume_margin_deg:g}) is below `edge_margin_deg` "
                f"({self.edge_margin_deg:g}): the wait would end before it began"
            )


class Plan(ConfigSection, frozen=True, kw_only=True):
    """A mission: one lawnmower or a list of points, and how it is flown."""

    name: Annotated[str, msgspec.Meta(min_length=1, max_length=64)] = "mission"
    lawnmower: Lawnmower | None = None
    points: Annotated[tuple[Point, ...], msgspec.Meta(max_length=MAX_WAYPOINTS)] = ()
    # A waypoint is reached when the ROV's fix is this close (3D).
    accept_radius_m: Annotated[float, msgspec.Meta(gt=0.02, le=5.0)] = 0.2
    # The speed the plan is flown at (the autopilot's own limit may be lower): the GUIDED
    # target runs this x 2 s ahead of the ROV on its leg (capsd.mission.controller), so the
    # vehicle follows the line rather than cutting corners.
    speed_m_s: Annotated[float, msgspec.Meta(gt=0.0, le=2.0)] = 0.25
    # The fix must have been good for this long before a paused mission resumes.
    resume_after_s: Annotated[float, msgspec.Meta(ge=0.0, le=60.0)] = 2.0
    # Good fixes for this long before the first GUIDED: the autopilot refuses GUIDED until
    # it has had external positions (the bridge starts sending with the first good fix).
    start_after_s: Annotated[float, msgspec.Meta(ge=0.0, le=60.0)] = 2.0
    # A fix older than this, or not good, pauses the mission (the ROV holds position).
    fix_timeout_s: Annotated[float, msgspec.Meta(gt=0.0, le=5.0)] = 0.5
    # The geofence: every waypoint at least this far from the walls, the floor and the surface.
    clearance_m: Annotated[float, msgspec.Meta(ge=0.0, le=100.0)] = 0.5
    view_guard: ViewGuard = ViewGuard()

    def __post_init__(self) -> None:
        super().__post_init__()
        if (self.lawnmower is None) == (not self.points):
            raise ValueError("give either `lawnmower` or `points` (exactly one of them)")


@dataclass(frozen=True)
class Waypoint:
    """One target in W (z = -depth) and the hover time once there."""

    position_m: tuple[float, float, float]
    dwell_s: float = 0.0


def lane_count(pattern: Lawnmower) -> int:
    """Lanes no more than `spacing_m` apart, the first and last on the rectangle's edges."""
    across = 1 if pattern.along == "x" else 0
    width = abs(pattern.corner_b_m[across] - pattern.corner_a_m[across])
    return max(1, math.ceil(width / pattern.spacing_m - 1e-9)) + 1 if width > 0 else 1


def lawnmower_waypoints(pattern: Lawnmower) -> list[Waypoint]:
    """Lane ends, back and forth; lanes spread evenly so the last one is on the far edge."""
    (ax, ay), (bx, by) = pattern.corner_a_m, pattern.corner_b_m
    z = -pattern.depth_m
    if pattern.along == "x":
        lane_lo, lane_hi, across_lo, across_hi = ax, bx, ay, by
    else:
        lane_lo, lane_hi, across_lo, across_hi = ay, by, ax, bx
    lanes = lane_count(pattern)
    out: list[Waypoint] = []
    for k in range(lanes):
        across = across_lo + (across_hi - across_lo) * (k / (lanes - 1) if lanes > 1 else 0.0)
        ends = (lane_lo, lane_hi) if k % 2 == 0 else (lane_hi, lane_lo)
        for along in ends:
            xy = (along, across) if pattern.along == "x" else (across, along)
            out.append(Waypoint((float(xy[0]), float(xy[1]), z)))
    return out


def waypoints(plan: Plan) -> list[Waypoint]:
    """The plan as a list of waypoints, in order."""
    if plan.lawnmower is not None:
        return lawnmower_waypoints(plan.lawnmower)
    return [
        Waypoint((float(p.position_m[0]), float(p.position_m[1]), -p.depth_m), p.dwell_s)
        for p in plan.points
    ]


def check_geofence(
    points: list[Waypoint], tank: TankBounds, *, clearance_m: float, source: str
) -> None:
    """Every waypoint inside the geofence, else a ConfigError naming the first one outside."""
    for i, w in enumerate(points):
        if not tank.clear_of_walls(w.position_m, clearance_m):
            x, y, z = w.position_m
            raise ConfigError(
                source,
                f"waypoint {i}",
                f"({x:.2f}, {y:.2f}, {z:.2f}) m is outside the geofence: the tank "
                f"({tank.length_m:g} x {tank.width_m:g} x {tank.depth_m:g} m) less "
                f"{clearance_m:g} m from each wall, the floor and the surface",
            )


def load_plan(path: Path, *, tank: TankBounds) -> tuple[Plan, list[Waypoint]]:
    """Read, validate and geofence a plan file."""
    plan = load_config(path, Plan)
    points = waypoints(plan)  # bounded: points by the schema, lanes by Lawnmower
    check_geofence(points, tank, clearance_m=plan.clearance_m, source=str(path))
    return plan, points


def path_length_m(points: list[Waypoint]) -> float:
    """Length of the polyline through the waypoints."""
    p = np.array([w.position_m for w in points], dtype=np.float64)
    return float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1))) if len(p) > 1 else 0.0


def cross_track_m(position_m: Floats, start_m: Floats, end_m: Floats) -> float:
    """Distance from `position_m` to the segment start -> end (3D)."""
    return distance_to_segment(position_m, start_m, end_m)
