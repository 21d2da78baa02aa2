"""A reference system's frame and clock aligned to the tank's, from matched trajectories.

A motion-capture system states the ROV's position in its own frame and on its own clock. From
the fixes (tank frame, the ASV's clock) and the reference track, this module estimates

- the similarity (rotation, translation, optionally scale) taking reference positions into the
  tank frame: Umeyama's closed form (SVD), weighted, iterated so that outliers (marker swaps,
  wrong fixes) get no weight (residuals beyond 3 robust sigmas, sigma from the median absolute
  residual);
- the clock offset (how far the reference's stamps run ahead of the fixes'), by minimising the
  robust fit's residual over offsets: a grid, then a golden-section search around its best.

Any constant bias the fixes share is absorbed by the fitted transform: an aligned evaluation
measures the fixes' scatter and their shape errors, not a common shift (that needs a surveyed
transform, `Similarity` given from outside).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from capsd.geometry import matrix_to_euler_zyx

# Residual distances beyond this many robust per-axis sigmas get no weight in the fit (a 3-D
# Gaussian error's distance exceeds 5 sigma once in 100,000).
OUTLIER_SIGMAS = 5.0
# The median distance of a 3-D Gaussian error, in per-axis sigmas.
_MEDIAN_DISTANCE_SIGMAS = 1.5382
# A normal law's sigma over its median absolute deviation.
_MAD_SIGMAS = 1.4826
# Never call a residual an outlier below this (a perfect reference and fixes would make
# the robust sigma ~0 and every point an outlier).
OUTLIER_FLOOR_M = 0.01


def rotation_angle_deg(rotation: np.ndarray) -> float:
    """The angle (deg) of a rotation matrix about its axis."""
    cos = (float(np.trace(rotation)) - 1.0) / 2.0
    return math.degrees(math.acos(max(-1.0, min(1.0, cos))))


@dataclass(frozen=True)
class Similarity:
    """p_tank = scale * rotation @ p_reference + translation_m."""

    rotation: np.ndarray
    translation_m: np.ndarray
    scale: float = 1.0

    def apply(self, points: np.ndarray) -> np.ndarray:
        out: np.ndarray = self.scale * points @ self.rotation.T + self.translation_m
        return out

    def inverse(self) -> Similarity:
        rotation = self.rotation.T
        return Similarity(rotation, -rotation @ self.translation_m / self.scale, 1.0 / self.scale)

    def describe(self) -> dict[str, float]:
        yaw, pitch, roll = matrix_to_euler_zyx(self.rotation)
        return {
            "yaw_deg": round(math.degrees(yaw), 4),
            "pitch_deg": round(math.degrees(pitch), 4),
            "roll_deg": round(math.degrees(roll), 4),
            "rotation_angle_deg": round(rotation_angle_deg(self.rotation), 4),
            "x_m": round(float(self.translation_m[0]), 4),
            "y_m": round(float(self.translation_m[1]), 4),
            "z_m": round(float(self.translation_m[2]), 4),
            "scale": round(self.scale, 6),
        }


def umeyama(
    source: np.ndarray,
    target: np.ndarray,
    weights: np.ndarray | None = None,
    *,
    with_scale: bool = False,
) -> Similarity:
    """The least-squares similarity taking `source` (n x 3) onto `target` (Umeyama 1991)."""
    w = np.ones(len(source)) if weights is None else np.asarray(weights, dtype=np.float64)
    if np.count_nonzero(w) < 3:
        raise ValueError("an alignment needs at least 3 weighted point pairs")
    w = w / w.sum()
    mu_s, mu_t = w @ source, w @ target
    s, t = source - mu_s, target - mu_t
    covariance = (t * w[:, None]).T @ s
    u, d, vt = np.linalg.svd(covariance)
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0.0:  # a reflection is no rotation
        sign[2, 2] = -1.0
    rotation = u @ sign @ vt
    scale = 1.0
    if with_scale:
        variance = float(w @ np.sum(s**2, axis=1))
        scale = float(np.sum(d * np.diag(sign)) / variance) if variance > 0.0 else 1.0
    return Similarity(rotation, mu_t - scale * rotation @ mu_s, scale)


@dataclass(frozen=True)
class RobustFit:
    transform: Similarity
    residuals_m: np.ndarray  # every pair's distance after the fit
    inliers: np.ndarray  # bool: the pairs that carried weight
    sigma_m: float  # the robust per-axis residual scale (from the median distance)
    independent: float  # how many independent pairs the inliers are worth (autocorrelation)
    # The largest axis's robust scale (MAD): fixes err more across than in depth (the pressure
    # sensor), so the 3-D median understates the horizontal scatter.
    worst_axis_sigma_m: float = 0.0


def robust_fit(
    source: np.ndarray, target: np.ndarray, *, with_scale: bool = False, iterations: int = 8
) -> RobustFit:
    """`umeyama` refitted on the pairs within OUTLIER_SIGMAS of the previous fit."""
    inliers = np.ones(len(source), dtype=bool)
    transform = umeyama(source, target, with_scale=with_scale)
    for _ in range(iterations):
        residuals = np.linalg.norm(transform.apply(source) - target, axis=1)
        sigma = float(np.median(residuals[inliers])) / _MEDIAN_DISTANCE_SIGMAS
        keep = residuals <= max(OUTLIER_SIGMAS * sigma, OUTLIER_FLOOR_M)
        if np.count_nonzero(keep) < 3 or np.array_equal(keep, inliers):
            break
        inliers = keep
        transform = umeyama(source, target, inliers.astype(np.float64), with_scale=with_scale)
    vectors = transform.apply(source) - target
    residuals = np.linalg.norm(vectors, axis=1)
    sigma = float(np.median(residuals[inliers])) / _MEDIAN_DISTANCE_SIGMAS
    kept = vectors[inliers]
    mad = np.median(np.abs(kept - np.median(kept, axis=0)), axis=0)
    worst = float(np.max(mad)) * _MAD_SIGMAS
    return RobustFit(
        transform, residuals, inliers, sigma, independent_count(kept), max(worst, sigma)
    )


def independent_count(series: np.ndarray, *, max_lag: int = 200) -> float:
    """What n correlated samples are worth: n / (1 + 2 sum of autocorrelations), worst axis.

    The sum runs until the autocorrelation first drops below 0.05.
    """
    n = len(series)
    worst = float(n)
    for axis in range(series.shape[1]):
        x = series[:, axis] - series[:, axis].mean()
        variance = float(x @ x)
        if variance <= 0.0:
            continue
        total = 0.0
        for lag in range(1, min(max_lag, n - 1)):
            rho = float(x[:-lag] @ x[lag:]) / variance
            if rho < 0.05:
                break
            total += rho
        worst = min(worst, n / (1.0 + 2.0 * total))
    return max(worst, 1.0)


# A reference sample further than this (and than SPIKE_SIGMAS robust sigmas) from the median
# of its neighbours is a jump no vehicle makes: a marker swap, a mislabelled body.
SPIKE_FLOOR_M = 0.01
SPIKE_SIGMAS = 6.0
_SPIKE_WINDOW = 7


def spikes(positions: np.ndarray) -> np.ndarray:
    """Which samples of a track jump off it (bool), judged against a running median."""
    n = len(positions)
    if n < _SPIKE_WINDOW:
        return np.zeros(n, dtype=bool)
    half = _SPIKE_WINDOW // 2
    padded = np.pad(positions, ((half, half), (0, 0)), mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, _SPIKE_WINDOW, axis=0)
    deviation = np.linalg.norm(positions - np.median(windows, axis=2), axis=1)
    scale = float(np.median(deviation)) / _MEDIAN_DISTANCE_SIGMAS
    return np.asarray(deviation > max(SPIKE_FLOOR_M, SPIKE_SIGMAS * scale))


@dataclass(frozen=True)
class Track:
    """A time-ordered position track, interpolated linearly; no value across a gap."""

    stamps_ns: np.ndarray  # int64, increasing
    positions_m: np.ndarray  # n x 3
    max_gap_s: float

    spikes: int = 0  # samples dropped as jumps off the track (marker swaps)

    @classmethod
    def of(cls, stamps_ns: np.ndarray, positions_m: np.ndarray, *, max_gap_s: float) -> Track:
        """Sorted, repeated stamps and spikes dropped (the track interpolates across them)."""
        order = np.argsort(stamps_ns, kind="stable")
        stamps, positions = np.asarray(stamps_ns)[order], np.asarray(positions_m)[order]
        unique = np.concatenate(([True], np.diff(stamps) > 0))  # a repeated stamp: the first
        stamps, positions = stamps[unique], positions[unique]
        spiky = spikes(positions)
        return cls(stamps[~spiky], positions[~spiky], max_gap_s, int(np.count_nonzero(spiky)))

    def at(self, stamps_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(positions n x 3, valid n): valid where both neighbours lie within max_gap_s."""
        t0 = self.stamps_ns[0]
        x = (self.stamps_ns - t0) / 1e9
        q = (np.asarray(stamps_ns) - t0) / 1e9
        right = np.searchsorted(x, q, side="left")
        inside = (right > 0) & (right < len(x))
        exact = (right < len(x)) & (x[np.minimum(right, len(x) - 1)] == q)
        r = np.clip(right, 1, len(x) - 1)
        gap = x[r] - x[r - 1]
        valid = exact | (inside & (gap <= self.max_gap_s))
        out = np.column_stack([np.interp(q, x, self.positions_m[:, k]) for k in range(3)])
        return out, valid


