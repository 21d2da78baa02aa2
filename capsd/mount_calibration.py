"""Self-calibration of the sonar mount from the tank's walls: heading and roll against the LiDAR.

The ASV knows its pose from the LiDAR (scan matching against the walls), and the tank's walls
are in every sonar image as a bright band. With the mount known, each beam's wall echo starts
at the range where the shallowest ray of the beam's vertical aperture first meets a wall;
with the mount wrong, the band sits elsewhere. This module measures, per beam, where the band
starts (half way up its rising edge) and fits the mount's heading (yaw) and roll, plus one
range scale, by robust least squares over many frames and beams:
- yaw: rotates the band across the fan: well determined whenever a wall is seen across many
  beams, best obliquely or in a corner, and from several ASV headings;
- roll: tilts the aperture's top edge across the fan: determined when walls are seen on both
  sides of the boresight (reported as such otherwise);
- range scale: the speed of sound and the pitch of the mount both scale every wall range (a
  pitch error moves the aperture's top edge, 0.36 % per degree at 20 deg): they cannot be told
  apart from walls, so pitch is reported as not determined and the scale is reported, not used.
The mount's position is not estimated (2 cm moves a wall range by at most 2 cm).
What the fit measures is the sonar's heading relative to the ASV's LiDAR-derived heading: the
error a fix feels, whether the sonar or the LiDAR was mounted askew.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import msgspec
import numpy as np
import numpy.typing as npt

from capsd.errors import CapsdError
from capsd.geometry import Transform, euler_zyx_to_matrix, matrix_to_euler_zyx
from capsd.mounts import SonarMountConfig
from capsd.payloads import SonarFrame
from capsd.sonar_image import unit_image
from capsd.tank import TankBounds

Floats = npt.NDArray[np.float64]
ELEVATIONS = 15  # rays across the vertical aperture per beam
BEAM_STEP = 4  # every 4th beam is measured
BEAM_HALF_WIDTH = 0.5  # in beam spacings: the main lobe's half width
MIN_CONTRAST = 25.0  # 8-bit levels between the water before the wall and the wall's peak
MIN_MEASUREMENTS = 200
# A correction is "determined" (and applied) when its 1-sigma is within what a fix can bear:
# 0.1 deg of heading is 14 mm at 8 m; tilt matters far less (the depth constraint forgives it).
# The 1-sigma is the marginal one (fit_mount: the wider of two estimates): it already carries
# how much yaw and roll trade off against each other. (A cut on their correlation alone, 0.95,
# refused a mockup's yaw known to 0.07 deg, and 0.06 deg right.)
YAW_SIGMA_MAX_DEG = 0.1
ROLL_SIGMA_MAX_DEG = 0.3
SHIFT_SIGMA_MAX_M = 0.015
F_SCALE_M = 0.05  # the robust loss's scale: edges further off than this count less


@dataclass(frozen=True)
class Observation:
    """One sonar frame and the ASV's pose H_W_B at its stamp (from the LiDAR)."""

    frame: SonarFrame
    asv: Transform


@dataclass(frozen=True)
class MountFit:
    """Corrections to add to the configured mount, with 1-sigma and what the data determined."""

    yaw_deg: float
    yaw_sigma_deg: float
    roll_deg: float
    roll_sigma_deg: float
    range_scale: float
    range_scale_sigma: float
    shift_y_m: float  # the sonar's sideways position correction in the ASV frame
    shift_y_sigma_m: float
    yaw_roll_correlation: float
    measurements: int
    frames: int
    residual_rms_m: float
    yaw_determined: bool
    roll_determined: bool
    shift_determined: bool

    def lines(self) -> list[str]:
        """What a person reads: each estimate, its uncertainty, and what could not be told."""

        def verdict(ok: bool) -> str:
            return "determined" if ok else "NOT determined by this data (keep the configured value)"

        return [
            f"{self.measurements} wall edges in {self.frames} frames, "
            f"residual rms {self.residual_rms_m * 1000:.1f} mm",
            f"sonar yaw correction   {self.yaw_deg:+.3f} deg  (1 sigma {self.yaw_sigma_deg:.3f}) "
            f"{verdict(self.yaw_determined)}",
            f"sonar roll correction  {self.roll_deg:+.3f} deg  (1 sigma {self.roll_sigma_deg:.3f}) "
            f"{verdict(self.roll_determined)}",
            f"sonar position y       {self.shift_y_m * 1000:+.1f} mm  "
            f"(1 sigma {self.shift_y_sigma_m * 1000:.1f}) {verdict(self.shift_determined)}",
            "sonar pitch            NOT determined: walls cannot tell it from the sound speed",
            "sonar position x, z    NOT determined: walls cannot tell x from a range offset",
            f"range scale            {self.range_scale:.4f}  "
            f"(1 sigma {self.range_scale_sigma:.4f}; sound speed and pitch together; "
            "reported, not applied)",
            f"yaw-roll correlation   {self.yaw_roll_correlation:+.2f}",
        ]


