"""The simulated world: tanks with clutter, the ROV's five trajectories, the ASV on waves.

Frames follow CONVENTIONS.md: W has its origin at a tank corner on the still-water surface,
x along the long wall, y along the short wall, z up (the floor is at z = -depth). Walls rise
`freeboard_m` above the water, which is what the ASV's LiDAR sees.

Motion is precomputed on a 10 ms grid and interpolated, deterministically from a seed. The ROV
tracks a "carrot" that runs along the trajectory's polyline at the commanded speed through a
critically damped second-order follower, so speed stays <= the commanded speed and velocity and
acceleration are continuous; its roll and pitch follow what a BlueROV2 in ArduSub does: pitch
with forward acceleration and vertical speed, roll with lateral acceleration (a few degrees).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from capsd.geometry import Array, euler_zyx_to_matrix
from capsd.simulator.sonar_look import Look
from capsd.tank import TankBounds, TankFixture

TankName = Literal["nfp", "mockup", "pond"]
# Never used to train the detector or tune anything: the benches' held-out tank.
HELD_OUT_TANK: TankName = "pond"
TUNING_TANKS: tuple[TankName, ...] = ("nfp", "mockup")
TrajectoryName = Literal["square", "lawnmower", "bouncing", "random", "two_floor"]
TRAJECTORIES: tuple[TrajectoryName, ...] = (
    "square",
    "lawnmower",
    "bouncing",
    "random",
    "two_floor",
)

GRAVITY = 9.80665
_DT = 0.01


@dataclass(frozen=True)
class Box:
    """An axis-aligned box (racks, sandbags, wall fixtures); `lo` and `hi` corners in W."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    kind: str
    reflectivity: float = 0.6


@dataclass(frozen=True)
class Cylinder:
    """A pipe or post along a world axis: `start` is one end's centre."""

    start: tuple[float, float, float]
    axis: Literal["x", "y", "z"]
    length: float
    radius: float
    kind: str
    reflectivity: float = 0.7


# The ROV's flight levels as shares of the tank's depth (Tank.rov_depths).
UPPER_LEVEL_SHARE = 0.3
LOWER_LEVEL_SHARE = 0.57


@dataclass(frozen=True)
class Tank:
    """A rectangular tank with its clutter."""

    name: str
    length_m: float
    width_m: float
    depth_m: float
    freeboard_m: float
    boxes: tuple[Box, ...] = ()
    cylinders: tuple[Cylinder, ...] = ()
    wall_reflectivity: float = 0.35
    floor_reflectivity: float = 0.25

    @property
    def rov_region(self) -> tuple[float, float, float, float]:
        """x0, x1, y0, y1 the ROV's trajectories keep to (clear of the walls)."""
        mx = min(0.25 * self.length_m, 4.0)
        my = min(0.25 * self.width_m, 4.0)
        return mx, self.length_m - mx, my, self.width_m - my

    @property
    def rov_depths(self) -> tuple[float, float]:
        """Upper and lower flight levels (z, negative).

        The lower one passes ~0.6 m over the racks, where their echoes share the ROV's range in
        the image (the paper's failure case).
        """
        return -UPPER_LEVEL_SHARE * self.depth_m, -LOWER_LEVEL_SHARE * self.depth_m


def _nfp_clutter(
    length: float, width: float, depth: float
) -> tuple[tuple[Box, ...], tuple[Cylinder, ...]]:
    boxes: list[Box] = []
    # Fuel racks on the floor, 35% of the depth high, in a grid with aisles.
    rack_h = 0.35 * depth
    for i in range(4):
        for j in range(2):
            x0 = 4.0 + i * 5.5
            y0 = 3.0 + j * 6.0
            boxes.append(Box((x0, y0, -depth), (x0 + 4.0, y0 + 4.0, -depth + rack_h), "rack", 0.8))
    # Sandbags on the floor in the aisles (the Fukushima storage tanks have hundreds).
    rng = np.random.default_rng(1234)  # the layout is part of the preset, not of the run's seed
    for _ in range(24):
        x = float(rng.uniform(1.0, length - 1.5))
        y = float(rng.uniform(1.0, width - 1.5))
        boxes.append(Box((x, y, -depth), (x + 0.6, y + 0.4, -depth + 0.25), "sandbag", 0.5))
    # Wall fixtures: brackets below water, and handrail posts above it (LiDAR features).
    for x in (6.0, 14.0, 21.0):
        boxes.append(Box((x, 0.0, -2.5), (x + 0.4, 0.3, -2.0), "bracket", 0.9))
    boxes.append(Box((0.0, 5.0, -3.5), (0.3, 5.6, -3.0), "bracket", 0.9))
    boxes.append(Box((3.0, 0.0, 0.0), (3.3, 0.15, 0.9), "post", 0.9))
    boxes.append(Box((length - 0.2, 11.0, 0.0), (length, 11.5, 0.7), "post", 0.9))
    cylinders = (
        Cylinder((0.5, 0.4, -1.0), "x", length - 1.0, 0.15, "pipe"),
        Cylinder((length - 0.4, 0.5, -5.0), "y", width - 1.0, 0.2, "pipe"),
        Cylinder((10.0, width - 0.6, -depth), "z", depth - 1.0, 0.12, "post"),
    )
    return tuple(boxes), cylinders


