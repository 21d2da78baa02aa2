"""Self-calibration of the range offset: a parked ROV's fixes while the ASV swings round it.

What the wall fit cannot see (capsd.mount_calibration): where along its own axis the sonar
sits. From one viewpoint a forward offset of the sonar, the detector's range bias to the ROV's
centre and the ROV's true position cannot be told apart. With the ROV parked (on the floor or a
stand) and the ASV swinging round it on an arc, facing it, the line of sight turns: every fix
is the ROV's fixed position plus an offset along the line of sight (the range offset, whatever
makes it) and one across it (what the heading and sideways fit left). A linear least-squares
fit separates the three; the line of sight must turn far enough (MIN_SPREAD_DEG).

What it measures is the sum of everything that moves a fix along the line of sight in this
geometry: the sonar's forward position, the detector's range bias, and the part of a depth or
sonar-height error that the depth constraint turns into horizontal range at this depression.
It is applied as the sonar's forward position, right where the ROV is seen at the orbit's
ranges and depression, the usual ones when the ASV keeps the ROV in view.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from capsd.errors import CapsdError
from capsd.geometry import Transform
from capsd.payloads import RovFix
from capsd.pose_lookup import PoseLookup

MIN_FIXES = 100
MIN_SPREAD_DEG = 60.0  # how far the line of sight must turn for the offset to be told apart
MAX_SIGMA_M = 0.01  # written only when known this well
INDEPENDENT_EVERY_S = 1.0  # fixes closer than this share their errors (the uncertainty's count)
# What the fit misses by beyond its own statistics, added to its 1-sigma: `capsd bench
# calibrate` (pond, 5 seeds) finds it 0.4-13.4 mm (RMS 7.2 mm) off what the fixes truly were
# off along the sight (less the ASV pose estimate's own error): the ROV's place and the offset
# are only partly apart on a 150 deg arc, and the echo's range bias changes with range as the
# ASV goes in and out.
MODEL_SIGMA_M = 0.007


@dataclass(frozen=True)
class RangeFit:
    """Offsets of the fixes along and across the line of sight (m), the ROV's place, how sure."""

    along_m: float  # positive: the fixes lie too far from the sonar
    along_sigma_m: float
    across_m: float  # positive: to the left of the line of sight, seen from the sonar
    across_sigma_m: float
    rov_xy_m: tuple[float, float]
    fixes: int
    spread_deg: float
    residual_m: float
    # How much the along offset grows per metre the sonar truly sits higher than configured:
    # the depth constraint turns a height error into horizontal range by the sight's dip
    # (the mean over the fixes of their drop over their horizontal distance). The pitch
    # manoeuvre's height fit needs it: the forward position written took that part in.
    height_coupling: float = math.nan

    @property
    def determined(self) -> bool:
        """Whether the forward position is known well enough to write."""
        return (
            self.fixes >= MIN_FIXES
            and self.spread_deg >= MIN_SPREAD_DEG
            and self.along_sigma_m <= MAX_SIGMA_M
        )

    def lines(self) -> list[str]:
        """What a person reads."""
        verdict = (
            f"determined: the sonar's forward position moves by {-self.along_m * 1000:+.1f} mm"
            if self.determined
            else f"NOT determined (needs >= {MIN_FIXES} fixes, the line of sight turning >= "
            f"{MIN_SPREAD_DEG:g} deg, 1-sigma <= {MAX_SIGMA_M * 1000:g} mm)"
        )
        return [
            f"range offset along the line of sight: {self.along_m * 1000:+.1f} mm "
            f"(1-sigma {self.along_sigma_m * 1000:.1f} mm) from {self.fixes} fixes of the "
            f"parked ROV, the line of sight turning {self.spread_deg:.0f} deg: {verdict}",
            f"  across it {self.across_m * 1000:+.1f} mm (1-sigma "
            f"{self.across_sigma_m * 1000:.1f} mm; the heading and sideways fit's remainder), "
            f"fix scatter {self.residual_m * 1000:.1f} mm",
        ]


def fit_range_offset(fixes: Sequence[RovFix], poses: PoseLookup, *, mount: Transform) -> RangeFit:
    """The offsets from the good fixes of a parked ROV, each with the sonar's place then."""
    rows: list[tuple[float, float, float, int]] = []  # x, y, line-of-sight bearing, stamp
    dips: list[float] = []  # each fix's drop below the sonar over its horizontal distance
    for fix in fixes:
        if fix.quality != "good" or fix.raw_position_m is None:
            continue
        asv = poses.at(fix.stamp_ns)
        if asv is None:
            continue
        sonar = asv.compose(mount).translation
        x, y = fix.raw_position_m[0], fix.raw_position_m[1]
        angle = math.atan2(y - float(sonar[1]), x - float(sonar[0]))
        rows.append((x, y, angle, fix.stamp_ns))
        horizontal = math.hypot(x - float(sonar[0]), y - float(sonar[1]))
        dips.append((float(sonar[2]) - fix.raw_position_m[2]) / max(horizontal, 0.1))
    if len(rows) < 4:
        raise CapsdError(
            f"{len(rows)} good fixes with an ASV pose: the range offset needs the parked ROV "
            "tracked (record cap/** with the locator running)"
        )
    data = np.array([r[:3] for r in rows])
    stamps = np.array([r[3] for r in rows], dtype=np.int64)
    u = np.column_stack([np.cos(data[:, 2]), np.sin(data[:, 2])])
    v = np.column_stack([-u[:, 1], u[:, 0]])
    n = len(rows)
    design = np.zeros((2 * n, 4))
    design[0::2, 0] = 1.0
    design[1::2, 1] = 1.0
    design[0::2, 2], design[1::2, 2] = u[:, 0], u[:, 1]
    design[0::2, 3], design[1::2, 3] = v[:, 0], v[:, 1]
    observed = data[:, :2].reshape(-1)
    solution, *_ = np.linalg.lstsq(design, observed, rcond=None)
    residual = observed - design @ solution
    # Neighbouring fixes share their errors: count one independent pair per INDEPENDENT_EVERY_S.
    span_s = (int(stamps.max()) - int(stamps.min())) / 1e9
    independent = max(min(n, span_s / INDEPENDENT_EVERY_S), 2.0)
    variance = float(residual @ residual) / max(2 * n - 4, 1)
    covariance = np.linalg.pinv(design.T @ design) * variance * (n / independent)
    angles = np.unwrap(data[:, 2])
    return RangeFit(
        along_m=float(solution[2]),
        along_sigma_m=math.sqrt(max(float(covariance[2, 2]), 0.0) + MODEL_SIGMA_M**2),
        across_m=float(solution[3]),
        across_sigma_m=math.sqrt(max(float(covariance[3, 3]), 0.0)),
        rov_xy_m=(float(solution[0]), float(solution[1])),
        fixes=n,
        spread_deg=math.degrees(float(angles.max() - angles.min())),
        residual_m=float(np.sqrt(variance)),
        height_coupling=float(np.mean(dips)),
    )


__all__ = ["RangeFit", "fit_range_offset"]
