"""Self-calibration of the ROV's depth reading: its offset from a float at the surface.

ArduSub zeroes its pressure sensor at boot, so a depth reading is off by whatever the surface
pressure then was against now (and the port is not quite where the drawing puts it). Floating
at rest at the surface, the ROV's origin is at its known floating depth (`rov.float_depth_m`),
so the pressure port should read that plus its lever arm: the mean difference over a stretch
of calm floating is the offset every later reading needs. Waves heave a floating ROV by a few
centimetres; they average out over several of their periods. What stays is how well the
floating depth itself is known (trim, ballast, payload): FLOAT_DEPTH_SIGMA_M.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from capsd.geometry import quat_to_matrix
from capsd.mounts import RovConfig
from capsd.payloads import RovAttitude, RovDepth

# A reading this far deeper than a floating ROV's is not floating (the offset is a few cm).
FLOATING_WITHIN_M = 0.3
# Readings this far from the floating stretch's median are the start of a dive, not waves.
HEAVE_WITHIN_M = 0.06
MIN_FLOAT_S = 10.0  # two or three wave periods at least
MAX_GAP_S = 1.0  # a longer silence ends a stretch
FLOAT_DEPTH_SIGMA_M = 0.01  # how well a trimmed ROV's floating depth is known
WAVE_PERIOD_S = 5.0  # readings closer than this in time are not independent
MAX_SIGMA_M = 0.015  # determined (and applied) within this 1-sigma


@dataclass(frozen=True)
class DepthFit:
    """The offset to add to every depth reading, with its 1-sigma and what it rests on."""

    offset_m: float
    sigma_m: float
    readings: int
    floating_s: float
    heave_rms_m: float
    determined: bool
    why_not: str | None = None

    def lines(self) -> list[str]:
        """What a person reads: the estimate, its uncertainty, or why there is none."""
        if not self.determined:
            return [f"depth offset           NOT determined: {self.why_not}"]
        return [
            f"depth offset           {self.offset_m * 1000:+.1f} mm  (1 sigma "
            f"{self.sigma_m * 1000:.1f}, of which {FLOAT_DEPTH_SIGMA_M * 1000:.0f} from the "
            f"floating depth) determined: {self.readings} readings floating for "
            f"{self.floating_s:.0f} s, heave rms {self.heave_rms_m * 1000:.0f} mm",
        ]


def _port_float_depths(
    depths: Sequence[RovDepth], attitudes: Sequence[RovAttitude], rov: RovConfig
) -> np.ndarray:
    """Per reading, the depth the port would read floating: the arm turned by the attitude."""
    arm = np.array(rov.pressure_sensor_m)
    if not attitudes:
        return np.full(len(depths), rov.float_depth_m - arm[2])
    stamps = np.array([a.stamp_ns for a in attitudes])
    order = np.argsort(stamps)
    stamps = stamps[order]
    out = np.empty(len(depths))
    for i, depth in enumerate(depths):
        k = int(np.clip(np.searchsorted(stamps, depth.stamp_ns), 0, len(stamps) - 1))
        if k > 0 and abs(stamps[k - 1] - depth.stamp_ns) < abs(stamps[k] - depth.stamp_ns):
            k -= 1
        rotation = quat_to_matrix(np.array(attitudes[order[k]].orientation_xyzw))
        out[i] = rov.float_depth_m - float((rotation @ arm)[2])
    return out


def _stretches(stamps_s: np.ndarray, inside: np.ndarray) -> list[np.ndarray]:
    """Index runs of `inside` readings with no gap over MAX_GAP_S."""
    runs: list[np.ndarray] = []
    current: list[int] = []
    for i, ok in enumerate(inside):
        if current and (not ok or stamps_s[i] - stamps_s[current[-1]] > MAX_GAP_S):
            runs.append(np.array(current))
            current = []
        if ok:
            current.append(i)
    if current:
        runs.append(np.array(current))
    return runs


def fit_depth_offset(
    depths: Sequence[RovDepth], attitudes: Sequence[RovAttitude], *, rov: RovConfig
) -> DepthFit:
    """The depth offset from the longest stretch in which the ROV floated at the surface."""

    def none(why: str) -> DepthFit:
        return DepthFit(0.0, math.inf, 0, 0.0, 0.0, False, why)

    if not depths:
        return none("no depth readings (record the ROV's depth with the bridge running)")
    depths = sorted(depths, key=lambda d: d.stamp_ns)
    readings = np.array([d.depth_m for d in depths])
    stamps_s = (np.array([d.stamp_ns for d in depths]) - depths[0].stamp_ns) / 1e9
    wanted = _port_float_depths(depths, attitudes, rov)
    difference = wanted - readings  # the offset, reading by reading, while floating
    best: np.ndarray | None = None
    for run in _stretches(stamps_s, readings < wanted + FLOATING_WITHIN_M):
        # The calm part: near the stretch's median (a dive's start leaves it).
        calm = run[np.abs(difference[run] - np.median(difference[run])) <= HEAVE_WITHIN_M]
        if len(calm) > 1 and (best is None or _span(stamps_s[calm]) > _span(stamps_s[best])):
            best = calm
    if best is None or _span(stamps_s[best]) < MIN_FLOAT_S:
        longest = 0.0 if best is None else _span(stamps_s[best])
        return none(
            f"the ROV floated at the surface for {longest:.0f} s at most (at least "
            f"{MIN_FLOAT_S:.0f} s needed: record it floating before the dive)"
        )
    floating_s = _span(stamps_s[best])
    offset = float(np.mean(difference[best]))
    heave = float(np.std(difference[best]))
    independent = max(floating_s / WAVE_PERIOD_S, 1.0)
    sigma = math.hypot(heave / math.sqrt(independent), FLOAT_DEPTH_SIGMA_M)
    return DepthFit(
        offset_m=offset,
        sigma_m=sigma,
        readings=len(best),
        floating_s=floating_s,
        heave_rms_m=heave,
        determined=sigma <= MAX_SIGMA_M,
        why_not=None if sigma <= MAX_SIGMA_M else f"1 sigma {sigma * 1000:.0f} mm (waves?)",
    )


def _span(stamps_s: np.ndarray) -> float:
    return float(stamps_s[-1] - stamps_s[0]) if len(stamps_s) else 0.0
