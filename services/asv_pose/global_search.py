"""Global localisation in the tank map: where is the ASV when the pose is unknown or lost.

1. Heading candidates: the scan's dominant line direction (a histogram of the directions
   between neighbouring returns, modulo 180 deg) is aligned with each map segment direction,
   both ways round: for a rectangle that is 4 candidates.
2. For each heading, every position on a `step_m` grid inside the map's bounding box is
   scored by the share of (a subsample of) scan points within `near_m` of a wall, looked up in
   a distance transform of the rasterised map; the best few go to the local matcher (ICP).
3. The refined hypotheses are ranked by inlier ratio and residual. A bare rectangle gives two
   equally good answers 180 deg apart: the heading prior (compass, launch orientation, or the
   gyro-propagated heading after a loss) picks the one within `prior_tolerance_rad`; clutter
   that breaks the symmetry in the map makes the prior unnecessary. When the prior cannot
   decide (no prior and two equal answers, or none within the tolerance), the result says
   ambiguous: the service reports lost rather than guess.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from capsd.geometry import Array
from capsd.services.asv_pose.scan_match import MatchResult, Segment, match


@dataclass(frozen=True)
class SearchSettings:
    step_m: float = 0.25
    raster_m: float = 0.05
    near_m: float = 0.15
    sample_points: int = 120
    refine_top: int = 3  # per heading
    prior_tolerance_rad: float = math.radians(60.0)
    # Two answers whose scores differ by less than this are equally good (symmetry).
    tie_margin: float = 0.05


@dataclass(frozen=True)
class SearchResult:
    best: MatchResult | None
    ambiguous: bool
    hypotheses: int
    why: str  # "" when a unique pose was found


def _angle_diff(a: float, b: float) -> float:
    return abs(math.atan2(math.sin(a - b), math.cos(a - b)))


def dominant_direction(points: Array) -> float | None:
    """The scan's strongest line direction in [0, pi), from returns 0.15-0.6 m apart.

    Neighbouring returns are closer than the range noise in a small tank: their differences
    point anywhere. Pairs a few returns apart, on the same surface, point along it.
    """
    if len(points) < 30:
        return None
    angles_list, weights_list = [], []
    for k in (3, 8, 20, 40):
        d = points[k:] - points[:-k]
        length = np.hypot(d[:, 0], d[:, 1])
        ok = (length > 0.15) & (length < 0.6)
        angles_list.append(np.mod(np.arctan2(d[ok, 1], d[ok, 0]), math.pi))
        weights_list.append(np.ones(int(ok.sum())))
    angles = np.concatenate(angles_list)
    if len(angles) < 10:
        return None
    hist, _ = np.histogram(
        angles, bins=180, range=(0.0, math.pi), weights=np.concatenate(weights_list)
    )
    # Circular smoothing over +-2 bins.
    kernel = np.array([1.0, 2.0, 3.0, 2.0, 1.0])
    padded = np.concatenate([hist[-2:], hist, hist[:2]])
    smooth = np.convolve(padded, kernel, mode="valid")
    return (int(np.argmax(smooth)) + 0.5) * math.pi / 180.0


class MapRaster:
    """The map's distance transform on a grid, for fast scoring of many poses."""

    def __init__(self, segments: tuple[Segment, ...], *, raster_m: float, margin_m: float = 1.0):
        xs = [p[0] for s in segments for p in (s.a, s.b)]
        ys = [p[1] for s in segments for p in (s.a, s.b)]
        self.x0, self.y0 = min(xs) - margin_m, min(ys) - margin_m
        self.x1, self.y1 = max(xs) + margin_m, max(ys) + margin_m
        self.res = raster_m
        w = math.ceil((self.x1 - self.x0) / raster_m) + 1
        h = math.ceil((self.y1 - self.y0) / raster_m) + 1
        img = np.full((h, w), 255, np.uint8)
        for s in segments:
            a = (round((s.a[0] - self.x0) / raster_m), round((s.a[1] - self.y0) / raster_m))
            b = (round((s.b[0] - self.x0) / raster_m), round((s.b[1] - self.y0) / raster_m))
            cv2.line(img, a, b, 0, 1)
        self.distance_m = cv2.distanceTransform(img, cv2.DIST_L2, 5).astype(np.float32) * raster_m
        self.shape = (h, w)

    def near_share(self, world: Array, near_m: float) -> Array:
        """world: (..., n, 2) points; the share within near_m of the map, per leading index."""
        col = np.clip(((world[..., 0] - self.x0) / self.res).astype(np.int32), 0, self.shape[1] - 1)
        row = np.clip(((world[..., 1] - self.y0) / self.res).astype(np.int32), 0, self.shape[0] - 1)
        near = self.distance_m[row, col] < near_m
        return np.asarray(near.mean(axis=-1), dtype=np.float64)