def _pond_clutter(
    length: float, width: float, depth: float
) -> tuple[tuple[Box, ...], tuple[Cylinder, ...]]:
    """One row of three racks, a waste skip, sandbags, a ladder, brackets, a pipe, a post."""
    boxes: list[Box] = []
    rack_h = 0.4 * depth
    for i in range(3):
        x0 = 3.0 + i * 4.5
        boxes.append(Box((x0, 3.5, -depth), (x0 + 3.5, 6.5, -depth + rack_h), "rack", 0.75))
    boxes.append(Box((14.5, 7.8, -depth), (16.5, 9.3, -depth + 1.2), "skip", 0.85))
    rng = np.random.default_rng(4321)  # the layout is part of the preset, not of the run's seed
    for _ in range(16):
        x = float(rng.uniform(1.0, length - 1.5))
        y = float(rng.uniform(1.0, width - 1.5))
        boxes.append(Box((x, y, -depth), (x + 0.5, y + 0.5, -depth + 0.3), "sandbag", 0.5))
    for y in (2.0, 8.0):
        boxes.append(Box((length - 0.3, y, -1.8), (length, y + 0.4, -1.4), "bracket", 0.9))
    boxes.append(Box((9.0, width - 0.25, 0.0), (9.3, width, 0.8), "post", 0.9))
    boxes.append(Box((0.0, 1.5, 0.0), (0.2, 1.8, 0.6), "post", 0.9))
    cylinders = (
        Cylinder((0.4, 0.5, -2.0), "y", width - 1.0, 0.12, "pipe"),
        Cylinder((6.0, 0.25, -depth), "z", depth + 0.8, 0.04, "ladder"),
        Cylinder((6.5, 0.25, -depth), "z", depth + 0.8, 0.04, "ladder"),
    )
    return tuple(boxes), cylinders


def _mockup_clutter(
    length: float, width: float, depth: float
) -> tuple[tuple[Box, ...], tuple[Cylinder, ...]]:
    boxes = (
        Box((0.6, 0.5, -depth), (1.4, 1.3, -depth + 0.5), "rack", 0.8),
        Box((3.3, 2.3, -depth), (4.1, 3.1, -depth + 0.5), "rack", 0.8),
        Box((2.0, 0.0, -0.8), (2.3, 0.15, -0.5), "bracket", 0.9),
        Box((0.0, 2.6, 0.0), (0.12, 2.9, 0.5), "post", 0.9),
    )
    cylinders = (Cylinder((0.3, width - 0.3, -1.2), "x", length - 0.6, 0.05, "pipe"),)
    return boxes, cylinders


# How tall a drawn layout's racks and skips stand (make_tank's rack_heights): "preset", the
# preset's heights; "drawn", each at even odds its preset height or one that leaves
# RACK_CLEARANCE_M (drawn in that span) between its top and the hull of a ROV at the lower
# flight level. The presets leave 36 (mockup) and 64 cm (nfp) at its centre; a survey over
# real racks flies lower (the held-out pond: 15 cm, 2 cm under the hull).
RackHeights = Literal["preset", "drawn"]
RACK_CLEARANCE_M = (0.05, 1.0)
ROV_HULL_HALF_HEIGHT_M = 0.13  # capsd.simulator.scene.BLUEROV2_SEMI_AXES[2]
MIN_RACK_HEIGHT_M = 0.3


def make_tank(
    name: TankName,
    *,
    clutter: Literal["on", "off"] = "on",
    layout_seed: int | None = None,
    rack_heights: RackHeights = "preset",
) -> Tank:
    """A tank preset: `nfp` (the paper's pool), `mockup` (its real test tank), or `pond`.

    `pond` is a storage pond of another size and layout, held out of training and tuning.
    With `layout_seed`, the clutter is the preset's kinds and numbers laid out anew (`drawn`),
    and with `rack_heights` "drawn" its racks and skips of other heights (RackHeights).
    """
    if name == "nfp":
        dims = (28.0, 16.0, 8.0, 1.0)
        boxes, cylinders = _nfp_clutter(*dims[:3])
    elif name == "pond":
        dims = (18.0, 10.0, 5.0, 0.8)
        boxes, cylinders = _pond_clutter(*dims[:3])
    else:
        dims = (4.8, 3.6, 2.0, 0.6)
        boxes, cylinders = _mockup_clutter(*dims[:3])
    if clutter == "off":
        boxes, cylinders = (), ()
    elif layout_seed is not None:
        # The layout's own stream: a run's other draws (noise, looks) stay as they were.
        rng = np.random.default_rng([layout_seed % 2**32, 0x1A70])
        boxes, cylinders = drawn(boxes, cylinders, dims[:3], rng)
        if rack_heights == "drawn":
            # A stream of its own: the layout stays as "preset" heights draw it.
            heights = np.random.default_rng([layout_seed % 2**32, 0x4AC5])
            boxes = _drawn_heights(boxes, dims[2], heights)
    return Tank(name, *dims, boxes=boxes, cylinders=cylinders)


