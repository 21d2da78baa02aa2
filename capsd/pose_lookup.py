"""The ASV pose at a ping's stamp, from a recorded pose stream: interpolated, if close enough."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from capsd.geometry import Transform, quat_to_matrix
from capsd.payloads import AsvPose

MAX_POSE_GAP_NS = 200_000_000  # a pose further than this from the ping is not used


class PoseLookup:
    """Poses sorted by stamp; `at(stamp_ns)` gives H_W_B (None: none near, or lost)."""

    def __init__(self, poses: list[AsvPose]):
        self.poses = sorted(poses, key=lambda p: p.stamp_ns)
        self.stamps: npt.NDArray[np.int64] = np.array(
            [p.stamp_ns for p in self.poses], dtype=np.int64
        )

    def at(self, stamp_ns: int, *, max_gap_ns: int = MAX_POSE_GAP_NS) -> Transform | None:
        """H_W_B at `stamp_ns`, interpolated between the poses either side (slerp).

        At either end, the nearer pose; None when none is within `max_gap_ns` or it is lost.

        Interpolation matters on a turning ASV: at 6 deg/s a pose one LiDAR scan old is 0.4 deg
        off in heading.
        """
        if not self.poses:
            return None
        i = int(np.searchsorted(self.stamps, stamp_ns))
        if 0 < i < len(self.poses):
            before, after = self.poses[i - 1], self.poses[i]
            if (
                after.stamp_ns - before.stamp_ns <= 2 * max_gap_ns
                and before.status != "lost"
                and after.status != "lost"
            ):
                span = after.stamp_ns - before.stamp_ns
                frac = (stamp_ns - before.stamp_ns) / span if span > 0 else 0.0
                return _interpolate(before, after, frac)
        best = min(
            (k for k in (i - 1, i) if 0 <= k < len(self.poses)),
            key=lambda k: abs(int(self.stamps[k]) - stamp_ns),
        )
        pose = self.poses[best]
        if abs(pose.stamp_ns - stamp_ns) > max_gap_ns or pose.status == "lost":
            return None
        return Transform(quat_to_matrix(np.array(pose.orientation_xyzw)), np.array(pose.position_m))


def _interpolate(a: AsvPose, b: AsvPose, frac: float) -> Transform:
    """The pose a fraction `frac` of the way from `a` to `b` (slerp, linear position)."""
    qa, qb = np.array(a.orientation_xyzw), np.array(b.orientation_xyzw)
    dot = float(qa @ qb)
    if dot < 0.0:  # the shorter way round
        qb, dot = -qb, -dot
    if dot > 0.9995:
        q = qa + frac * (qb - qa)
    else:
        theta = math.acos(dot)
        q = (math.sin((1 - frac) * theta) * qa + math.sin(frac * theta) * qb) / math.sin(theta)
    q = q / np.linalg.norm(q)
    position = (1 - frac) * np.array(a.position_m) + frac * np.array(b.position_m)
    return Transform(quat_to_matrix(q), position)