def search(
    points_b: Array,
    segments: tuple[Segment, ...],
    *,
    heading_prior_rad: float | None,
    settings: SearchSettings | None = None,
    raster: MapRaster | None = None,
) -> SearchResult:
    """Find (x, y, yaw) for levelled scan points anywhere in the map."""
    s = settings or SearchSettings()
    scan_dir = dominant_direction(points_b)
    if scan_dir is None:
        return SearchResult(None, False, 0, "too few structured returns for a global search")
    raster = raster or MapRaster(segments, raster_m=s.raster_m)
    map_dirs: list[float] = []
    for seg in segments:
        d = math.atan2(seg.b[1] - seg.a[1], seg.b[0] - seg.a[0]) % math.pi
        if all(_angle_diff(2 * d, 2 * m) > math.radians(2.0) for m in map_dirs):
            map_dirs.append(d)
    headings = [m - scan_dir + k * math.pi for m in map_dirs for k in (0, 1)]
    rng = np.random.default_rng(0)
    sample = points_b[rng.choice(len(points_b), min(s.sample_points, len(points_b)), replace=False)]
    gx = np.arange(raster.x0 + 1.0, raster.x1 - 1.0 + 1e-9, s.step_m)
    gy = np.arange(raster.y0 + 1.0, raster.y1 - 1.0 + 1e-9, s.step_m)
    grid = np.stack(np.meshgrid(gx, gy), axis=-1).reshape(-1, 2)
    refined: list[tuple[float, MatchResult]] = []
    for yaw in headings:
        c, sn = math.cos(yaw), math.sin(yaw)
        rotated = sample @ np.array([[c, -sn], [sn, c]]).T
        scores = raster.near_share(grid[:, None, :] + rotated[None, :, :], s.near_m)
        for k in np.argsort(scores)[::-1][: s.refine_top]:
            result = match(
                points_b, segments, x_m=float(grid[k, 0]), y_m=float(grid[k, 1]), yaw_rad=yaw
            )
            score = result.inlier_ratio - 2.0 * min(result.residual_rms_m, 0.5)
            refined.append((score, result))
    if not refined:
        return SearchResult(None, False, 0, "no hypothesis")
    refined.sort(key=lambda t: -t[0])
    top_score = refined[0][0]
    # Distinct answers that are as good as the best (the rectangle's twin, for instance).
    equals: list[MatchResult] = []
    for score, result in refined:
        if score < top_score - s.tie_margin:
            break
        if all(
            math.hypot(result.x_m - e.x_m, result.y_m - e.y_m) > 0.3
            or _angle_diff(result.yaw_rad, e.yaw_rad) > math.radians(5.0)
            for e in equals
        ):
            equals.append(result)
    if heading_prior_rad is None:
        if len(equals) > 1:
            return SearchResult(None, True, len(refined), "symmetric map and no heading prior")
        return SearchResult(equals[0], False, len(refined), "")
    within = [
        e for e in equals if _angle_diff(e.yaw_rad, heading_prior_rad) <= s.prior_tolerance_rad
    ]
    if len(within) != 1:
        why = "no" if not within else "more than one"
        return SearchResult(
            None, True, len(refined), f"{why} answer within the heading prior's tolerance"
        )
    return SearchResult(within[0], False, len(refined), "")