def _drawn_heights(
    boxes: tuple[Box, ...], depth: float, rng: np.random.Generator
) -> tuple[Box, ...]:
    """Each rack and skip at even odds its own height, else RACK_CLEARANCE_M under the ROV."""
    lower = -LOWER_LEVEL_SHARE * depth  # Tank.rov_depths' lower flight level
    out: list[Box] = []
    for b in boxes:
        if b.kind in ("rack", "skip") and rng.random() < 0.5:
            clearance = float(rng.uniform(*RACK_CLEARANCE_M))
            top = max(lower - ROV_HULL_HALF_HEIGHT_M - clearance, b.lo[2] + MIN_RACK_HEIGHT_M)
            b = replace(b, hi=(b.hi[0], b.hi[1], top))
        out.append(b)
    return tuple(out)


# How far a drawn layout moves things: floor objects (racks, skips) in the plane, fixtures
# along their wall, pipes along the walls up or down.
_FLOOR_SHIFT_M = 0.75
_WALL_SHIFT_M = 1.5
_PIPE_SHIFT_M = 0.5


def drawn(
    boxes: tuple[Box, ...],
    cylinders: tuple[Cylinder, ...],
    size: tuple[float, float, float],
    rng: np.random.Generator,
) -> tuple[tuple[Box, ...], tuple[Cylinder, ...]]:
    """The same kinds and numbers of clutter, laid out anew (a run's own tank layout).

    Sandbags anywhere on the floor; racks and skips shifted in the plane; wall fixtures slid
    along their wall; pipes along the walls raised or lowered, posts and ladders slid along
    their wall. Everything stays inside the tank.
    """
    length, width, depth = size
    limits = ((0.0, length), (0.0, width))
    out: list[Box] = []
    for b in boxes:
        lo, hi = list(b.lo), list(b.hi)
        on_wall = [k for k in (0, 1) if lo[k] <= 0.0 or hi[k] >= limits[k][1]]
        if b.kind == "sandbag":
            moves = [float(rng.uniform(1.0, limits[k][1] - 1.5)) - lo[k] for k in (0, 1)]
        elif on_wall:
            moves = [0.0, 0.0]
            moves[1 - on_wall[0]] = float(rng.uniform(-_WALL_SHIFT_M, _WALL_SHIFT_M))
        else:
            moves = [float(v) for v in rng.uniform(-_FLOOR_SHIFT_M, _FLOOR_SHIFT_M, 2)]
        for k in (0, 1):
            # Inside the tank, clear of the walls it did not touch.
            low = limits[k][0] if k in on_wall else limits[k][0] + 0.3
            high = limits[k][1] if k in on_wall else limits[k][1] - 0.3
            move = min(max(moves[k], low - lo[k]), high - hi[k])
            lo[k] = float(lo[k] + move)
            hi[k] = float(hi[k] + move)
        out.append(replace(b, lo=(lo[0], lo[1], lo[2]), hi=(hi[0], hi[1], hi[2])))
    pipes: list[Cylinder] = []
    for c in cylinders:
        start = list(c.start)
        if c.axis == "z":
            k = 0 if min(start[1], width - start[1]) < min(start[0], length - start[0]) else 1
            shifted = start[k] + float(rng.uniform(-_WALL_SHIFT_M, _WALL_SHIFT_M))
            start[k] = min(max(shifted, 0.3), limits[k][1] - 0.3)
        else:
            shifted = start[2] + float(rng.uniform(-_PIPE_SHIFT_M, _PIPE_SHIFT_M))
            start[2] = min(max(shifted, -depth + 0.5), -0.3)
        pipes.append(replace(c, start=(start[0], start[1], start[2])))
    return tuple(out), tuple(pipes)