# What counts as determined: the worst axis's rotation and the clock offset this well known.
MAX_ROTATION_SIGMA_DEG = 0.05
MAX_OFFSET_SIGMA_MS = 2.0


@dataclass(frozen=True)
class Alignment:
    transform: Similarity  # reference frame -> tank frame
    offset_ns: int  # the reference's stamps run this far ahead of the fixes'
    fit: RobustFit
    pairs: int
    spread_m: tuple[float, float, float]  # the matched track's std along its principal axes
    speed_rms_m_s: float  # how fast the reference moved at the matched stamps
    offset_given: bool = False

    def rotation_sigma_deg(self) -> float:
        """About the worst axis (the track's longest): scatter over lever arm, approximately."""
        lever = math.hypot(self.spread_m[1], self.spread_m[2])
        n = self.fit.independent
        return math.degrees(self.fit.sigma_m / (lever * math.sqrt(n))) if lever > 0 else math.inf

    def offset_sigma_ms(self) -> float:
        """The clock offset's uncertainty: the worst axis's scatter over speed, approximately.

        An offset moves every pair along the ROV's motion, mostly horizontal, where the fixes
        scatter most: the worst axis's scale, not the 3-D average.
        """
        if self.offset_given:
            return 0.0
        n = self.fit.independent
        speed = self.speed_rms_m_s
        sigma = self.fit.worst_axis_sigma_m
        return 1000 * sigma / (speed * math.sqrt(n)) if speed > 0 else math.inf

    def problems(self) -> list[str]:
        """Why the alignment cannot be trusted (empty when it can)."""
        out = []
        if self.rotation_sigma_deg() > MAX_ROTATION_SIGMA_DEG:
            out.append(
                f"rotation not determined (about {self.rotation_sigma_deg():.2g} deg): the dive "
                f"spans {self.spread_m[0]:.2f} x {self.spread_m[1]:.2f} x "
                f"{self.spread_m[2]:.2f} m (std), worth {self.fit.independent:.0f} independent "
                "fixes; a longer dive, or one over a wider area, determines it"
            )
        if self.offset_sigma_ms() > MAX_OFFSET_SIGMA_MS:
            out.append(
                f"clock offset not determined (about {self.offset_sigma_ms():.2g} ms): the ROV "
                f"moved at {self.speed_rms_m_s:.2f} m/s rms; a longer or livelier dive "
                "determines it, or give the offset (--clock-offset-ms)"
            )
        return out

    def summary(self) -> dict[str, Any]:
        inliers = self.fit.inliers
        return {
            **self.transform.describe(),
            "clock_offset_ms": round(self.offset_ns / 1e6, 2),
            "clock_offset_given": self.offset_given,
            "pairs": self.pairs,
            "inliers": int(np.count_nonzero(inliers)),
            "residual_rms_mm": round(
                float(np.sqrt(np.mean(self.fit.residuals_m[inliers] ** 2))) * 1000, 2
            ),
            "residual_sigma_mm": round(self.fit.sigma_m * 1000, 2),
            "independent_pairs": round(self.fit.independent, 1),
            "spread_m": [round(v, 3) for v in self.spread_m],
            "rotation_sigma_deg": round(self.rotation_sigma_deg(), 4),
            "offset_sigma_ms": round(self.offset_sigma_ms(), 3),
            "problems": self.problems(),
        }


