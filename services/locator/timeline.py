"""Bounded, stamped sample buffers that interpolate at a ping's stamp and never go stale."""

from __future__ import annotations

import bisect
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, Literal, TypeVar

T = TypeVar("T")

LookupFailure = Literal["no_samples", "too_old", "too_new"]


@dataclass(frozen=True)
class Lookup(Generic[T]):
    """An interpolated value with the stamps it came from, or why there is none."""

    value: T | None
    stamp_ns: int | None
    failure: LookupFailure | None = None
    # How far past the newest sample the value was extrapolated, in units of the gap between
    # the two samples it came from (0: a sample or an interpolation). From two samples with
    # independent noise sigma, the extrapolated value's noise is sigma * noise_gain.
    extrapolation: float = 0.0

    @property
    def noise_gain(self) -> float:
        f = self.extrapolation
        return math.hypot(1.0 + f, f)


class Timeline(Generic[T]):
    """Samples ordered by stamp (late and out-of-order arrivals are inserted in place).

    `at(t)` interpolates between the samples around t; past the newest sample it
    extrapolates from the last two only up to `max_extrapolation_ns`, else it refuses.
    With `use="before"` only samples stamped at or before t count (one at t itself, or an
    extrapolation from the last two before it): the value then does not depend on anything
    that arrives after the ping, and a replay gives the very same value as live. (A sample
    stamped exactly at the ping can still race it when both are put at the same instant, as
    the simulator's truth detections are: Zenoh runs different subscribers' callbacks on
    different threads. Real detections come a detection time after their ping.)
    """

    def __init__(
        self,
        interpolate: Callable[[T, T, float], T],
        *,
        capacity: int,
        max_extrapolation_ns: int,
    ):
        self._interpolate = interpolate
        self._capacity = capacity
        self._max_extrapolation_ns = max_extrapolation_ns
        self._stamps: list[int] = []
        self._values: list[T] = []
        self._lock = threading.Lock()

    def add(self, stamp_ns: int, value: T) -> None:
        with self._lock:
            i = bisect.bisect_right(self._stamps, stamp_ns)
            if i > 0 and self._stamps[i - 1] == stamp_ns:
                self._values[i - 1] = value  # a duplicate stamp replaces, never doubles
                return
            self._stamps.insert(i, stamp_ns)
            self._values.insert(i, value)
            if len(self._stamps) > self._capacity:
                del self._stamps[0], self._values[0]

    def latest(self) -> Lookup[T]:
        """The newest sample as it is, whatever its age (the paper's input matching)."""
        with self._lock:
            if not self._stamps:
                return Lookup(None, None, "no_samples")
            return Lookup(self._values[-1], self._stamps[-1])

    def at(self, stamp_ns: int, *, use: Literal["around", "before"] = "around") -> Lookup[T]:
        with self._lock:
            n = len(self._stamps)
            if n == 0:
                return Lookup(None, None, "no_samples")
            i = bisect.bisect_left(self._stamps, stamp_ns)
            if i < n and self._stamps[i] == stamp_ns:
                return Lookup(self._values[i], stamp_ns)
            if use == "before":
                n = i  # samples stamped after t are not looked at
            if i == 0:
                return Lookup(None, self._stamps[0], "too_old")
            if i < n:
                t0, t1 = self._stamps[i - 1], self._stamps[i]
                frac = (stamp_ns - t0) / (t1 - t0)
                return Lookup(self._interpolate(self._values[i - 1], self._values[i], frac), t0)
            newest = self._stamps[n - 1]
            if stamp_ns - newest > self._max_extrapolation_ns or n < 2:
                return Lookup(None, newest, "too_new")
            t0 = self._stamps[n - 2]
            frac = (stamp_ns - t0) / (newest - t0)
            return Lookup(
                self._interpolate(self._values[n - 2], self._values[n - 1], frac),
                newest,
                extrapolation=frac - 1.0,
            )
