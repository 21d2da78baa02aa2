"""Self-calibration of the sonar's pitch: a ROV going down and up through the vertical aperture.

The walls cannot tell the sonar's pitch from the speed of sound (capsd.mount_calibration), and
the depth constraint forgives it in a fix; but the aperture tests (the locator's, the
detector's depth gate, the mission's view guard) compute the ROV's elevation in the sonar from
its depth and the mount, and a pitch off by a degree refuses good fixes near an edge. So, as
sonar teams map a beam by lowering a target through it: the ROV holds its place in the plane
in front of the still ASV and goes slowly down and up, from above the aperture's top edge to
below its bottom edge. Its echo is strong inside the aperture and gone outside it. Per frame,
the ROV's elevation as the configured mount computes it (from the fixes' horizontal place, its
depth reading and the ASV's pose) and the echo's strength where it must be in the image; a
plateau with two soft edges, symmetric about the true boresight whatever the vertical
pattern's shape or the image's gain and gamma, is fitted to strength against elevation: its
centre is how far the computed elevations are off.

What it measures is the elevation offset at the manoeuvre's ranges: the pitch error plus what
an error in the sonar's height does to an elevation there (2 cm at 2.5 m is 0.46 deg). That is
what the aperture tests feel at such ranges; it is applied as the mount's pitch.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares

from capsd.errors import CapsdError
from capsd.geometry import Transform
from capsd.mount_calibration import Observation
from capsd.payloads import RovDepth, RovFix
from capsd.sonar_geometry import BeamModel, to_polar
from capsd.sonar_image import unit_image

Floats = npt.NDArray[np.float64]
# Where the ROV's echo is looked for around its centre's range and azimuth: its near side
# returns first (up to 0.35 m before the centre), and 0.3 m to either side.
BEFORE_M, AFTER_M, HALF_WIDTH_M = 0.35, 0.15, 0.3
TOP_SHARE = 0.1  # the strength: the mean of the window's brightest tenth
MAX_FIX_GAP_S = 60.0  # outside the aperture there are no fixes: the last place still holds
MIN_BEYOND = 10  # frames beyond each edge (and as many inside) for the edges to be fitted
# Written only when known this well: as the roll (capsd.mount_calibration), tilt matters far
# less than heading (the depth constraint forgives it; the aperture's edges are soft).
SIGMA_MAX_DEG = 0.3
INDEPENDENT_EVERY_S = 0.5  # neighbouring frames' strengths share the ROV's aspect and gain
# What the fit misses by beyond its own statistics, added to its 1-sigma: `capsd bench
# calibrate` (pond, 5 seeds, session 25) found it 0.004-0.31 deg (RMS 0.14 deg) off what the
# elevations were truly off at the edges, the worst 5.7 of its statistical sigmas: the echo's
# edges are not quite symmetric about the boresight (the ROV's outline seen from above and
# from the side; with the truth's own geometry that seed's plateau centred 0.31 deg off).
MODEL_SIGMA_DEG = 0.14


@dataclass(frozen=True)
class EchoSamples:
    """Per frame: the ROV's elevation as the configured mount computes it, its echo's strength."""

    stamps_ns: npt.NDArray[np.int64]
    elevation_rad: Floats
    range_m: Floats
    strength: Floats


@dataclass(frozen=True)
class PitchFit:
    """The elevation offset found (nominal less true), its 1-sigma, the aperture seen."""

    offset_deg: float  # positive: the configured mount puts the ROV higher than it is
    offset_sigma_deg: float
    half_width_deg: float  # where the echo fades, either side of the centre
    edge_deg: float  # how soft the edges are
    frames: int
    above: int  # frames beyond the top edge
    below: int  # frames beyond the bottom edge
    range_m: float  # the median range of the frames near the edges
    residual: float

    @property
    def pitch_correction_deg(self) -> float:
        """What to add to the mount's pitch (positive down): the boresight is that much lower."""
        return -self.offset_deg

    @property
    def determined(self) -> bool:
        """Whether both edges were seen and the centre is known well enough to write."""
        return (
            self.above >= MIN_BEYOND
            and self.below >= MIN_BEYOND
            and self.offset_sigma_deg <= SIGMA_MAX_DEG
        )

    def lines(self) -> list[str]:
        """What a person reads."""
        verdict = (
            f"determined: the sonar's pitch moves by {self.pitch_correction_deg:+.3f} deg"
            if self.determined
            else f"NOT determined (needs >= {MIN_BEYOND} frames beyond each edge of the "
            f"aperture: {self.above} above, {self.below} below; 1-sigma <= {SIGMA_MAX_DEG:g} deg)"
        )
        return [
            f"elevation offset {self.offset_deg:+.3f} deg (1 sigma {self.offset_sigma_deg:.3f}) "
            f"from {self.frames} frames of the ROV going down and up, {self.range_m:.1f} m off: "
            f"{verdict}",
            f"  the echo fades {self.half_width_deg:.1f} deg either side of the boresight "
            f"(edges {self.edge_deg:.1f} deg soft); the offset includes what the sonar's "
            f"height error does at {self.range_m:.1f} m",
        ]