def _spread(points: np.ndarray) -> tuple[float, float, float]:
    centred = points - points.mean(axis=0)
    values = np.sqrt(np.maximum(np.linalg.eigvalsh(centred.T @ centred / len(points)), 0.0))
    return float(values[2]), float(values[1]), float(values[0])


def _speed_rms(stamps_ns: np.ndarray, points: np.ndarray) -> float:
    dt = np.diff(stamps_ns) / 1e9
    step = np.linalg.norm(np.diff(points, axis=0), axis=1)
    usable = (dt > 0) & (dt < 1.0)
    if not np.any(usable):
        return 0.0
    return float(np.sqrt(np.mean((step[usable] / dt[usable]) ** 2)))


def _fit_at(
    offset_s: float,
    fix_stamps_ns: np.ndarray,
    fixes_m: np.ndarray,
    reference: Track,
    *,
    with_scale: bool,
) -> tuple[RobustFit, np.ndarray] | None:
    ref, valid = reference.at(fix_stamps_ns + round(offset_s * 1e9))
    if np.count_nonzero(valid) < 10:
        return None
    return robust_fit(ref[valid], fixes_m[valid], with_scale=with_scale), valid


def _cost(fit: RobustFit | None, clip_m: float) -> float:
    """Truncated quadratic: outliers count as clip_m, so no offset wins by discarding pairs."""
    if fit is None:
        return math.inf
    return float(np.mean(np.minimum(fit.residuals_m, clip_m) ** 2))


