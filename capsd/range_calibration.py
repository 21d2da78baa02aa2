"""Self-calibration of the range offset and the sonar's forward position: a parked ROV's fixes.

What the wall fit cannot see (capsd.mount_calibration): where along its own axis the sonar
sits, and what the detector's ranges are off by. From one viewpoint a forward offset of the
sonar, a range offset and the ROV's true position cannot be told apart. With the ROV parked
(on the floor or a stand) and the ASV swinging round it on an arc, the line of sight turns:
every fix is the ROV's fixed place plus an offset along the line of sight (the range offset)
and one across it (what the heading and sideways fit left). With the ASV also looking to
either side of the ROV as it goes (the ROV seen up to about 25 deg off the boresight), the
sonar's forward offset moves the fixes along the ASV's own axis, which then turns against the
line of sight: across the sight by sin(azimuth), where no range offset reaches. A linear
least-squares fit separates the four; the line of sight must turn far enough
(MIN_SPREAD_DEG), and the azimuths spread (MIN_LOOK_SPREAD_DEG) for the forward position.

The range offset is in slant metres, as the sonar measures: the detector's range bias to the
ROV's centre, the sonar's own zero, and the part of a depth or sonar-height error that the
depth constraint turns into horizontal range at this dip (`height_coupling`). It is applied
to every detection's range (SonarMountConfig.range_offset_m); the forward offset to the
sonar's position.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from capsd.errors import CapsdError
from capsd.geometry import Transform
from capsd.payloads import RovFix
from capsd.pose_lookup import PoseLookup

Floats = npt.NDArray[np.float64]
MIN_FIXES = 100
MIN_SPREAD_DEG = 60.0  # how far the line of sight must turn for the offset to be told apart
# How far apart (5th to 95th percentile) the ROV's azimuths in the sonar must lie for the
# forward position: at +-25 deg a forward offset moves a fix across the sight by 0.42 of itself.
MIN_LOOK_SPREAD_DEG = 25.0
MAX_SIGMA_M = 0.01  # written only when known this well
INDEPENDENT_EVERY_S = 1.0  # fixes closer than this share their errors (the uncertainty's count)
# What the fit misses by beyond its own statistics, added to its 1-sigma: `capsd bench
# calibrate` (pond, 5 seeds) found the along offset 0.4-13.4 mm (RMS 7.2 mm) off what the fixes
# truly were off along the sight (session 20), and the range offset with the forward term
# 2.0-5.4 mm (RMS 3.6 mm, session 28; always short): the ROV's place and the offset are only
# partly apart on a 150 deg arc, and the echo's range bias changes with range as the ASV goes
# in and out. Kept at the larger.
MODEL_SIGMA_M = 0.007
# The same for the forward position: `capsd bench calibrate` (pond, 5 seeds, session 28) found
# the fit 1.3-1.7 mm off what the orbit's fixes were off along the ASV's axis, and the position
# written 0.9-40.3 mm off where a fix needs the sonar (RMS 20.4 mm): what the detector gets
# wrong that grows with the azimuth (on our renderer its bearings 0.3-0.4 % wide) looks like a
# forward offset. This term covers the first; the second is the renderer's (docs/INSTALL-ERRORS).
FORWARD_MODEL_SIGMA_M = 0.005


@dataclass(frozen=True)
class RangeFit:
    """Offsets of the fixes along and across the line of sight, forward, the ROV's place."""

    range_offset_m: float  # slant; positive: the ranges are too long (the fixes too far)
    range_offset_sigma_m: float
    across_m: float  # positive: to the left of the line of sight, seen from the sonar
    across_sigma_m: float
    rov_xy_m: tuple[float, float]
    fixes: int
    spread_deg: float
    residual_m: float
    # The fixes' offset along the ASV's forward axis (the sonar sits that much further back
    # than configured); NaN where the azimuths did not spread (then in the range offset).
    forward_m: float = math.nan
    forward_sigma_m: float = math.nan
    look_spread_deg: float = 0.0
    # How much the range offset grows per metre the sonar truly sits higher than configured:
    # the depth constraint turns a height error into horizontal range by tan(dip), which is
    # sin(dip) of slant range (the mean over the fixes). The pitch manoeuvre's height fit
    # needs it: the range offset written took that part in.
    height_coupling: float = math.nan

    @property
    def determined(self) -> bool:
        """Whether the forward position is known well enough to write."""
        return (
            self.fixes >= MIN_FIXES
            and self.spread_deg >= MIN_SPREAD_DEG
            and self.range_offset_sigma_m <= MAX_SIGMA_M
        )

    @property
    def forward_apart(self) -> bool:
        """Whether the fit held the forward offset apart (else the range offset took it in)."""
        return self.forward_sigma_m <= MAX_SIGMA_M  # NaN (not fitted) compares False

    @property
    def forward_determined(self) -> bool:
        """Whether the sonar's forward position is known well enough to write."""
        return self.determined and self.forward_apart

    def lines(self) -> list[str]:
        """What a person reads."""
        needs = (
            f"needs >= {MIN_FIXES} fixes, the line of sight turning >= {MIN_SPREAD_DEG:g} deg, "
            f"1-sigma <= {MAX_SIGMA_M * 1000:g} mm"
        )
        verdict = (
            f"determined: every range moves by {-self.range_offset_m * 1000:+.1f} mm"
            if self.determined
            else f"NOT determined ({needs})"
        )
        if self.forward_determined:
            forward = f"determined: the sonar's position moves by {-self.forward_m * 1000:+.1f} mm"
        elif math.isnan(self.forward_m):
            forward = (
                f"NOT determined: the ROV's azimuths spread {self.look_spread_deg:.0f} deg "
                f"(needs >= {MIN_LOOK_SPREAD_DEG:g}: the ASV looking to either side of it), "
                "so it is in the range offset"
            )
        elif not self.forward_apart:
            limit = MAX_SIGMA_M * 1000
            forward = f"NOT determined (1-sigma > {limit:g} mm), so it is in the range offset"
        else:
            forward = f"NOT determined ({needs})"
        sigma = self.forward_sigma_m * 1000
        return [
            f"range offset along the line of sight: {self.range_offset_m * 1000:+.1f} mm "
            f"(1-sigma {self.range_offset_sigma_m * 1000:.1f} mm) from {self.fixes} fixes of "
            f"the parked ROV, the line of sight turning {self.spread_deg:.0f} deg: {verdict}",
            f"  sonar forward offset {self.forward_m * 1000:+.1f} mm (1-sigma {sigma:.1f} mm), "
            f"azimuths spread {self.look_spread_deg:.0f} deg: {forward}",
            f"  across it {self.across_m * 1000:+.1f} mm (1-sigma "
            f"{self.across_sigma_m * 1000:.1f} mm; the heading and sideways fit's remainder), "
            f"fix scatter {self.residual_m * 1000:.1f} mm",
        ]


