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
what the aperture tests feel at such ranges. From one distance it is applied as the mount's
pitch. Profiles at two distances tell the two apart: the pitch offsets every elevation alike,
the height by its angle at that distance (at the edges of a 30 deg-down aperture about 0.27
deg per cm at 1.5 m, 0.11 at 3.8 m: `capsd bench calibrate`), so the offsets found at each
distance are fitted as pitch plus height times that angle per metre (`fit_profiles`), and the
height is written when known within HEIGHT_SIGMA_MAX_M. What is written weighs in what the
tape said (`ProfilesPrior`): two profiles pin the offset at their ranges far better than the
pitch and height apart, whose errors run along one line; the tape's own 1-sigma on each cuts
that line short. The fit says whether the profiles alone would have known the height.
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
# The ROV holds its place: its x, y the median of the good fixes this near in time, not the
# nearest fix alone (at 1.5 m a fix's 2 cm is most of a degree of elevation, and the last fix
# before the ROV leaves the aperture, held while it is out of view, is the least sure).
PLACE_WINDOW_S = 20.0
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
LIFT_STEP_M = 0.01  # the sonar raised this much to see what its height does to an elevation
# split_profiles: the distances' histogram in PROFILE_BIN_M bins; a profile's frames are those
# within PROFILE_HALF_SPREAD_M of its distance, and profiles more than twice that apart are
# told apart (a recording's transit between them falls between); a profile holds at least
# PROFILE_SHARE of the frames the largest one holds.
PROFILE_BIN_M = 0.1
PROFILE_HALF_SPREAD_M = 0.3
PROFILE_SHARE = 0.25
# The sonar's height is written when known this well (issue 24's target for its position).
HEIGHT_SIGMA_MAX_M = 0.015