def align(
    fix_stamps_ns: np.ndarray,
    fixes_m: np.ndarray,
    reference: Track,
    *,
    max_offset_s: float = 1.0,
    with_scale: bool = False,
    offset_s: float | None = None,
) -> Alignment:
    """The transform and clock offset that best lay the reference onto the fixes.

    With `offset_s`, the clock offset is taken as given and only the transform is fitted.
    """
    stamps = np.asarray(fix_stamps_ns, dtype=np.int64)
    fixes = np.asarray(fixes_m, dtype=np.float64)
    given = offset_s is not None

    def fit(offset: float) -> tuple[RobustFit, np.ndarray] | None:
        return _fit_at(offset, stamps, fixes, reference, with_scale=with_scale)

    if offset_s is None:
        # A grid fine enough that the ROV (<= 0.5 m/s) moves less than the fixes' scatter.
        step = 0.02
        grid = np.arange(-max_offset_s, max_offset_s + step / 2, step)
        fits = [fit(float(o)) for o in grid]
        sigmas = [f[0].sigma_m for f in fits if f is not None]
        if not sigmas:
            raise ValueError("the reference overlaps fewer than 10 fixes at every clock offset")
        clip = max(OUTLIER_SIGMAS * min(sigmas), OUTLIER_FLOOR_M)
        costs = [_cost(f[0] if f else None, clip) for f in fits]
        best = float(grid[int(np.argmin(costs))])
        low, high = best - step, best + step
        golden = (math.sqrt(5.0) - 1.0) / 2.0
        a, b = high - golden * (high - low), low + golden * (high - low)
        fa, fb = _cost(_first(fit(a)), clip), _cost(_first(fit(b)), clip)
        while high - low > 2e-4:  # 0.2 ms
            if fa <= fb:
                high, b, fb = b, a, fa
                a = high - golden * (high - low)
                fa = _cost(_first(fit(a)), clip)
            else:
                low, a, fa = a, b, fb
                b = low + golden * (high - low)
                fb = _cost(_first(fit(b)), clip)
        offset_s = (low + high) / 2.0
    final = fit(offset_s)
    if final is None:
        raise ValueError("the reference overlaps fewer than 10 fixes at the clock offset")
    robust, valid = final
    matched, _ = reference.at(stamps[valid] + round(offset_s * 1e9))
    return Alignment(
        robust.transform,
        round(offset_s * 1e9),
        robust,
        int(np.count_nonzero(valid)),
        _spread(matched[robust.inliers]),
        _speed_rms(stamps[valid][robust.inliers], matched[robust.inliers]),
        offset_given=given,
    )


def _first(value: tuple[RobustFit, np.ndarray] | None) -> RobustFit | None:
    return None if value is None else value[0]