def fit_range_offset(fixes: Sequence[RovFix], poses: PoseLookup, *, mount: Transform) -> RangeFit:
    """The offsets from the good fixes of a parked ROV, each with the sonar's place then."""
    rows: list[list[float]] = []
    stamps: list[int] = []
    for fix in fixes:
        if fix.quality != "good" or fix.raw_position_m is None:
            continue
        asv = poses.at(fix.stamp_ns)
        if asv is None:
            continue
        sonar = asv.compose(mount)
        x, y, z = fix.raw_position_m
        dx, dy = x - float(sonar.translation[0]), y - float(sonar.translation[1])
        horizontal = max(math.hypot(dx, dy), 0.1)
        drop = float(sonar.translation[2]) - z
        boresight = sonar.rotation[:2, 0]
        forward = asv.rotation[:2, 0]  # the ASV's own axis: where a forward offset moves a fix
        rows.append([
            x, y, math.atan2(dy, dx), math.atan2(float(boresight[1]), float(boresight[0])),
            math.hypot(horizontal, drop) / horizontal, drop / math.hypot(horizontal, drop),
            float(forward[0]), float(forward[1]),
        ])  # fmt: skip
        stamps.append(fix.stamp_ns)
    if len(rows) < 4:
        raise CapsdError(
            f"{len(rows)} good fixes with an ASV pose: the range offset needs the parked ROV "
            "tracked (record cap/** with the locator running)"
        )
    data = np.array(rows)
    sight, slant_per_horizontal = data[:, 2], data[:, 4]
    u = np.column_stack([np.cos(sight), np.sin(sight)])
    v = np.column_stack([-u[:, 1], u[:, 0]])
    azimuth = np.degrees(np.angle(np.exp(1j * (sight - data[:, 3]))))
    look_spread = float(np.percentile(azimuth, 95) - np.percentile(azimuth, 5))
    columns = [u * slant_per_horizontal[:, None], v]
    span_s = (max(stamps) - min(stamps)) / 1e9
    forward_m = forward_sigma_m = math.nan
    if look_spread >= MIN_LOOK_SPREAD_DEG:
        with_forward = _solve(data[:, :2], [*columns, data[:, 6:8]], span_s)
        forward_m = float(with_forward.solution[4])
        forward_sigma_m = math.hypot(float(with_forward.sigmas[4]), FORWARD_MODEL_SIGMA_M)
    # The forward position apart where it is known well enough; else the range offset takes
    # it in, as from an orbit facing the ROV (a short one: both known less well apart).
    apart = forward_sigma_m <= MAX_SIGMA_M
    fit = with_forward if apart else _solve(data[:, :2], columns, span_s)
    angles = np.unwrap(sight)
    return RangeFit(
        range_offset_m=float(fit.solution[2]),
        range_offset_sigma_m=math.hypot(float(fit.sigmas[2]), MODEL_SIGMA_M),
        across_m=float(fit.solution[3]),
        across_sigma_m=float(fit.sigmas[3]),
        rov_xy_m=(float(fit.solution[0]), float(fit.solution[1])),
        fixes=len(rows),
        spread_deg=math.degrees(float(angles.max() - angles.min())),
        residual_m=fit.residual_m,
        forward_m=forward_m,
        forward_sigma_m=forward_sigma_m,
        look_spread_deg=look_spread,
        height_coupling=float(np.mean(data[:, 5])),
    )