@dataclass(frozen=True)
class EchoSamples:
    """Per frame: the ROV's elevation as the configured mount computes it, its echo's strength."""

    stamps_ns: npt.NDArray[np.int64]
    elevation_rad: Floats
    range_m: Floats
    strength: Floats
    distance_m: Floats  # horizontal, from the sonar to the ROV
    # How much the computed elevation is off per metre the sonar truly sits higher than the
    # mount says (the ROV then lies lower in it than computed): what a height error does here.
    height_gain_rad_per_m: Floats
    # The same per metre the mount puts the sonar further forward than it truly is.
    forward_gain_rad_per_m: Floats

    def subset(self, keep: npt.NDArray[np.bool_]) -> EchoSamples:
        """The samples where `keep` holds."""
        return EchoSamples(
            self.stamps_ns[keep], self.elevation_rad[keep], self.range_m[keep],
            self.strength[keep], self.distance_m[keep], self.height_gain_rad_per_m[keep],
            self.forward_gain_rad_per_m[keep],
        )  # fmt: skip


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
    distance_m: float = math.nan  # the median horizontal distance from the sonar to the ROV
    # What a height error does to the centre (the mean of the two edges' EchoSamples gains).
    height_gain_rad_per_m: float = math.nan
    forward_gain_rad_per_m: float = math.nan  # the same for a forward error
    # The sight's dip below the horizontal while the ROV is inside the aperture (where its
    # fixes, and so its place, come from): the median over the plateau's frames.
    dip_rad: float = math.nan

    def height_gain_with(self, coupling: float | None) -> float:
        """What a height error does to the centre, with what it does to the ROV's place.

        The place comes from fixes: the depth constraint puts them tan(dip) further out per
        metre the sonar truly sits higher, and the range offset (capsd.range_calibration),
        fitted with the old height, took `coupling` of slant range per metre back, which is
        1 / cos(dip) of horizontal here. A place further out is as a sonar further back
        (the forward gain). None: the range offset's fit not known; the place taken as right.
        """
        if coupling is None:
            return self.height_gain_rad_per_m
        place = math.tan(self.dip_rad) - coupling / math.cos(self.dip_rad)
        return self.height_gain_rad_per_m - place * self.forward_gain_rad_per_m

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
    """The ROV's centre at each stamp: x, y from the good fixes; z from the depth readings.

    The ROV holds its place in the plane: its x, y the median of the good fixes within
    PLACE_WINDOW_S; outside the aperture there are none, and the nearest one stands (within
    MAX_FIX_GAP_S). Its z follows the depth readings, offset by how the good fixes' z lies
    against them (the pressure port's lever arm and any offset).
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
        window = np.abs(fix_ns - stamp) <= PLACE_WINDOW_S * 1e9
        x, y = np.median(fix_m[window, :2], axis=0) if window.any() else fix_m[k, :2]
        out.append(np.array([float(x), float(y), z]))
    return out


def echo_samples(
    observations: Sequence[Observation],
    places: Sequence[Floats | None],
    *,
    mount: Transform,
    beam_model: BeamModel,
) -> EchoSamples:
    """Each frame's ROV elevation (the given mount) and the strength of its echo there."""
    rows: list[tuple[int, float, float, float, float, float, float]] = []
    raised = Transform(mount.rotation, mount.translation + np.array([0.0, 0.0, LIFT_STEP_M]))
    back = Transform(mount.rotation, mount.translation - np.array([LIFT_STEP_M, 0.0, 0.0]))
    for obs, place in zip(observations, places, strict=True):
        if place is None:
            continue
        frame = obs.frame
        sonar = obs.asv.compose(mount)
        try:
            range_m, azimuth, elevation = to_polar(beam_model, sonar.inverse().apply(place))
            _, _, elevation_raised = to_polar(
                beam_model, obs.asv.compose(raised).inverse().apply(place)
            )
            _, _, elevation_back = to_polar(
                beam_model, obs.asv.compose(back).inverse().apply(place)
            )
        except ValueError:
            continue
        gain = (elevation - elevation_raised) / LIFT_STEP_M
        forward_gain = (elevation - elevation_back) / LIFT_STEP_M
        distance = float(np.hypot(*(np.asarray(place)[:2] - sonar.translation[:2])))
        bins = frame.range_start_m + (np.arange(frame.n_ranges) + 0.5) * frame.range_resolution_m
        rows_in = np.nonzero((bins > range_m - BEFORE_M) & (bins < range_m + AFTER_M))[0]
        beams = np.asarray(frame.azimuths_rad)
        beams_in = np.nonzero(np.abs(beams - azimuth) <= HALF_WIDTH_M / max(range_m, 0.1))[0]
        if len(rows_in) < 2 or len(beams_in) < 1:
            continue  # outside the image
        window = unit_image(frame)[rows_in[0] : rows_in[-1] + 1, beams_in[0] : beams_in[-1] + 1]
        values = np.sort(window.ravel())
        top = values[-max(1, int(len(values) * TOP_SHARE)) :]
        strength = float(np.mean(top))
        rows.append((frame.stamp_ns, elevation, range_m, strength, distance, gain, forward_gain))
    if not rows:
        e = np.zeros(0)
        return EchoSamples(np.zeros(0, dtype=np.int64), e, e, e, e, e, e)
    data = np.array([r[1:] for r in rows])
    return EchoSamples(
        np.array([r[0] for r in rows], dtype=np.int64),
        data[:, 0], data[:, 1], data[:, 2], data[:, 3], data[:, 4], data[:, 5],
    )  # fmt: skip


