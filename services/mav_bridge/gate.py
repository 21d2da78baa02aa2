"""The safety gate: which estimates may reach the autopilot, and why others may not.

The estimates are the locator's ROV fixes (the ROV's bridge) or the ASV's own pose (the ASV's
bridge, `role: asv`); a pose is "good" when its status is "ok".

An estimate passes only if it is "good", carries a position and covariance, is younger than
`max_age_s` (by this computer's clock, from its measurement stamp), its largest horizontal
standard deviation is within `max_sigma_m`, measured at least 1 / `max_rate_hz` after the last
one sent, and its time (usec) is later than the last one sent. Every decision is counted by
reason. The rate is limited by measurement stamps, as EKF3's writeExtNavData thins external
navigation (20 ms apart by their timestamps): pings 25 ms apart all pass, however jittered
their arrival. A position outside the tank (plus its margin), or absurdly far, is refused.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from typing import Literal

import numpy as np

from capsd.geometry import Array
from capsd.payloads import AsvPose, RovFix
from capsd.tank import TankBounds

Decision = Literal[
    "sent", "not_good", "no_position", "stale", "from_future", "uncertain", "rate_limited",
    "not_monotonic", "outside_tank",
]  # fmt: skip
# Whatever the tank, a position further than this from W's origin is absurd (a 1e30 m fix).
_MAX_ABS_POSITION_M = 10_000.0

# Clocks are chrony-synced; a stamp further ahead than this is a clock fault, not a fix.
_MAX_FUTURE_NS = 200_000_000


@dataclass(frozen=True)
class GateSettings:
    max_age_s: float = 0.3
    max_sigma_m: float = 0.5
    max_rate_hz: float = 50.0


@dataclass(frozen=True)
class Passed:
    """An estimate cleared to send."""

    usec: int
    position_w: Array
    covariance_w: Array
    reset_counter: int
    orientation_xyzw: tuple[float, float, float, float] | None = None  # an ASV pose's own


Estimate = RovFix | AsvPose


class SafetyGate:
    """Stateful: remembers the last estimate sent (rate limit, monotonic usec)."""

    def __init__(self, settings: GateSettings, *, tank: TankBounds | None = None):
        self.settings = settings
        self.tank = tank
        self.counts: Counter[Decision] = Counter()
        self._last_sent_stamp_ns: int | None = None
        self._last_usec = 0

    def from_future(self, fix: Estimate, *, now_ns: int) -> bool:
        """Stamped further ahead than clock skew explains (checked on arrival, and at send)."""
        future = fix.stamp_ns - now_ns > _MAX_FUTURE_NS
        if future:
            self.counts["from_future"] += 1
        return future

    def check(self, fix: Estimate, *, now_ns: int) -> Passed | Decision:
        decision = self._decide(fix, now_ns=now_ns)
        self.counts["sent" if isinstance(decision, Passed) else decision] += 1
        return decision

    def _decide(self, fix: Estimate, *, now_ns: int) -> Passed | Decision:
        s = self.settings
        orientation = None
        if isinstance(fix, AsvPose):
            if fix.status != "ok":
                return "not_good"
            position: tuple[float, ...] | None = fix.position_m
            pose_cov = np.array(fix.covariance).reshape(6, 6)
            covariance: tuple[float, ...] | None = tuple(pose_cov[:3, :3].ravel())
            orientation = fix.orientation_xyzw
            resets = 0
        else:
            if fix.quality != "good":
                return "not_good"
            position = fix.position_m if fix.position_m is not None else fix.raw_position_m
            covariance = fix.covariance_m2 if fix.position_m is not None else fix.raw_covariance_m2
            resets = fix.track_resets
        if position is None or covariance is None:
            return "no_position"
        age_ns = now_ns - fix.stamp_ns
        if age_ns > s.max_age_s * 1e9:
            return "stale"
        if age_ns < -_MAX_FUTURE_NS:
            return "from_future"
        if not all(abs(v) <= _MAX_ABS_POSITION_M for v in position) or (
            self.tank is not None and not self.tank.contains(np.array(position))
        ):
            return "outside_tank"
        cov = np.array(covariance).reshape(3, 3)
        horizontal = np.linalg.eigvalsh(cov[:2, :2])
        if not math.sqrt(max(float(horizontal[-1]), 0.0)) <= s.max_sigma_m:
            return "uncertain"
        usec = fix.stamp_ns // 1000
        if usec <= self._last_usec:
            return "not_monotonic"
        last = self._last_sent_stamp_ns
        if last is not None and fix.stamp_ns - last < 1e9 / s.max_rate_hz:
            return "rate_limited"
        self._last_sent_stamp_ns = fix.stamp_ns
        self._last_usec = usec
        return Passed(usec, np.array(position), cov, resets, orientation)
