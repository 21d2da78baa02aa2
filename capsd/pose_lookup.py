"""The ASV pose at a ping's stamp, from a recorded pose stream: the nearer pose, if close enough."""

from __future__ import annotations

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
        if not self.poses:
            return None
        i = int(np.searchsorted(self.stamps, stamp_ns))
        best = min(
            (k for k in (i - 1, i) if 0 <= k < len(self.poses)),
            key=lambda k: abs(int(self.stamps[k]) - stamp_ns),
        )
        pose = self.poses[best]
        if abs(pose.stamp_ns - stamp_ns) > max_gap_ns or pose.status == "lost":
            return None
        return Transform(quat_to_matrix(np.array(pose.orientation_xyzw)), np.array(pose.position_m))