def split_profiles(samples: EchoSamples) -> list[EchoSamples]:
    """The samples of each profile, nearest first: one per distance the ROV held from the sonar.

    A distance held is a peak of the distances' histogram with enough frames for a fit and at
    least PROFILE_SHARE of the largest peak's; the frames of a transit between two profiles
    spread thin, fall outside every peak's spread and are left out.
    """
    d = samples.distance_m
    if len(d) == 0:
        return []
    edges = np.arange(float(d.min()) - PROFILE_BIN_M, float(d.max()) + 2 * PROFILE_BIN_M,
                      PROFILE_BIN_M)  # fmt: skip
    counts, _ = np.histogram(d, bins=edges)
    centres = 0.5 * (edges[:-1] + edges[1:])
    # Frames within the spread of each bin: a profile's frames whatever its drift.
    near = np.array([np.sum(np.abs(d - c) <= PROFILE_HALF_SPREAD_M) for c in centres])
    order = np.argsort(-near, kind="stable")
    # A distance held: as many frames about it as a fit needs, and a good share of the most
    # any distance holds (a transit's frames spread thin).
    least = max(3 * MIN_BEYOND, PROFILE_SHARE * float(near.max()))
    peaks: list[float] = []
    for i in order:
        if near[i] < least:
            break
        if counts[i] and all(abs(centres[i] - p) > 2 * PROFILE_HALF_SPREAD_M for p in peaks):
            peaks.append(float(np.median(d[np.abs(d - centres[i]) <= PROFILE_HALF_SPREAD_M])))
    return [samples.subset(np.abs(d - p) <= PROFILE_HALF_SPREAD_M) for p in sorted(peaks)]


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


MIN_EDGE_DEG = 0.2  # the softest edge the fit may call sharp (logistic scale)


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

    # The edges' softness is bounded below: a step has no slope to pull the centre with, and
    # a fit whose edges collapsed to one stopped up to 0.3 deg off a sharp plateau (session 41,
    # the property test). No real edge is that sharp: the ROV itself spans a degree or more.
    lower = np.array([-np.inf, -np.inf, -np.inf, -np.inf, math.radians(MIN_EDGE_DEG), -np.inf])
    result = least_squares(
        misfit, start, loss="soft_l1", f_scale=0.1 * scale,
        x_scale=np.array([scale, scale, 0.01, 0.01, 0.01, scale]),
        bounds=(lower, np.full(6, np.inf)),
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
    seen = np.abs(e - centre) < half
    dips = np.arccos(np.clip(samples.distance_m / np.maximum(samples.range_m, 1e-6), 0.0, 1.0))
    dip = float(np.median(dips[seen])) if seen.any() else math.nan
    # The centre is the mean of the edges: so is what a height error does to it.
    upper = near_edges & (e > centre)
    lower = near_edges & (e < centre)

    def at_edges(gains: Floats) -> float:
        if not (upper.any() and lower.any()):
            return math.nan
        return 0.5 * (float(np.mean(gains[upper])) + float(np.mean(gains[lower])))

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
        distance_m=float(np.median(samples.distance_m)),
        height_gain_rad_per_m=at_edges(samples.height_gain_rad_per_m),
        forward_gain_rad_per_m=at_edges(samples.forward_gain_rad_per_m),
        dip_rad=dip,
    )


@dataclass(frozen=True)
class ProfilesPrior:
    """What was known before the profiles: the pitch and height errors' 1-sigma, zero mean.

    The tape-measured installation's (the locator's `installation` section): the sonar's
    pitch, and its height combined with what the ROV's depth offset may still get wrong (the
    profiles see the sonar's height against the ROV's depth reference). A sigma of 0 or less
    is no prior on that term.
    """

    pitch_sigma_rad: float
    height_sigma_m: float

    def information(self) -> Floats:
        """The prior's information matrix over (pitch, height): zero where none is known."""
        return np.diag(
            [1.0 / s**2 if s > 0.0 else 0.0 for s in (self.pitch_sigma_rad, self.height_sigma_m)]
        )