def _mount_with(
    mount: SonarMountConfig, yaw_rad: float, roll_rad: float, shift_m: tuple[float, float] = (0, 0)
) -> Transform:
    """H_B_S with the corrections: a small rotation in the sonar's frame, a shift in the ASV's."""
    correction = Transform(euler_zyx_to_matrix(yaw_rad, 0.0, roll_rad), np.zeros(3))
    nominal = mount.transform()
    shifted = Transform(nominal.rotation, nominal.translation + np.array([*shift_m, 0.0]))
    return shifted.compose(correction)


def _beam_directions(
    mount: SonarMountConfig,
    azimuths: Floats,
    aperture_rad: float,
    widen_rad: float = 0.0,
    spacing_rad: float = 0.0,
) -> Floats:
    """Unit rays in S, (beams, 3 x ELEVATIONS, 3), under the mount's beam model.

    `widen_rad` widens (or narrows) the aperture's half-width: where the echo is first seen is
    where the vertical beam pattern gets strong enough, not the nominal edge.
    """
    half = aperture_rad / 2 + widen_rad
    elevations = np.linspace(-half, half, ELEVATIONS)
    # A beam is about one beam spacing wide: its nearest echo comes from its near side, which
    # on an oblique wall is closer than its centre line.
    parts = []
    for offset in (-BEAM_HALF_WIDTH * spacing_rad, 0.0, BEAM_HALF_WIDTH * spacing_rad):
        theta = azimuths + offset
        ct, st = np.cos(theta)[:, None], np.sin(theta)[:, None]
        ce, se = np.cos(elevations)[None, :], np.sin(elevations)[None, :]
        if mount.beam_model == "planar":
            d = np.stack(np.broadcast_arrays(ce * ct, ce * st, se * np.ones_like(ct)), axis=-1)
        else:
            d = np.stack(np.broadcast_arrays(ct * ce, st * np.ones_like(ce), ct * se), axis=-1)
        parts.append(d)
    d = np.concatenate(parts, axis=1)
    out: Floats = d / np.linalg.norm(d, axis=-1, keepdims=True)
    return out


def predicted_edges(asv: Transform, sonar: Transform, rays_s: Floats, tank: TankBounds) -> Floats:
    """Per beam, the range at which the beam's rays first meet a wall (NaN: none).

    `asv` is H_W_B, `sonar` H_B_S. A ray leaving the tank through the floor or the surface
    does not count: the band is the wall's, and the floor's grazing echo is far weaker.
    """
    lows = np.array([0.0, 0.0, -tank.depth_m])
    highs = np.array([tank.length_m, tank.width_m, 0.0])
    h = asv.compose(sonar)
    d = rays_s @ h.rotation.T  # (beams, rays, 3) in W
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        t_low = (lows - h.translation) / d
        t_high = (highs - h.translation) / d
    t = np.where(d > 0, t_high, np.where(d < 0, t_low, np.inf))  # exit distance per axis
    exit_axis = np.argmin(t, axis=-1)
    exit_t = np.min(t, axis=-1)
    wall = exit_axis < 2  # x or y walls; axis 2 is the floor or the surface
    edge = np.where(wall & (exit_t > 0), exit_t, np.inf).min(axis=1)
    return np.where(np.isfinite(edge), edge, np.nan)


def _spacing(frame: SonarFrame) -> float:
    """The median angle between neighbouring beams."""
    azimuths = np.asarray(frame.azimuths_rad)
    return float(np.median(np.abs(np.diff(azimuths)))) if len(azimuths) > 1 else 0.0


def _smoothed_columns(frame: SonarFrame, step: int) -> Floats:
    """Every `step`-th beam of the frame in 8-bit levels, averaged over 5 range bins."""
    columns = unit_image(frame)[:, ::step].astype(np.float64) * 255.0
    padded = np.pad(columns, ((2, 2), (0, 0)))
    total = padded[: len(columns)].copy()
    for k in range(1, 5):
        total += padded[k : k + len(columns)]
    out: Floats = total / 5.0
    return out


