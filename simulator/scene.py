"""Ray casting against the tank, its clutter and the ROV: nearest hits, normals, reflectivity.

Vectorised over rays (numpy): the sonar casts a few thousand rays per ping, the LiDAR 811 per
scan. Every function returns, per ray, the distance to the nearest hit (inf for none), the unit
surface normal there, the reflectivity and an integer label of what was hit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from capsd.geometry import Array, IndexArray
from capsd.simulator.world import Tank

NONE, WALL, FLOOR, CLUTTER, ROV = 0, 1, 2, 3, 4
_EPS = 1e-9


@dataclass
class Hits:
    """Per-ray nearest hit: distance, normal, reflectivity, what (NONE/WALL/FLOOR/CLUTTER/ROV)."""

    distance: Array
    normal: Array
    reflectivity: Array
    label: Array

    @staticmethod
    def empty(n: int) -> Hits:
        return Hits(np.full(n, np.inf), np.zeros((n, 3)), np.zeros(n), np.zeros(n, dtype=np.int8))

    def take(self, t: Array, normal: Array, reflectivity: Array | float, label: int) -> None:
        """Keep (t, normal, ...) where it is nearer than what each ray has so far."""
        closer = (t > _EPS) & (t < self.distance)
        self.distance = np.where(closer, t, self.distance)
        self.normal[closer] = normal[closer] if normal.ndim == 2 else normal
        refl = np.broadcast_to(np.asarray(reflectivity, dtype=np.float64), t.shape)
        self.reflectivity = np.where(closer, refl, self.reflectivity)
        self.label = np.where(closer, np.int8(label), self.label)


@dataclass(frozen=True)
class Ellipsoid:
    """The ROV's hull as an ellipsoid: centre, R_W_R, semi-axes (x, y, z) in its body frame."""

    centre: Array
    rotation: Array
    semi_axes: Array
    reflectivity: float = 1.0


# BlueROV2 (heavy): 0.457 x 0.575 x 0.254 m.
BLUEROV2_SEMI_AXES = np.array([0.23, 0.29, 0.13])


def cast(
    origin: Array, directions: Array, tank: Tank, *, rov: Ellipsoid | None, water: str = "below"
) -> Hits:
    """Nearest hits of rays from `origin` along unit `directions` (N x 3).

    `water` "below" traces the underwater part (floor, walls below z=0, clutter, ROV);
    "above" the dry part (walls up to the freeboard, clutter above z=0), as the LiDAR sees it.
    """
    n = len(directions)
    hits = Hits.empty(n)
    o = origin.astype(np.float64)
    d = directions
    z_lo, z_hi = (-tank.depth_m, 0.0) if water == "below" else (0.0, tank.freeboard_m)
    # Walls: x = 0, x = L, y = 0, y = W (inner faces), between z_lo and z_hi.
    for axis, plane, inward in (
        (0, 0.0, 1.0),
        (0, tank.length_m, -1.0),
        (1, 0.0, 1.0),
        (1, tank.width_m, -1.0),
    ):
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (plane - o[axis]) / d[:, axis]
            point_z = o[2] + t * d[:, 2]
        t = np.where((point_z >= z_lo) & (point_z <= z_hi) & np.isfinite(t), t, np.inf)
        normal = np.zeros(3)
        normal[axis] = inward
        hits.take(t, normal, tank.wall_reflectivity, WALL)
    if water == "below":
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (-tank.depth_m - o[2]) / d[:, 2]
        hits.take(
            np.where(np.isfinite(t), t, np.inf),
            np.array([0.0, 0.0, 1.0]),
            tank.floor_reflectivity,
            FLOOR,
        )
    for box in tank.boxes:
        if (box.hi[2] <= 0.0) != (water == "below") and not (box.lo[2] < 0.0 < box.hi[2]):
            continue
        lo, hi = np.array(box.lo), np.array(box.hi)
        rays = _aimed_at(o, d, lo, hi)
        if rays.size:
            t_sub, normal_sub = _ray_box(o, d[rays], lo, hi)
            t = np.full(n, np.inf)
            t[rays] = t_sub
            normal = np.zeros_like(d)
            normal[rays] = normal_sub
            hits.take(t, normal, box.reflectivity, CLUTTER)
    for cyl in tank.cylinders:
        t, normal = _ray_cylinder(o, d, cyl.start, cyl.axis, cyl.length, cyl.radius)
        hits.take(t, normal, cyl.reflectivity, CLUTTER)
    if rov is not None and water == "below":
        t, normal = _ray_ellipsoid(o, d, rov)
        hits.take(t, normal, rov.reflectivity, ROV)
    return hits