@dataclass(frozen=True)
class ProfilesFit:
    """The pitch and height from the profiles' elevation offsets (or the offset, from one)."""

    fits: tuple[PitchFit, ...]  # one per distance, nearest first
    # With two or more determined profiles: offset_k = pitch + height * gain_k, by weighted
    # least squares. pitch_offset_deg is the part alike at every range (the pitch error, as
    # PitchFit's offset: positive, the mount puts the ROV higher than it is); height_m how
    # much higher the sonar truly sits than configured. NaN from fewer profiles. With a
    # prior, these and their 1-sigma weigh it in (the most likely pitch and height given the
    # tape and the profiles: what is written, when known within HEIGHT_SIGMA_MAX_M);
    # height_data_sigma_m is the profiles' own, which says whether they alone would have.
    pitch_offset_deg: float = math.nan
    pitch_offset_sigma_deg: float = math.nan
    height_m: float = math.nan
    height_sigma_m: float = math.nan
    height_data_sigma_m: float = math.nan
    prior: ProfilesPrior | None = None
    # The range offset's height coupling (capsd.range_calibration.RangeFit): the range offset
    # it wrote took in that much slant range per metre of a height error, which the height
    # found here gives back (`range_give_back_m`). None: not known (the range manoeuvre's fit
    # not given), so the height is not written: alone it would move the fixes along the sight.
    height_coupling: float | None = None

    @property
    def used(self) -> tuple[PitchFit, ...]:
        """The profiles whose centre was determined."""
        return tuple(f for f in self.fits if f.determined)

    @property
    def height_determined(self) -> bool:
        """Whether the height (and with it the pitch alone) is known well enough to write.

        The two go together: their errors cancel at the profiles' ranges (the pitch alone is
        the offset extrapolated to where a height error does nothing, and less sure). Known:
        from everything the fit was given, the tape's prior too (`by_profiles_alone` says
        whether the profiles alone pinned it).
        """
        return (
            len(self.used) >= 2
            and self.height_sigma_m <= HEIGHT_SIGMA_MAX_M
            and self.height_coupling is not None
        )

    @property
    def by_profiles_alone(self) -> bool:
        """Whether the profiles alone, without the tape's prior, know the height well enough."""
        return self.height_determined and self.height_data_sigma_m <= HEIGHT_SIGMA_MAX_M

    @property
    def range_give_back_m(self) -> float:
        """What the range offset moves by with the height (0 where none is written).

        The range offset's fit put the fixes right along the sight with the old height; with
        the new one the depth constraint no longer puts them out, so the range offset gives
        back the coupling times the height.
        """
        if not self.height_determined or self.height_coupling is None:
            return 0.0
        return self.height_coupling * self.height_m

    @property
    def determined(self) -> bool:
        """Whether the pitch is written (alone: the offset at the profiles' ranges)."""
        return self.height_determined or bool(self.used)

    @property
    def offset_deg(self) -> float:
        """The elevation offset written as the pitch (the pitch alone, if the height is known).

        Else the determined profiles' weighted mean: right at their ranges.
        """
        if self.height_determined:
            return self.pitch_offset_deg
        used = self.used or self.fits
        weights = np.array([1.0 / f.offset_sigma_deg**2 for f in used])
        return float(np.average([f.offset_deg for f in used], weights=weights))

    @property
    def offset_sigma_deg(self) -> float:
        """The written pitch's 1-sigma."""
        if self.height_determined:
            return self.pitch_offset_sigma_deg
        used = self.used or self.fits
        return float(1.0 / math.sqrt(sum(1.0 / f.offset_sigma_deg**2 for f in used)))

    @property
    def pitch_correction_deg(self) -> float:
        """What to add to the mount's pitch (positive down)."""
        return -self.offset_deg

    def lines(self) -> list[str]:
        """What a person reads: each profile, then what they tell together."""
        out = [line for f in self.fits for line in f.lines()]
        if len(self.used) < 2:
            out.append(
                f"the sonar's height NOT determined: {len(self.used)} profile(s) determined, "
                "needs two at different distances (e.g. 1.5 m and 4 m)"
            )
            return out
        if self.height_determined:
            leaning = (
                ""
                if self.by_profiles_alone
                else (
                    f" (leaning on the tape: the profiles alone know it to "
                    f"{self.height_data_sigma_m * 1000:.1f} mm, not "
                    f"{HEIGHT_SIGMA_MAX_M * 1000:g})"
                )
            )
            verdict = (
                f"determined{leaning}: the sonar sits {self.height_m * 1000:+.1f} mm higher than "
                f"configured (the range offset moves by {self.range_give_back_m * 1000:+.1f} "
                f"mm, what it took of the height) and its pitch moves by "
                f"{-self.pitch_offset_deg:+.3f} deg"
            )
        elif self.height_coupling is None:
            verdict = (
                "height NOT written: the range manoeuvre's recording is needed too (--orbit), "
                "its range offset took part of the height in; the pitch takes the "
                "profiles' mean offset"
            )
        else:
            verdict = (
                f"height NOT determined (1-sigma <= {HEIGHT_SIGMA_MAX_M * 1000:g} mm needed): "
                "the pitch takes the profiles' mean offset"
            )
        weighed = (
            ""
            if self.prior is None
            else (
                f", the tape's 1-sigma weighed in ({math.degrees(self.prior.pitch_sigma_rad):g} "
                f"deg, {self.prior.height_sigma_m * 1000:.0f} mm)"
            )
        )
        out.append(
            f"from {len(self.used)} distances "
            f"({', '.join(f'{f.distance_m:.1f}' for f in self.used)} m): height "
            f"{self.height_m * 1000:+.1f} mm (1 sigma {self.height_sigma_m * 1000:.1f}; the "
            f"profiles alone {self.height_data_sigma_m * 1000:.1f}), pitch offset "
            f"{self.pitch_offset_deg:+.3f} deg (1 sigma {self.pitch_offset_sigma_deg:.3f})"
            f"{weighed}: {verdict}"
        )
        return out