def tank_bounds(tank: Tank) -> TankBounds:
    """The tank as the services are told it: its box and its fixtures (clutter) as boxes."""
    fixtures = [TankFixture(name=b.kind, lo_m=b.lo, hi_m=b.hi) for b in tank.boxes]
    for c in tank.cylinders:
        k = "xyz".index(c.axis)
        lo = [v - c.radius for v in c.start]
        hi = [v + c.radius for v in c.start]
        lo[k], hi[k] = c.start[k], c.start[k] + c.length
        fixtures.append(TankFixture(name=c.kind, lo_m=(lo[0], lo[1], lo[2]),
                                    hi_m=(hi[0], hi[1], hi[2])))  # fmt: skip
    return TankBounds(length_m=tank.length_m, width_m=tank.width_m, depth_m=tank.depth_m,
                      fixtures=tuple(fixtures))  # fmt: skip


def with_look(tank: Tank, look: Look, rng: np.random.Generator) -> Tank:
    """The tank with a run's floor and its ROV-sized clutter in the water column."""
    boxes = list(tank.boxes)
    cylinders = list(tank.cylinders)
    for _ in range(look.floating_clutter):
        x = float(rng.uniform(0.5, tank.length_m - 0.5))
        y = float(rng.uniform(0.5, tank.width_m - 0.5))
        z = float(rng.uniform(-0.9 * tank.depth_m, -0.3))
        reflectivity = float(rng.uniform(0.3, 0.9))
        kind = rng.integers(0, 3)
        if kind == 0:  # a buoy or a box: 0.15-0.6 m
            size = rng.uniform(0.15, 0.6, 3)
            lo = (x, y, z)
            hi = (x + float(size[0]), y + float(size[1]), min(z + float(size[2]), 0.0))
            boxes.append(Box(lo, hi, "floating", reflectivity))
        else:  # a short pipe (horizontal) or a pole (vertical)
            axis: Literal["x", "y", "z"] = (
                "z" if kind == 1 else ("x" if rng.random() < 0.5 else "y")
            )
            length = float(rng.uniform(0.3, 1.5))
            if axis == "z":
                length = min(length, -z)
            cylinders.append(
                Cylinder((x, y, z), axis, length, float(rng.uniform(0.03, 0.12)), "floating")
            )
    return replace(
        tank,
        boxes=tuple(boxes),
        cylinders=tuple(cylinders),
        floor_reflectivity=look.floor_reflectivity,
    )


# ------------------------------------------------------------------------ trajectories


def _waypoints(tank: Tank, name: TrajectoryName, rng: np.random.Generator) -> Array:
    """The polyline a trajectory follows (closed for the periodic ones)."""
    x0, x1, y0, y1 = tank.rov_region
    z_hi, z_lo = tank.rov_depths
    if name == "square":
        pts = [(x0, y0, z_hi), (x1, y0, z_hi), (x1, y1, z_hi), (x0, y1, z_hi)]
    elif name == "lawnmower":  # a survey over the racks, at the lower level
        lanes = 5
        pts = []
        for i in range(lanes):
            y = y0 + (y1 - y0) * i / (lanes - 1)
            xs = (x0, x1) if i % 2 == 0 else (x1, x0)
            pts.extend([(xs[0], y, z_lo), (xs[1], y, z_lo)])
    elif name == "bouncing":
        # A billiard ball in the region: straight legs, reflected at the edges.
        p = np.array([x0 + 0.3 * (x1 - x0), y0 + 0.2 * (y1 - y0)])
        d = np.array([math.cos(0.6), math.sin(0.6)])
        pts = []
        for _ in range(12):
            tx = ((x1 if d[0] > 0 else x0) - p[0]) / d[0]
            ty = ((y1 if d[1] > 0 else y0) - p[1]) / d[1]
            t = min(tx, ty)
            p = p + t * d
            pts.append((float(p[0]), float(p[1]), z_lo))
            if tx < ty:
                d[0] = -d[0]
            else:
                d[1] = -d[1]
    elif name == "random":
        pts = [
            (float(rng.uniform(x0, x1)), float(rng.uniform(y0, y1)), float(rng.uniform(z_lo, z_hi)))
            for _ in range(12)
        ]
    else:  # two_floor: a loop on the upper level, down, the same loop on the lower level, up
        loop = [(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)]
        pts = [(x, y, z_hi) for x, y in loop] + [(x, y, z_lo) for x, y in loop]
    return np.array(pts, dtype=np.float64)


@dataclass
class Track:
    """Positions, velocities and accelerations on a regular time grid, interpolated."""

    dt: float
    p: Array
    v: Array
    a: Array

    def at(self, t_s: float) -> tuple[Array, Array, Array]:
        x = min(max(t_s / self.dt, 0.0), len(self.p) - 1.000001)
        i = int(x)
        f = x - i
        return (
            self.p[i] + f * (self.p[i + 1] - self.p[i]),
            self.v[i] + f * (self.v[i + 1] - self.v[i]),
            self.a[i] + f * (self.a[i + 1] - self.a[i]),
        )