def _ray_box(o: Array, d: Array, lo: Array, hi: Array) -> tuple[Array, Array]:
    # Directions with a zero component get a tiny one: no inf/nan, same slabs.
    safe = np.where(np.abs(d) < 1e-12, 1e-12, d)
    inv = 1.0 / safe
    t1 = (lo - o) * inv
    t2 = (hi - o) * inv
    t_min = np.minimum(t1, t2)
    t_near = t_min.max(axis=1)
    t_far = np.maximum(t1, t2).min(axis=1)
    hit = (t_near <= t_far) & (t_near > 0.0)
    t = np.where(hit, t_near, np.inf)
    normal = np.zeros_like(d)
    rows = np.flatnonzero(hit)
    if rows.size:
        # The entry face is on the axis whose slab was entered last.
        axis = np.argmax(t_min[rows], axis=1)
        normal[rows, axis] = -np.sign(d[rows, axis])
    return t, normal


def _aimed_at(o: Array, d: Array, lo: Array, hi: Array) -> IndexArray:
    """Indices of the rays that pass within the box's bounding sphere (a cheap cull)."""
    centre = (lo + hi) / 2.0
    radius = float(np.linalg.norm(hi - lo)) / 2.0
    to_centre = centre - o
    distance = float(np.linalg.norm(to_centre))
    if distance <= radius:
        return np.arange(len(d))
    cos_needed = math.cos(math.asin(min(1.0, radius / distance)))
    return np.flatnonzero(d @ (to_centre / distance) >= cos_needed - 1e-9)


def _ray_cylinder(
    o: Array, d: Array, start: tuple[float, float, float], axis: str, length: float, radius: float
) -> tuple[Array, Array]:
    k = "xyz".index(axis)
    i, j = [a for a in range(3) if a != k]
    c = np.array(start)
    ox, oy = o[i] - c[i], o[j] - c[j]
    dx, dy = d[:, i], d[:, j]
    a = dx * dx + dy * dy
    b = 2.0 * (ox * dx + oy * dy)
    cc = ox * ox + oy * oy - radius * radius
    disc = b * b - 4.0 * a * cc
    ok = (disc >= 0.0) & (a > _EPS)
    sq = np.sqrt(np.where(ok, disc, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(ok, (-b - sq) / (2.0 * a), np.inf)
    finite = np.isfinite(t)
    along = np.where(finite, o[k] + np.where(finite, t, 0.0) * d[:, k] - c[k], -1.0)
    t = np.where(finite & (along >= 0.0) & (along <= length) & (t > 0.0), t, np.inf)
    normal = np.zeros_like(d)
    finite = np.isfinite(t)
    normal[finite, i] = (ox + t[finite] * dx[finite]) / radius
    normal[finite, j] = (oy + t[finite] * dy[finite]) / radius
    return t, normal


def _ray_ellipsoid(o: Array, d: Array, rov: Ellipsoid) -> tuple[Array, Array]:
    # In the ROV's frame scaled to a unit sphere.
    r_t = rov.rotation.T
    o_b = (r_t @ (o - rov.centre)) / rov.semi_axes
    d_b = (d @ r_t.T) / rov.semi_axes
    a = np.einsum("ij,ij->i", d_b, d_b)
    b = 2.0 * (d_b @ o_b)
    c = float(o_b @ o_b) - 1.0
    disc = b * b - 4.0 * a * c
    ok = disc >= 0.0
    t = np.where(ok, (-b - np.sqrt(np.where(ok, disc, 0.0))) / (2.0 * a), np.inf)
    t = np.where(t > 0.0, t, np.inf)
    finite = np.isfinite(t)
    normal = np.zeros_like(d)
    p_b = o_b + t[finite, None] * d_b[finite]
    n_b = p_b / rov.semi_axes  # gradient of the implicit surface
    n_w = n_b @ rov.rotation.T
    normal[finite] = n_w / np.linalg.norm(n_w, axis=1, keepdims=True)
    return t, normal