def measured_edge(
    smooth: Floats, ranges: Floats, predicted_m: float, window_m: float
) -> float | None:
    """Where the wall band starts along one (smoothed) beam near `predicted_m`: half way up."""
    inside = np.nonzero(np.abs(ranges - predicted_m) <= window_m)[0]
    before = np.nonzero((ranges < predicted_m - window_m) & (ranges > predicted_m - 3 * window_m))[
        0
    ]
    if len(inside) < 5 or len(before) < 5:
        return None
    water = float(np.median(smooth[before]))
    peak_at = inside[int(np.argmax(smooth[inside]))]
    peak = float(smooth[peak_at])
    if peak - water < MIN_CONTRAST:
        return None
    half = water + 0.5 * (peak - water)
    rising = inside[(inside <= peak_at) & (smooth[inside] < half)]
    if len(rising) == 0:
        return None  # the band started before the window: not a clean edge
    i = int(rising[-1])
    # Linear interpolation between the last bin below half and the next one.
    lo, hi = smooth[i], smooth[i + 1]
    frac = (half - lo) / (hi - lo) if hi > lo else 0.0
    return float(ranges[i] + frac * (ranges[i + 1] - ranges[i]))


def _measure(
    observations: list[Observation],
    mount: SonarMountConfig,
    tank: TankBounds,
    params: Floats,
) -> tuple[Floats, Floats, Floats]:
    """(frame index, beam index, measured edge range) for every clean wall edge."""
    frames_i: list[int] = []
    beams_i: list[int] = []
    edges: list[float] = []
    sonar = _mount_with(mount, params[0], params[1], (params[5], params[6]))
    scale, offset = math.exp(params[3]), params[4]
    for f, obs in enumerate(observations):
        frame = obs.frame
        azimuths = np.asarray(frame.azimuths_rad)[::BEAM_STEP]
        rays = _beam_directions(
            mount, azimuths, frame.vertical_aperture_rad, params[2], _spacing(frame)
        )
        predicted = predicted_edges(obs.asv, sonar, rays, tank) / scale + offset
        smooth = _smoothed_columns(frame, BEAM_STEP)
        bins = np.arange(frame.n_ranges, dtype=np.float64) + 0.5
        ranges = frame.range_start_m + bins * frame.range_resolution_m
        reach = ranges[-1]
        for k, r_pred in enumerate(predicted):
            if not np.isfinite(r_pred) or r_pred > 0.9 * reach or r_pred < 1.0:
                continue
            window = max(0.3, 0.06 * r_pred)
            edge = measured_edge(smooth[:, k], ranges, float(r_pred), window)
            if edge is not None:
                frames_i.append(f)
                beams_i.append(k * BEAM_STEP)
                edges.append(edge)
    return np.array(frames_i), np.array(beams_i), np.array(edges)


PARAMETERS = ("yaw", "roll", "widen", "scale", "offset", "x", "y")
# x (along the ASV) is left out: the sonar looks outwards while the ASV turns, so moving it
# forward shortens every wall range alike, which the range offset already is.
FREE = ("yaw", "roll", "widen", "scale", "offset", "y")
X_SCALE = np.array([0.01, 0.01, 0.01, 0.003, 0.02, 0.02, 0.02])


@dataclass(frozen=True)
class _Edges:
    """Measured wall edges and the model that predicts them for a parameter vector."""

    observations: list[Observation]
    mount: SonarMountConfig
    tank: TankBounds
    frames: npt.NDArray[np.int_]
    beams: npt.NDArray[np.int_]
    ranges_m: Floats

    def residuals(self, p: Floats) -> Floats:
        """Measured minus predicted edge range, per edge (parameters as in PARAMETERS)."""
        sonar = _mount_with(self.mount, p[0], p[1], (p[5], p[6]))
        predicted = np.empty(len(self.ranges_m))
        for f in np.unique(self.frames):
            mask = self.frames == f
            frame = self.observations[f].frame
            azimuths = np.asarray(frame.azimuths_rad)[self.beams[mask]]
            rays = _beam_directions(
                self.mount, azimuths, frame.vertical_aperture_rad, p[2], _spacing(frame)
            )
            edge = predicted_edges(self.observations[f].asv, sonar, rays, self.tank)
            predicted[mask] = edge / math.exp(p[3]) + p[4]
        out = self.ranges_m - predicted
        return np.where(np.isfinite(out), out, 0.0)