def rov_places(
    fixes: Sequence[RovFix], depths: Sequence[RovDepth], stamps_ns: Sequence[int]
) -> list[Floats | None]:
    """The ROV's centre at each stamp: the nearest good fix's x, y; z from the depth readings.

    Outside the aperture there are no fixes; the ROV holds its place in the plane, so the
    nearest one stands (within MAX_FIX_GAP_S). Its z follows the depth readings, offset by
    how the good fixes' z lies against them (the pressure port's lever arm and any offset).
    """
    good = [f for f in fixes if f.quality == "good" and f.position_m is not None]
    if len(good) < 2 or len(depths) < 2:
        raise CapsdError(
            f"{len(good)} good fixes and {len(depths)} depth readings: the pitch needs the ROV "
            "tracked and its depth (record cap/** with the locator running)"
        )
    fix_ns = np.array([f.stamp_ns for f in good], dtype=np.int64)
    fix_m = np.array([f.position_m for f in good], dtype=np.float64)
    order = np.argsort([d.stamp_ns for d in depths])
    depth_ns = np.array([depths[i].stamp_ns for i in order], dtype=np.float64)
    depth_z = -np.array([depths[i].depth_m for i in order], dtype=np.float64)
    offset = float(np.median(fix_m[:, 2] - np.interp(fix_ns.astype(np.float64), depth_ns, depth_z)))
    out: list[Floats | None] = []
    for stamp in stamps_ns:
        k = int(np.argmin(np.abs(fix_ns - stamp)))
        outside = stamp < depth_ns[0] or stamp > depth_ns[-1]
        if outside or abs(int(fix_ns[k]) - stamp) > MAX_FIX_GAP_S * 1e9:
            out.append(None)
            continue
        z = float(np.interp(float(stamp), depth_ns, depth_z)) + offset
        out.append(np.array([fix_m[k, 0], fix_m[k, 1], z]))
    return out


def echo_samples(
    observations: Sequence[Observation],
    places: Sequence[Floats | None],
    *,
    mount: Transform,
    beam_model: BeamModel,
) -> EchoSamples:
    """Each frame's ROV elevation (the given mount) and the strength of its echo there."""
    rows: list[tuple[int, float, float, float]] = []
    for obs, place in zip(observations, places, strict=True):
        if place is None:
            continue
        frame = obs.frame
        try:
            range_m, azimuth, elevation = to_polar(
                beam_model, obs.asv.compose(mount).inverse().apply(place)
            )
        except ValueError:
            continue
        bins = frame.range_start_m + (np.arange(frame.n_ranges) + 0.5) * frame.range_resolution_m
        rows_in = np.nonzero((bins > range_m - BEFORE_M) & (bins < range_m + AFTER_M))[0]
        beams = np.asarray(frame.azimuths_rad)
        beams_in = np.nonzero(np.abs(beams - azimuth) <= HALF_WIDTH_M / max(range_m, 0.1))[0]
        if len(rows_in) < 2 or len(beams_in) < 1:
            continue  # outside the image
        window = unit_image(frame)[rows_in[0] : rows_in[-1] + 1, beams_in[0] : beams_in[-1] + 1]
        values = np.sort(window.ravel())
        top = values[-max(1, int(len(values) * TOP_SHARE)) :]
        rows.append((frame.stamp_ns, elevation, range_m, float(np.mean(top))))
    if not rows:
        return EchoSamples(
            np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0), np.zeros(0)
        )  # fmt: skip
    data = np.array([r[1:] for r in rows])
    return EchoSamples(
        np.array([r[0] for r in rows], dtype=np.int64), data[:, 0], data[:, 1], data[:, 2]
    )