@dataclass(frozen=True)
class _Solved:
    solution: Floats
    sigmas: Floats
    residual_m: float


def _solve(fixes_xy: Floats, columns: list[Floats], span_s: float) -> _Solved:
    """Least squares: each fix is the ROV's place plus the columns (2-vectors per fix) scaled."""
    n = len(fixes_xy)
    design = np.zeros((2 * n, 2 + len(columns)))
    design[0::2, 0] = 1.0
    design[1::2, 1] = 1.0
    for j, column in enumerate(columns):
        design[0::2, 2 + j], design[1::2, 2 + j] = column[:, 0], column[:, 1]
    observed = fixes_xy.reshape(-1)
    solution: Floats = np.linalg.lstsq(design, observed, rcond=None)[0].astype(np.float64)
    residual = observed - design @ solution
    # Neighbouring fixes share their errors: count one independent pair per INDEPENDENT_EVERY_S.
    independent = max(min(n, span_s / INDEPENDENT_EVERY_S), 2.0)
    variance = float(residual @ residual) / max(2 * n - design.shape[1], 1)
    covariance = np.linalg.pinv(design.T @ design) * variance * (n / independent)
    sigmas: Floats = np.sqrt(np.maximum(np.diag(covariance), 0.0)).astype(np.float64)
    return _Solved(solution, sigmas, math.sqrt(variance))


__all__ = ["RangeFit", "fit_range_offset"]