def _follow(targets: Array, start: Array, *, omega: float, max_speed: float, dt: float) -> Track:
    """Critically damped second-order tracking of `targets` (one per grid step)."""
    n = len(targets)
    out = np.zeros((3, n, 3))  # p, v, a
    k2, k1 = omega * omega, 2.0 * omega
    tx, ty, tz = (targets[:, i].tolist() for i in range(3))
    px, py, pz = (float(c) for c in start)
    vx = vy = vz = 0.0
    rows = []
    for k in range(n):  # plain floats: ~5x faster than numpy on 3-vectors
        ax = k2 * (tx[k] - px) - k1 * vx
        ay = k2 * (ty[k] - py) - k1 * vy
        az = k2 * (tz[k] - pz) - k1 * vz
        nx, ny, nz = vx + ax * dt, vy + ay * dt, vz + az * dt
        speed = math.sqrt(nx * nx + ny * ny + nz * nz)
        if speed > max_speed:
            scale = max_speed / speed
            nx, ny, nz = nx * scale, ny * scale, nz * scale
        # The acceleration recorded is the one the motion has (after the speed limit), or the
        # simulated accelerometer would report a push the vehicle never makes.
        ax, ay, az = (nx - vx) / dt, (ny - vy) / dt, (nz - vz) / dt
        rows.append((px, py, pz, vx, vy, vz, ax, ay, az))
        vx, vy, vz = nx, ny, nz
        px, py, pz = px + vx * dt, py + vy * dt, pz + vz * dt
    table = np.array(rows)
    out[0], out[1], out[2] = table[:, 0:3], table[:, 3:6], table[:, 6:9]
    return Track(dt, out[0], out[1], out[2])


def _carrot(points: Array, speed: float, duration_s: float, *, closed: bool, dt: float) -> Array:
    """The point running along the polyline at `speed`, sampled every `dt` for `duration_s`."""
    pts = np.vstack([points, points[:1]]) if closed else points
    seg = np.diff(pts, axis=0)
    lengths = np.linalg.norm(seg, axis=1)
    cumulative = np.concatenate([[0.0], np.cumsum(lengths)])
    total = float(cumulative[-1])
    s = np.arange(int(duration_s / dt) + 2) * dt * speed
    # Closed loops repeat; open paths go back and forth.
    s = np.mod(s, total) if closed else total - np.abs(np.mod(s, 2 * total) - total)
    idx = np.clip(np.searchsorted(cumulative, s, side="right") - 1, 0, len(seg) - 1)
    frac = (s - cumulative[idx]) / np.maximum(lengths[idx], 1e-9)
    return np.asarray(pts[idx] + seg[idx] * frac[:, None], dtype=np.float64)


def rov_attitude(v: Array, a: Array, yaw: float, tilt_gain: float) -> Array:
    """R_W_R of a ROV heading `yaw` with velocity `v` and acceleration `a`.

    Positive pitch is nose down (z up, Z-Y-X): it noses down accelerating forward and while
    descending; it rolls into lateral acceleration.
    """
    c, s = math.cos(yaw), math.sin(yaw)
    a_forward = c * float(a[0]) + s * float(a[1])
    a_left = -s * float(a[0]) + c * float(a[1])
    pitch = tilt_gain * math.atan2(a_forward, GRAVITY) + math.radians(25.0) * -float(v[2])
    roll = -tilt_gain * math.atan2(a_left, GRAVITY)
    return euler_zyx_to_matrix(yaw, pitch, roll)


@dataclass
class RovMotion:
    """The ROV's trajectory: position, velocity, attitude at any time (deterministic)."""

    track: Track
    tilt_gain: float = field(default=0.6)

    def state(self, t_s: float) -> RovState:
        p, v, a = self.track.at(t_s)
        speed_xy = math.hypot(float(v[0]), float(v[1]))
        yaw = math.atan2(float(v[1]), float(v[0])) if speed_xy > 0.02 else self._yaw_before(t_s)
        return RovState(p, v, a, rov_attitude(v, a, yaw, self.tilt_gain))

    def _yaw_before(self, t_s: float) -> float:
        # Hovering: keep the last heading it had while moving.
        for back in np.arange(t_s, max(t_s - 30.0, 0.0), -0.5):
            _, v, _ = self.track.at(float(back))
            if math.hypot(float(v[0]), float(v[1])) > 0.02:
                return math.atan2(float(v[1]), float(v[0]))
        return 0.0


@dataclass(frozen=True)
class RovState:
    """The ROV's true state at one instant (W frame; rotation is R_W_R)."""

    position_m: Array
    velocity_m_s: Array
    acceleration_m_s2: Array
    rotation: Array