def fit_mount(
    observations: list[Observation],
    *,
    mount: SonarMountConfig,
    tank: TankBounds,
    free: tuple[str, ...] = FREE,
) -> MountFit:
    """Fit the mount's corrections (the `free` PARAMETERS) to the wall edges of `observations`."""
    from scipy.optimize import least_squares

    if not observations:
        raise CapsdError("calibrate: no sonar frames with an ASV pose to fit")
    free_i = [PARAMETERS.index(name) for name in free]
    params = np.zeros(len(PARAMETERS))
    edges: _Edges | None = None
    result = None
    for _ in range(3):  # measure where the current mount predicts, fit, measure again
        frames_i, beams_i, ranges_m = _measure(observations, mount, tank, params)
        if len(ranges_m) < MIN_MEASUREMENTS:
            raise CapsdError(
                f"calibrate: only {len(ranges_m)} clean wall edges (at least {MIN_MEASUREMENTS} "
                "needed): record with the tank's walls in the sonar's view"
            )
        edges = _Edges(
            observations, mount, tank, frames_i.astype(int), beams_i.astype(int), ranges_m
        )
        base = params.copy()

        def residuals(q: Floats, base: Floats = base, edges: _Edges = edges) -> Floats:
            p = base.copy()
            p[free_i] = q
            return edges.residuals(p)

        result = least_squares(
            residuals, params[free_i], loss="soft_l1", f_scale=F_SCALE_M, x_scale=X_SCALE[free_i]
        )
        params[free_i] = result.x
    assert edges is not None
    assert result is not None
    res = result.fun
    n = len(res)
    jac = np.asarray(result.jac, dtype=np.float64)
    dof = max(n - len(free_i), 1)
    s2 = float(np.sum(res**2) / dof)
    # Two estimates of the covariance, the larger 1-sigma kept: every edge independent, scaled
    # by the residuals' spread (outliers and all), and the sandwich over frames (a frame's
    # edges sharing their errors, the robust loss's weights). Neither holds what the model
    # itself gets wrong (the beam's pattern), so the wider is what is reported.
    cov = np.zeros((len(PARAMETERS), len(PARAMETERS)))
    framed = np.zeros_like(cov)
    try:
        bread: Floats = np.linalg.inv(jac.T @ jac).astype(np.float64)
        cov[np.ix_(free_i, free_i)] = bread * s2
        framed[np.ix_(free_i, free_i)] = _frame_covariance(bread, jac, res, edges.frames)
    except np.linalg.LinAlgError:
        cov[np.ix_(free_i, free_i)] = np.inf
    sig = np.sqrt(np.clip(np.maximum(np.diag(cov), np.diag(framed)), 0.0, np.inf))
    both = float(cov[0, 0] * cov[1, 1])
    corr = float(cov[0, 1]) / math.sqrt(both) if math.isfinite(both) and both > 0 else 0.0
    yaw_sigma, roll_sigma = math.degrees(float(sig[0])), math.degrees(float(sig[1]))
    return MountFit(
        yaw_deg=math.degrees(params[0]),
        yaw_sigma_deg=yaw_sigma,
        roll_deg=math.degrees(params[1]),
        roll_sigma_deg=roll_sigma,
        range_scale=math.exp(params[3]),
        range_scale_sigma=float(sig[3] * math.exp(params[3])),
        shift_y_m=float(params[6]),
        shift_y_sigma_m=float(sig[6]),
        yaw_roll_correlation=corr,
        measurements=n,
        frames=len(np.unique(edges.frames)),
        residual_rms_m=float(np.sqrt(np.mean(res**2))),
        yaw_determined=bool(0 < yaw_sigma <= YAW_SIGMA_MAX_DEG),
        roll_determined=bool(0 < roll_sigma <= ROLL_SIGMA_MAX_DEG),
        shift_determined=bool("y" in free and 0 < sig[6] <= SHIFT_SIGMA_MAX_M),
    )


def _frame_covariance(
    bread: Floats, jac: Floats, residuals: Floats, frames: npt.NDArray[np.int_]
) -> Floats:
    """The fit's covariance with each frame's edges allowed to share their errors.

    A frame's edges are not independent (one pose, one ping's noise): the sandwich estimate
    over frames, (J'J)^-1 (sum over frames of J_f' r_f r_f' J_f) (J'J)^-1 (`bread` is
    (J'J)^-1), with the robust loss's weights (jac is least_squares' weighted Jacobian, so the
    residuals are weighted alike: soft_l1's).
    """
    weighted = residuals / np.sqrt(np.sqrt(1.0 + (residuals / F_SCALE_M) ** 2))
    _, frame_of = np.unique(frames, return_inverse=True)
    scores = np.zeros((int(frame_of.max()) + 1, jac.shape[1]))
    np.add.at(scores, frame_of, jac * weighted[:, None])
    out: Floats = bread @ (scores.T @ scores) @ bread
    return out


def corrected(mount: SonarMountConfig, fit: MountFit) -> SonarMountConfig:
    """The mount with the determined corrections applied (angles stay in the config's terms)."""
    sonar = _mount_with(
        mount,
        math.radians(fit.yaw_deg) if fit.yaw_determined else 0.0,
        math.radians(fit.roll_deg) if fit.roll_determined else 0.0,
        (0.0, fit.shift_y_m if fit.shift_determined else 0.0),
    )
    yaw, pitch, roll = (math.degrees(v) for v in matrix_to_euler_zyx(sonar.rotation))
    x, y, z = (round(float(v), 4) for v in sonar.translation)
    return msgspec.structs.replace(
        mount,
        position_m=(x, y, z),
        yaw_deg=round(yaw, 4),
        pitch_deg=round(pitch, 4),
        roll_deg=round(roll, 4),
    )
