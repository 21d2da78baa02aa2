"""Where a sonar mount's servos are, from the angles its autopilot says it drives them to.

A servo mount has no feedback: ArduPilot reports the angle it drives each servo to, at once,
while the servo slews there at its own rate. A ping taken while it slews, fixed through the
reported angle, is fixed through where the servo is going, not where it is: for a pan, the
fix turns by the difference, the follower turns the pan after it, and the two chase each
other off the ROV (the mockup's pan-tilt demo, session 44: 3.6 % good fixes). So each report
is taken as a new target, and the servo as moving towards the previous target at its rate
until then (the simulator's servo, capsd.simulator.tilt_servo, moves so).

When did the servo take a new target? The autopilot reports at a steady rate (the bridge's
`status_hz`, 20 Hz), so somewhere between the report before and the one that first says it:
taken half way (at most MAX_BACKDATE_NS before the report). Taken at the report's stamp
(session 45's model), the modelled slew ran up to a report period behind the servo: at 60 deg/s,
3 deg of azimuth (a mockup demo's fixes scattered 27-57 mm across the line of sight while the
pan turned, 8-11 mm with it still; docs/JOURNAL.md, session 45).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from capsd.mounts import SonarMountConfig

# A new target is taken at most this long before the report that first says it (a stream
# slower than 5 Hz, or reports lost: the time is not known better than that).
MAX_BACKDATE_NS = 100_000_000


@dataclass(frozen=True)
class ServoState:
    """At `stamp_ns`: where the servos are (tilt, pan; rad) and where they are driven to.

    `since_ns`: when they took those targets, if after the report before (else `stamp_ns`).
    """

    stamp_ns: int
    tilt_rad: float
    pan_rad: float
    tilt_to_rad: float
    pan_to_rad: float
    since_ns: int | None = None


def toward(at: float, to: float, rate_rad_s: float, dt_s: float) -> float:
    """From `at` towards `to` at `rate_rad_s` for `dt_s` (an infinite rate: there at once)."""
    if dt_s <= 0.0:
        return at
    if math.isinf(rate_rad_s):
        return to
    most = rate_rad_s * dt_s
    return at + max(-most, min(most, to - at))


class ServoMotion:
    """The servos' rates (the mount's `tilt` and `pan`); `report` and `at` model their moves."""

    def __init__(self, mount: SonarMountConfig):
        self.tilt_rate_rad_s = (
            math.inf if mount.tilt is None else math.radians(mount.tilt.rate_deg_s)
        )
        self.pan_rate_rad_s = math.inf if mount.pan is None else math.radians(mount.pan.rate_deg_s)

    def at(self, state: ServoState, stamp_ns: int) -> ServoState:
        """The servos at `stamp_ns` (at or after `state`'s stamp), driven to `state`'s targets."""
        dt = max(0.0, (stamp_ns - state.stamp_ns) / 1e9)
        return ServoState(
            stamp_ns,
            toward(state.tilt_rad, state.tilt_to_rad, self.tilt_rate_rad_s, dt),
            toward(state.pan_rad, state.pan_to_rad, self.pan_rate_rad_s, dt),
            state.tilt_to_rad,
            state.pan_to_rad,
        )

    def report(
        self, previous: ServoState | None, stamp_ns: int, tilt_rad: float, pan_rad: float
    ) -> ServoState:
        """The servos at a report, driven to the reported angles (see the module).

        Moved since `previous` towards its targets until the new ones were taken, then towards
        those (None, or a report older than it: taken as where it says).
        """
        if previous is None or stamp_ns < previous.stamp_ns:
            return ServoState(stamp_ns, tilt_rad, pan_rad, tilt_rad, pan_rad)
        if (tilt_rad, pan_rad) == (previous.tilt_to_rad, previous.pan_to_rad):
            moved = self.at(previous, stamp_ns)
            return ServoState(stamp_ns, moved.tilt_rad, moved.pan_rad, tilt_rad, pan_rad)
        since = stamp_ns - min((stamp_ns - previous.stamp_ns) // 2, MAX_BACKDATE_NS)
        moved = self._retargeted(previous, since, tilt_rad, pan_rad, stamp_ns)
        return ServoState(stamp_ns, moved.tilt_rad, moved.pan_rad, tilt_rad, pan_rad, since)

    def between(self, a: ServoState, b: ServoState, fraction: float) -> ServoState:
        """The servos at `fraction` of the way from report `a` to report `b` (past `b` too)."""
        stamp = a.stamp_ns + round(fraction * (b.stamp_ns - a.stamp_ns))
        if stamp > b.stamp_ns:
            return self.at(b, stamp)
        if b.since_ns is None or stamp <= b.since_ns:
            return self.at(a, stamp)
        return self._retargeted(a, b.since_ns, b.tilt_to_rad, b.pan_to_rad, stamp)

    def _retargeted(
        self, before: ServoState, since_ns: int, tilt_to: float, pan_to: float, stamp_ns: int
    ) -> ServoState:
        """At `stamp_ns`: towards `before`'s targets until `since_ns`, then towards these."""
        start = self.at(before, since_ns)
        return self.at(
            ServoState(since_ns, start.tilt_rad, start.pan_rad, tilt_to, pan_to), stamp_ns
        )