def rov_motion(
    tank: Tank, name: TrajectoryName, *, speed_m_s: float, duration_s: float, seed: int
) -> RovMotion:
    """Precompute `duration_s` of trajectory `name` at `speed_m_s` (<= 0.5 m/s)."""
    rng = np.random.default_rng(seed)
    points = _waypoints(tank, name, rng)
    # The lawnmower runs its lanes back and forth; the others loop.
    closed = name in ("square", "random", "two_floor", "bouncing")
    targets = _carrot(points, speed_m_s, duration_s + 5.0, closed=closed, dt=_DT)
    track = _follow(targets, targets[0], omega=1.2, max_speed=min(speed_m_s * 1.05, 0.5), dt=_DT)
    return RovMotion(track)


def floating(
    position_m: Array, *, depth_m: float, heave_m: float, period_s: float, duration_s: float
) -> RovMotion:
    """A ROV floating at the surface above `position_m`: its origin `depth_m` down, heaving."""
    n = int(duration_s / _DT) + 2
    t = np.arange(n) * _DT
    w = 2.0 * math.pi / period_s
    p = np.tile(np.array([position_m[0], position_m[1], -depth_m], dtype=np.float64), (n, 1))
    v, a = np.zeros((n, 3)), np.zeros((n, 3))
    p[:, 2] += heave_m * np.sin(w * t)
    v[:, 2] = heave_m * w * np.cos(w * t)
    a[:, 2] = -heave_m * w * w * np.sin(w * t)
    return RovMotion(Track(_DT, p, v, a))


def hovering(position_m: Array, *, duration_s: float = 10.0) -> RovMotion:
    """A ROV that stays at `position_m` (what a stationary ASV faces when the ROV flies live)."""
    n = int(duration_s / _DT) + 2
    p = np.tile(np.asarray(position_m, dtype=np.float64), (n, 1))
    return RovMotion(Track(_DT, p, np.zeros((n, 3)), np.zeros((n, 3))))


def profiling(
    position_m: Array,
    *,
    top_z_m: float,
    bottom_z_m: float,
    duration_s: float,
    period_s: float = 120.0,
) -> RovMotion:
    """A ROV holding its place in the plane while it goes down and up (the pitch manoeuvre).

    From `top_z_m` down to `bottom_z_m` and back up, one round trip every `period_s`,
    the depth a raised cosine (no jerk at the turns): a pilot holding position and changing
    depth slowly, so the ROV passes through the sonar's vertical aperture from above its top
    edge to below its bottom edge and back (capsd.pitch_calibration).
    """
    n = int(duration_s / _DT) + 2
    t = np.arange(n) * _DT
    w = 2.0 * math.pi / period_s
    mid, half = 0.5 * (top_z_m + bottom_z_m), 0.5 * (top_z_m - bottom_z_m)
    p = np.tile(np.array([position_m[0], position_m[1], 0.0], dtype=np.float64), (n, 1))
    v, a = np.zeros((n, 3)), np.zeros((n, 3))
    p[:, 2] = mid + half * np.cos(w * t)
    v[:, 2] = -half * w * np.sin(w * t)
    a[:, 2] = -half * w * w * np.cos(w * t)
    return RovMotion(Track(_DT, p, v, a))


def profile_depths(tank: Tank) -> tuple[float, float]:
    """(top, bottom) z of the pitch manoeuvre: 0.4 m under the surface to the lower flight level.

    No deeper than the lower flight level (it passes ~0.6 m over the racks' tops), and at
    least 0.8 m down in a shallow tank.
    """
    return -0.4, min(-0.8, tank.rov_depths[1])


# Beyond the aperture's nominal edges (besides the ROV's own half height seen from there): the
# echo fades 3-6 deg outside them (fitted half widths 13.3-15.6 deg against the 10 deg
# aperture), its edges' softness twice over (1-1.5 deg each), and a pitch error of up to 2 deg.
PROFILE_EDGE_MARGIN_DEG = 10.0
PROFILE_TOP_Z_M = -0.3  # the ROV's top 0.17 m under the surface
PROFILE_FLOOR_CLEARANCE_M = 0.6  # over the floor's sandbags and debris


def profile_span(
    tank: Tank,
    *,
    distance_m: float,
    sonar_z_m: float,
    pitch_rad: float,
    half_aperture_rad: float,
    rov_half_height_m: float,
) -> tuple[float, float]:
    """(top, bottom) z for the pitch manoeuvre at a given horizontal distance from the sonar.

    From `PROFILE_EDGE_MARGIN_DEG` (and the ROV's half height seen from there) above the
    aperture's top edge to as far below its bottom edge, as the surface and the floor allow: a
    second profile at another distance is what separates the sonar's pitch from its height.
    """
    margin = math.atan2(rov_half_height_m, distance_m) + math.radians(PROFILE_EDGE_MARGIN_DEG)
    top_dep = pitch_rad - half_aperture_rad - margin
    bottom_dep = min(pitch_rad + half_aperture_rad + margin, math.radians(89.0))
    top = min(sonar_z_m - distance_m * math.tan(top_dep), PROFILE_TOP_Z_M)
    bottom = max(
        sonar_z_m - distance_m * math.tan(bottom_dep),
        -tank.depth_m + PROFILE_FLOOR_CLEARANCE_M,
    )
    return top, min(bottom, top - 0.4)


