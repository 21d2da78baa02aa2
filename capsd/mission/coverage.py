"""Where the ASV can watch a mission plan from: the places that see each point of its path.

Before a dive: can the follower keep this plan in the sonar's view at all, with this mount in
this tank, and how often must the ASV move? The plan's path (the ROV's way through its
waypoints, from the first) is sampled every `path_step_m`; the places the ASV may be (a grid
over the tank, kept as far from walls and keep-out boxes as the follower's stations,
`StationPlanner.clear`) are tried, the hull turned to face each point (a steered hull watches
by turning where it floats) and a tilt servo, where the mount has one, turned where the
follower turns it. A point is *seen* from a place where the follower's planner calls
the view good (inside the aperture less its margin, in the range band, conditioning bounded);
*clear* where, besides, no mapped fixture, floor or wall shares its range cell (`masked`: the
detector may miss a ROV there).

The fewest stops: the path cut into the fewest consecutive stretches that one place sees
whole (a place that sees a stretch keeps the ROV in view over it by turning alone): taking
each stretch as long as it goes is optimal for cutting a sequence this way. Each cut is a
move of the ASV, which a steered hull makes blind unless it goes along the line of sight;
points no place sees end a stretch and start the next after them.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from capsd.mission.plan import Waypoint
from capsd.services.asv_follow.station import ABEAM_PAN_MARGIN_RAD, StationPlanner

Floats = npt.NDArray[np.float64]
Bools = npt.NDArray[np.bool_]
Ints = npt.NDArray[np.int64]


@dataclass(frozen=True)
class Stretch:
    """Consecutive path samples `first`..`last` (inclusive) that the place `station_xy` sees.

    `masked`: how many of them a fixture, the floor or a wall hides from there.
    """

    first: int
    last: int
    station_xy: tuple[float, float]
    masked: int
    # The move here from the previous stop, the ROV waiting at `first` meanwhile: metres, and
    # seconds the sonar is off the ROV on the way (the planner's `blind_s`; 0 for the first).
    move_m: float = 0.0
    blind_s: float = 0.0


@dataclass(frozen=True)
class Route:
    """The ASV's place at each path sample, chosen for the least time with the sonar off the ROV.

    `places` index `Coverage.places_xy`; `blind` lists the moves that take the sonar off the
    ROV by the follower's model (`StationPlanner.blind_s`): (the sample the ROV waits at,
    seconds). Moves along the line of sight keep it in view and cost nothing.
    """

    places: Ints
    moves: int
    blind: tuple[tuple[int, float], ...]

    @property
    def blind_s(self) -> float:
        """Seconds off the ROV over the whole route."""
        return float(sum(seconds for _, seconds in self.blind))


@dataclass(frozen=True)
class Coverage:
    """What places see which points of a plan's path; see the module docstring."""

    path_m: Floats  # N x 3, the sampled path (W)
    leg: Ints  # N: the leg each sample lies on (leg k ends at waypoint k; 0: the first point)
    along_m: Floats  # N: the distance along its leg
    places_xy: Floats  # M x 2, the places tried
    seen: Bools  # N x M: the place sees the point
    clear_any: Bools  # N: some place sees the point with nothing sharing its range cell
    stretches: tuple[Stretch, ...]
    route: Route | None  # None where some point no place sees

    @property
    def seen_any(self) -> Bools:
        """Per point: some place sees it."""
        return np.asarray(self.seen.any(axis=1), dtype=np.bool_)


def sample_path(points: list[Waypoint], step_m: float) -> tuple[Floats, Ints, Floats]:
    """The path through the waypoints every `step_m` (each waypoint too): points, leg, along."""
    corners = np.array([w.position_m for w in points], dtype=np.float64)
    out: list[Floats] = [corners[0]]
    legs: list[int] = [0]
    along: list[float] = [0.0]
    for k in range(1, len(corners)):
        a, b = corners[k - 1], corners[k]
        length = float(np.linalg.norm(b - a))
        n = max(1, int(np.ceil(length / step_m - 1e-9)))
        for i in range(1, n + 1):
            out.append(a + (b - a) * (i / n))
            legs.append(k)
            along.append(length * i / n)
    return np.array(out), np.array(legs, dtype=np.int64), np.array(along)


def places(planner: StationPlanner, step_m: float) -> Floats:
    """Grid points over the tank where the follower may put the ASV (clear of walls, boxes)."""
    tank = planner.tank
    xs = np.arange(step_m / 2.0, tank.length_m, step_m)
    ys = np.arange(step_m / 2.0, tank.width_m, step_m)
    grid = [np.array([x, y]) for x in xs for y in ys]
    kept = [p for p in grid if planner.clear(p)]
    return np.array(kept, dtype=np.float64).reshape(-1, 2)