def _plateau(params: Floats, elevation: Floats) -> Floats:
    """Background plus a plateau between two logistic edges at centre -/+ half width.

    The plateau may slope (the echo's strength changes with range, and the range with the
    depth): the edges stay where the logistic factors are half way, whatever the slope.
    """
    inside, outside, centre, half, soft, slope = params
    k = max(abs(soft), 1e-4)
    rise = 0.5 * (1.0 + np.tanh((elevation - centre + half) / (2.0 * k)))
    fall = 0.5 * (1.0 + np.tanh((centre + half - elevation) / (2.0 * k)))
    level = inside + slope * (elevation - centre)
    out: Floats = outside + (level - outside) * rise * fall
    return out


def fit_pitch(samples: EchoSamples) -> PitchFit:
    """The plateau's centre (the elevation offset) and its 1-sigma, by robust least squares."""
    n = len(samples.strength)
    if n < 3 * MIN_BEYOND:
        raise CapsdError(
            f"{n} frames with the ROV placed: the pitch needs the ROV going down and up through "
            "the aperture in front of the ASV (about two minutes)"
        )
    e, s = samples.elevation_rad, samples.strength
    hi, lo = float(np.percentile(s, 90)), float(np.percentile(s, 10))
    # Start where the strength is above half way: the plateau's middle and half its span.
    strong = e[s > 0.5 * (hi + lo)]
    centre0 = 0.5 * float(strong.min() + strong.max()) if len(strong) else 0.0
    half0 = max(0.5 * float(strong.max() - strong.min()), math.radians(3.0)) if len(strong) else 0.2
    start = np.array([hi, lo, centre0, half0, math.radians(1.0), 0.0])
    scale = max(hi - lo, 1e-3)

    def misfit(params: Floats) -> Floats:
        out: Floats = _plateau(params, e) - s
        return out

    result = least_squares(
        misfit, start, loss="soft_l1", f_scale=0.1 * scale,
        x_scale=np.array([scale, scale, 0.01, 0.01, 0.01, scale]),
    )  # fmt: skip
    inside, outside, centre, half, soft, _ = (float(v) for v in result.x)
    residual = result.fun
    dof = max(n - 6, 1)
    variance = float(residual @ residual) / dof
    span_s = (int(samples.stamps_ns.max()) - int(samples.stamps_ns.min())) / 1e9
    independent = max(min(float(n), span_s / INDEPENDENT_EVERY_S), 2.0)
    jac = np.asarray(result.jac, dtype=np.float64)
    covariance = np.linalg.pinv(jac.T @ jac) * variance * (n / independent)
    sigma = math.sqrt(max(float(covariance[2, 2]), 0.0) + math.radians(MODEL_SIGMA_DEG) ** 2)
    half = abs(half)
    margin = half + 2.0 * abs(soft)
    contrast_ok = inside > outside
    above = int(np.sum(e > centre + margin)) if contrast_ok else 0
    below = int(np.sum(e < centre - margin)) if contrast_ok else 0
    near_edges = np.abs(np.abs(e - centre) - half) < math.radians(3.0)
    range_m = float(np.median(samples.range_m[near_edges])) if near_edges.any() else math.nan
    return PitchFit(
        offset_deg=math.degrees(centre),
        offset_sigma_deg=math.degrees(sigma),
        half_width_deg=math.degrees(half),
        edge_deg=math.degrees(abs(soft)),
        frames=n,
        above=above,
        below=below,
        range_m=range_m,
        residual=math.sqrt(variance),
    )


__all__ = ["EchoSamples", "PitchFit", "echo_samples", "fit_pitch", "rov_places"]