NEAR_PROFILE_M = 1.5  # where a height error tilts an elevation most and the ROV still fits
# No further: in the nfp pool at 6 m the plateau fitted to the true elevations centred 1.35
# deg off the boresight (its background higher below the aperture than above), at 4 m 0.19
# deg, at 1.5 m 0.32 deg (session 27, by hand, one seed): the height came out 14-49 mm off.
FAR_PROFILE_MAX_M = 4.0
FAR_PROFILE_MARGIN_DEG = 8.0  # below the bottom edge, for the far profile's depth
MIN_PROFILE_SEPARATION_M = 1.0


def profile_distances_m(
    tank: Tank, *, sonar_z_m: float, pitch_rad: float, half_aperture_rad: float
) -> tuple[float, ...]:
    """The horizontal distances from the sonar for the pitch manoeuvre's profiles.

    Near, where a height error tilts an elevation most, and as far as the floor lets the ROV
    go below the aperture's bottom edge there. A tank too shallow for both (the mockup) gets
    none: one profile where the fixed depths straddle the boresight (`profile_depths`).
    """
    room = sonar_z_m - (-tank.depth_m + PROFILE_FLOOR_CLEARANCE_M)
    depression = pitch_rad + half_aperture_rad + math.radians(FAR_PROFILE_MARGIN_DEG)
    far = min(FAR_PROFILE_MAX_M, room / math.tan(depression))
    if far < NEAR_PROFILE_M + MIN_PROFILE_SEPARATION_M:
        return ()
    return NEAR_PROFILE_M, round(far, 2)


def symmetric_standoff_m(top_m: float, bottom_m: float, *, pitch_rad: float) -> float:
    """The horizontal distance from which two depths straddle the sonar's boresight evenly.

    `top_m` and `bottom_m` are heights below the sonar; the boresight is depressed `pitch_rad`:
    the top as far above it as the bottom below it.
    """
    lo, hi = 0.05, 100.0
    for _ in range(60):  # the depressions' sum falls as the distance grows
        mid = 0.5 * (lo + hi)
        if math.atan2(top_m, mid) + math.atan2(bottom_m, mid) > 2.0 * pitch_rad:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


# ------------------------------------------------------------------------ the ASV


@dataclass(frozen=True)
class Waves:
    """Wave-induced ASV motion: amplitudes (deg, m) and periods (s)."""

    roll_deg: float = 1.5
    pitch_deg: float = 1.0
    heave_m: float = 0.02
    roll_period_s: float = 3.7
    pitch_period_s: float = 4.3
    heave_period_s: float = 5.1


def wave_motion(w: Waves, t_s: float) -> tuple[float, float, float]:
    """(roll, pitch, heave) the waves give the ASV at `t_s` (rad, rad, m)."""
    return (
        math.radians(w.roll_deg) * math.sin(2 * math.pi * t_s / w.roll_period_s),
        math.radians(w.pitch_deg) * math.sin(2 * math.pi * t_s / w.pitch_period_s + 1.0),
        w.heave_m * math.sin(2 * math.pi * t_s / w.heave_period_s + 2.0),
    )


@dataclass
class AsvMotion:
    """The ASV's pose: a horizontal track and heading (stationary or following) plus waves."""

    track: Track
    yaw: Array  # on the track's grid, unwrapped
    waves: Waves

    def yaw_at(self, t_s: float) -> float:
        x = min(max(t_s / self.track.dt, 0.0), len(self.yaw) - 1.000001)
        i = int(x)
        return float(self.yaw[i] + (x - i) * (self.yaw[i + 1] - self.yaw[i]))

    def pose(self, t_s: float) -> tuple[Array, Array]:
        """(R_W_B, t_W_B) at `t_s`."""
        p, _, _ = self.track.at(t_s)
        roll, pitch, heave = self._wave(t_s)
        return euler_zyx_to_matrix(self.yaw_at(t_s), pitch, roll), np.array([p[0], p[1], heave])

    def _wave(self, t_s: float) -> tuple[float, float, float]:
        return wave_motion(self.waves, t_s)

    def acceleration(self, t_s: float) -> Array:
        """World acceleration of the body origin: the track's plus the heave's."""
        _, _, a = self.track.at(t_s)
        w = self.waves
        omega = 2 * math.pi / w.heave_period_s
        heave_acc = -w.heave_m * omega * omega * math.sin(omega * t_s + 2.0)
        return np.array([a[0], a[1], heave_acc])