def ring_m(planner: StationPlanner, point: Floats) -> tuple[float, float]:
    """Horizontal sonar-to-point distances where a faced point sits inside the margin."""
    if planner.sonar_z - float(point[2]) <= 0.0:
        return math.inf, -math.inf  # at or above the sonar: no place sees it
    if planner.tilt is not None:
        return 0.0, planner.settings.max_range_m  # the servo moves the ring: every place in range
    far = min(planner.farthest_distance(point), planner.settings.max_range_m)
    return planner.nearest_distance(point), far


# With a pan servo the hull need not face the ROV: it is also tried turned this far off it,
# either way, within the pan's range less the follower's margin (`ABEAM_PAN_MARGIN_RAD`): the
# sonar sits ahead of the hull's origin, and a hull turned off the ROV keeps it further off.
PAN_TURNS_DEG = (45.0, 90.0)


def hull_turns(planner: StationPlanner) -> list[float]:
    """The hull's headings off facing a point to try (radians, facing first)."""
    turns = [0.0]
    if planner.pan is None:
        return turns
    left, right = planner.pan_room_rad(margin_rad=ABEAM_PAN_MARGIN_RAD)
    for deg in PAN_TURNS_DEG:
        # A hull turned left of the ROV (+) needs the pan turned right to face it, and so on.
        for side, limit in ((1.0, right), (-1.0, left)):
            turn = min(math.radians(deg), limit)
            if turn > 0.0 and side * turn not in turns:
                turns.append(side * turn)
    return turns


def fewest_stops(seen: Bools) -> list[tuple[int, int, Ints]]:
    """(first, last, places) stretches: the path cut into the fewest runs one place sees whole.

    `seen` is N x M; `places` are the indices of those that see the whole stretch. Points no
    place sees belong to no stretch.
    """
    out: list[tuple[int, int, Ints]] = []
    n = seen.shape[0]
    i = 0
    while i < n:
        if not seen[i].any():
            i += 1
            continue
        common = seen[i].copy()
        j = i
        while j + 1 < n and (common & seen[j + 1]).any():
            j += 1
            common &= seen[j]
        out.append((i, j, np.flatnonzero(common)))
        i = j + 1
    return out


# A stretch's place: of the CHOICES most central ones, the one that has the fewest of its
# points masked (each masking test is a ray cast through the fixtures: not for every place).
CHOICES = 12


# The least blind route: at each sample this many places spread over those that see it (the
# most central first, then each the farthest from those already taken), and of the places the
# route could be at on the sample before, as many again that still see it (the cheapest).
ROUTE_CANDIDATES = 16
# A metre moved costs this many seconds: of two routes equally blind, the one that moves less.
METRE_S = 0.01


def least_blind_route(
    planner: StationPlanner,
    path_m: Floats,
    places_xy: Floats,
    seen: Bools,
    off: Floats,
    *,
    candidates: int = ROUTE_CANDIDATES,
    extra: list[set[int]] | None = None,
) -> Route:
    """A place per sample, moving between samples, with the least blind time (dynamic program).

    The ROV waits at a sample while the ASV moves to a place that sees it from one that saw the
    sample before; staying costs nothing. `extra[i]`: places also tried at sample i. Needs every
    sample seen from somewhere.
    """
    n = len(path_m)
    chosen: list[Ints] = []
    cost: dict[int, float] = {}
    back: list[dict[int, int]] = []
    for i in range(n):
        sees = np.flatnonzero(seen[i])
        pick = [int(sees[np.argmin(off[i, sees])])]
        gap = np.linalg.norm(places_xy[sees] - places_xy[pick[0]], axis=1)
        while len(pick) < min(candidates, len(sees)):
            k = int(np.argmax(gap))
            pick.append(int(sees[k]))
            gap = np.minimum(gap, np.linalg.norm(places_xy[sees] - places_xy[sees[k]], axis=1))
        still = sorted((c for c in cost if seen[i, c]), key=lambda c: cost[c])[:candidates]
        here = set(pick) | set(still) | (extra[i] if extra is not None else set())
        chosen.append(np.array(sorted(here), dtype=np.int64))
        if i == 0:
            cost = {int(b): 0.0 for b in chosen[0]}
            back.append({})
            continue
        before, point = path_m[i - 1], path_m[i]
        new: dict[int, float] = {}
        links: dict[int, int] = {}
        # Each place the route may leave faces where the ROV was: once per place, not per way.
        leaving = {a: planner.facing(places_xy[a], before) for a in cost}
        for b in (int(c) for c in chosen[i]):
            heading_b = planner.facing(places_xy[b], point)
            best, arg = math.inf, -1
            for a, paid in cost.items():
                if a == b:
                    total = paid
                else:
                    a_xy = places_xy[a]
                    total = paid + METRE_S * float(np.linalg.norm(places_xy[b] - a_xy))
                    if total >= best:
                        continue  # the blind time only adds
                    total += planner.blind_s(a_xy, leaving[a], places_xy[b], heading_b, point)
                if total < best:
                    best, arg = total, a
            new[b], links[b] = best, arg
        cost = new
        back.append(links)
    route = [min(cost, key=lambda c: cost[c])]
    for i in range(n - 1, 0, -1):
        route.append(back[i][route[-1]])
    route.reverse()
    blind: list[tuple[int, float]] = []
    moves = 0
    for i in range(1, n):
        a, b = route[i - 1], route[i]
        if a == b:
            continue
        moves += 1
        seconds = planner.blind_s(
            places_xy[a],
            planner.facing(places_xy[a], path_m[i - 1]),
            places_xy[b],
            planner.facing(places_xy[b], path_m[i]),
            path_m[i],
        )
        if seconds > 0.0:
            blind.append((i, seconds))
    return Route(np.array(route, dtype=np.int64), moves, tuple(blind))