def fit_profiles(
    profiles: Sequence[EchoSamples],
    *,
    height_coupling: float | None,
    prior: ProfilesPrior | None = None,
) -> ProfilesFit:
    """Each profile's plateau; from two or more distances, the pitch and height apart.

    `height_coupling`: the range offset fit's (RangeFit.height_coupling), None where it is
    not known (the height then only reported). The height's gain at each profile takes in
    what it does to the ROV's place there (PitchFit.height_gain_with). `prior`: the tape's
    1-sigma, weighed into the pitch and height written and into whether the height is known
    well enough to write (ProfilesFit.by_profiles_alone: whether the profiles alone were).
    """
    if not profiles:
        raise CapsdError(
            "no profile: the pitch needs the ROV going down and up through the aperture in "
            "front of the still ASV (about two minutes)"
        )
    fits = tuple(fit_pitch(p) for p in profiles)
    used = [f for f in fits if f.determined and math.isfinite(f.height_gain_with(height_coupling))]
    gains = [f.height_gain_with(height_coupling) for f in used]
    if len(used) < 2 or max(gains) - min(gains) < 1e-3:
        return ProfilesFit(fits, height_coupling=height_coupling)
    design = np.array([[1.0, g] for g in gains])
    offsets = np.radians([f.offset_deg for f in used])
    weights = 1.0 / np.radians([f.offset_sigma_deg for f in used]) ** 2
    normal = design.T @ (design * weights[:, None])
    data_covariance = np.linalg.inv(normal)
    # The prior's mean is the configured mount (zero error): it adds information only.
    known = np.zeros((2, 2)) if prior is None else prior.information()
    covariance = np.linalg.inv(normal + known)
    pitch, height = covariance @ (design.T @ (weights * offsets))
    return ProfilesFit(
        fits,
        pitch_offset_deg=math.degrees(float(pitch)),
        pitch_offset_sigma_deg=math.degrees(math.sqrt(float(covariance[0, 0]))),
        height_m=float(height),
        height_sigma_m=math.sqrt(float(covariance[1, 1])),
        height_data_sigma_m=math.sqrt(float(data_covariance[1, 1])),
        prior=prior,
        height_coupling=height_coupling,
    )


__all__ = [
    "EchoSamples",
    "PitchFit",
    "ProfilesFit",
    "ProfilesPrior",
    "echo_samples",
    "fit_pitch",
    "fit_profiles",
    "rov_places",
    "split_profiles",
]