def asv_motion(
    tank: Tank,
    rov: RovMotion,
    *,
    mode: Literal["stationary", "follow", "spin", "orbit"],
    standoff_m: float,
    waves: Waves,
    start_xy: tuple[float, float] | None,
) -> AsvMotion:
    """The ASV stays put, or follows the ROV from `standoff_m` away on the tank-centre side.

    MallARD is omnidirectional: it turns to face the ROV (the sonar looks along body x), with
    its heading following the bearing to the ROV through a first-order lag (tau 2 s). `spin`:
    it stays put and turns on the spot, one turn a minute (the calibration manoeuvre: the
    sonar sweeps every wall at every angle). `orbit`: it swings to and fro on a circle of
    `standoff_m` about where the ROV starts, ORBIT_SWING_DEG to either side of the tank-centre
    side, one swing every ORBIT_PERIOD_S, nearer and further by ORBIT_IN_OUT, facing the ROV
    and looking ORBIT_LOOK_DEG to either side of it (the range-offset manoeuvre: the line of
    sight turns about a parked ROV and dips more and less steeply, the ROV seen across the fan).
    """
    n = len(rov.track.p)
    dt = rov.track.dt
    rov_xy = rov.track.p[:, :2]
    centre = np.array([tank.length_m / 2.0, tank.width_m / 2.0])
    margin = min(1.0, 0.2 * tank.width_m)
    low, high = (
        np.array([margin, margin]),
        np.array([tank.length_m - margin, tank.width_m - margin]),
    )
    if mode in ("stationary", "spin"):
        xy = np.array(start_xy) if start_xy is not None else centre
        targets = np.tile(np.array([xy[0], xy[1], 0.0]), (n, 1))
    elif mode == "orbit":
        t = np.arange(n) * dt
        home = rov_xy[0]
        inward = centre - home
        side = math.atan2(inward[1], inward[0]) if np.linalg.norm(inward) > 0.5 else 0.0
        angle = side + math.radians(ORBIT_SWING_DEG) * np.sin(2.0 * math.pi * t / ORBIT_PERIOD_S)
        # In and out as well, so that the ROV is seen at several depression angles.
        radius = standoff_m * (1.0 + ORBIT_IN_OUT * np.sin(2.0 * math.pi * t / ORBIT_IN_OUT_S))
        xy = home + radius[:, None] * np.column_stack([np.cos(angle), np.sin(angle)])
        targets = np.column_stack([np.clip(xy, low, high), np.zeros(n)])
    else:
        away = centre - rov_xy
        norm = np.linalg.norm(away, axis=1, keepdims=True)
        # Near the centre the side is arbitrary: keep to -x of the ROV there.
        direction = np.where(norm > 0.5, away / np.maximum(norm, 1e-9), np.array([-1.0, 0.0]))
        xy = np.clip(rov_xy + standoff_m * direction, low, high)
        targets = np.column_stack([xy, np.zeros(n)])
    track = _follow(targets, targets[0], omega=0.6, max_speed=0.6, dt=dt)
    bearing = np.arctan2(rov_xy[:, 1] - track.p[:, 1], rov_xy[:, 0] - track.p[:, 0])
    bearing = np.unwrap(bearing)
    yaw = np.empty(n)
    yaw[0] = bearing[0]
    if mode == "spin":
        yaw = bearing[0] + SPIN_RAD_S * dt * np.arange(n)
        return AsvMotion(track, yaw, waves)
    if mode == "orbit":
        # Looking to either side of the ROV as well, so that it is seen across the fan: a
        # forward offset of the sonar then moves fixes across the line of sight, a range
        # offset never does (capsd.range_calibration tells them apart so).
        phase = 2.0 * math.pi * np.arange(n) * dt / ORBIT_LOOK_S
        bearing = bearing + math.radians(ORBIT_LOOK_DEG) * np.sin(phase)
        yaw[0] = bearing[0]
    alpha = dt / 2.0
    for k in range(1, n):
        yaw[k] = yaw[k - 1] + alpha * (bearing[k] - yaw[k - 1])
    return AsvMotion(track, yaw, waves)


SPIN_RAD_S = 2.0 * math.pi / 60.0  # the calibration manoeuvre: one turn a minute
# The range-offset manoeuvre: one swing there and back, 75 deg to either side, while the
# distance goes in and out by 30 % twice.
ORBIT_PERIOD_S = 120.0
ORBIT_SWING_DEG = 75.0
ORBIT_IN_OUT = 0.3
ORBIT_IN_OUT_S = 60.0
ORBIT_LOOK_DEG = 25.0  # the ROV that far to either side of the boresight, 3 times a swing
ORBIT_LOOK_S = 40.0