def coverage(
    planner: StationPlanner,
    points: list[Waypoint],
    *,
    path_step_m: float,
    place_step_m: float,
    on_point: Callable[[int, int], None] | None = None,
) -> Coverage:
    """Which places see which points of the plan's path (the module docstring)."""
    path, leg, along = sample_path(points, path_step_m)
    xy = places(planner, place_step_m)
    seen = np.zeros((len(path), len(xy)), dtype=bool)
    # How far off the target elevation: a stretch's place keeps it most central.
    off = np.zeros((len(path), len(xy)))
    # Where a point is seen from a place: the hull's heading, the servos' tilt and pan.
    servos: dict[tuple[int, int], tuple[float, float, float]] = {}
    turns = hull_turns(planner)
    reach = float(np.linalg.norm(planner.mount_xy)) + 0.05
    target = planner.settings.target_elevation_rad
    for i, point in enumerate(path):
        # Only places in the ring where the aperture, less its margin, meets the ROV's depth
        # (the sonar's arm and a little slack either side) can see it: the rest need no look.
        lo, hi = ring_m(planner, point)
        distance = np.linalg.norm(xy - point[:2], axis=1)
        for j in (
            int(k) for k in np.flatnonzero((distance >= lo - reach) & (distance <= hi + reach))
        ):
            facing = planner.facing(xy[j], point)
            for turn in turns:
                heading = facing + turn
                reached, tilt, pan = planner.reached_view(xy[j], heading, point)
                if planner.view_is_good(reached):
                    seen[i, j] = True
                    servos[(i, j)] = (heading, tilt, pan)
                    # Off the target at the servos' zero (the follower's stations are chosen
                    # there, the hull facing).
                    view = planner.view(xy[j], facing, point)
                    off[i, j] = abs(view.elevation_rad - target)
                    break
        if on_point is not None:
            on_point(i + 1, len(path))

    def masked(i: int, j: int) -> bool:
        heading, tilt, pan = servos[(i, j)]
        return planner.masked(xy[j], heading, path[i], tilt_rad=tilt, pan_rad=pan)

    clear_any = np.zeros(len(path), dtype=bool)
    for i in range(len(path)):
        ranked = np.flatnonzero(seen[i])
        ranked = ranked[np.argsort(off[i, ranked])]
        clear_any[i] = any(not masked(i, int(j)) for j in ranked)
    stretches: list[Stretch] = []
    extra: list[set[int]] = [set() for _ in range(len(path))]
    for first, last, common in fewest_stops(seen):
        central = common[np.argsort(off[first : last + 1, common].sum(axis=0))][:CHOICES]
        counts = [sum(masked(i, int(j)) for i in range(first, last + 1)) for j in central]
        k = int(central[int(np.argmin(counts))])
        for i in range(first, last + 1):
            extra[i].add(k)  # the route may keep to the stops: it is never blinder than they
        move_m = blind_s = 0.0
        if stretches:
            here = np.array(stretches[-1].station_xy)
            # The hull faced the ROV where it left the last stop's stretch; it waits at `first`.
            heading = planner.facing(here, path[stretches[-1].last])
            move_m = float(np.linalg.norm(xy[k] - here))
            blind_s = planner.blind_s(
                here, heading, xy[k], planner.facing(xy[k], path[first]), path[first]
            )
        station = (float(xy[k, 0]), float(xy[k, 1]))
        stretches.append(Stretch(first, last, station, int(min(counts)), move_m, blind_s))
    route = (
        least_blind_route(planner, path, xy, seen, off, extra=extra)
        if bool(seen.any(axis=1).all())
        else None
    )
    return Coverage(path, leg, along, xy, seen, clear_any, tuple(stretches), route)
