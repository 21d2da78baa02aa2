"""The vehicle's boot-time clock mapped to Unix time, by the minimum-latency rule.

Each message stamped `time_boot_ms` arrives at Unix time `arrival = boot + offset + latency`,
latency >= 0, so the smallest `arrival - boot` over a window is the best estimate of `offset`
(it converges to the true offset plus the link's minimum latency). A boot time that jumps
backwards is a reboot: the window restarts and `boots` counts it.
"""

from __future__ import annotations

from collections import deque

_REBOOT_BACKSTEP_MS = 1000


class BootClock:
    """Maps `time_boot_ms` to Unix ns."""

    def __init__(self, *, window: int = 200):
        self._window: deque[int] = deque(maxlen=window)
        self._last_boot_ms: int | None = None
        self.boots = 0

    def observe(self, time_boot_ms: int, arrival_unix_ns: int) -> bool:
        """Feed one message's boot stamp and its arrival time; True if the vehicle rebooted."""
        rebooted = False
        if self._last_boot_ms is None:
            self.boots = 1
        elif time_boot_ms + _REBOOT_BACKSTEP_MS < self._last_boot_ms:
            self._window.clear()
            self.boots += 1
            rebooted = True
        self._last_boot_ms = time_boot_ms
        self._window.append(arrival_unix_ns - time_boot_ms * 1_000_000)
        return rebooted

    def last_boot_ms(self) -> int:
        """The newest `time_boot_ms` seen (0 before any): a stamp for what we send back."""
        return self._last_boot_ms or 0

    @property
    def ready(self) -> bool:
        return bool(self._window)

    def to_unix_ns(self, time_boot_ms: int) -> int:
        if not self._window:
            raise RuntimeError("no boot-time sample yet")
        return time_boot_ms * 1_000_000 + min(self._window)
