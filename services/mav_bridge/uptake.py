"""Whether the autopilot uses the estimates we send, from its own SYS_STATUS.

ArduPilot reports external position (MAV_SYS_STATUS_SENSOR_VISION_POSITION) present once
VISO_TYPE is set and healthy only while the backend it made at boot has had an estimate within
300 ms. Estimates sent for a while without a healthy report mean the autopilot drops them:
VISO_TYPE is 0, or it was set since the last boot (a reboot is pending). Position hold then
does not work although every fix goes out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

SensorState = Literal["absent", "unhealthy", "healthy"]


@dataclass(frozen=True)
class UptakeSettings:
    sustained_s: float = 3.0  # sending, and not once healthy, for this long
    status_max_age_s: float = 3.0  # a SYS_STATUS older than this says nothing


class EstimateUptake:
    """Feed it what we send and what SYS_STATUS says; `ignored` says if the autopilot drops it."""

    def __init__(self, settings: UptakeSettings = UptakeSettings()):
        self.settings = settings
        self.reset()

    def reset(self) -> None:
        """Forget everything (the link was lost: what the autopilot said no longer holds)."""
        self._sending_since: float | None = None
        self._last_sent = -math.inf
        self._last_status = -math.inf
        self._last_healthy = -math.inf
        self.state: SensorState | None = None

    def sent(self, now: float) -> None:
        if now - self._last_sent > 1.0:  # a gap of a second: a new run of estimates
            self._sending_since = now
        self._last_sent = now

    def status(self, state: SensorState, now: float) -> None:
        self.state = state
        self._last_status = now
        if state == "healthy":
            self._last_healthy = now

    def ignored(self, now: float) -> bool:
        """Sending for `sustained_s`, fresh SYS_STATUS, never healthy in that time."""
        s = self.settings
        return (
            self._sending_since is not None
            and now - self._last_sent < 1.0
            and now - self._sending_since >= s.sustained_s
            and now - self._last_status <= s.status_max_age_s
            and now - self._last_healthy > s.sustained_s
        )
