"""The sonar's own ping clock mapped onto ours, so a ping is stamped when it was taken.

Arrival time is a fair stamp only while the link keeps up. After a stall (the driver starved
of CPU, the network backed up) pings arrive late, several at once, and an arrival stamp would
make a ping seconds old look fresh. Each SimplePingResult carries `pingStartTime`, a counter of
the sonar's own whose unit the protocol does not document (on the fixtures' M1200d it steps
62.5 million per 62.5 ms ping: nanoseconds in a u32 that wraps every 4.3 s; v2 sends a double).
So the clock learns what it needs from the stream itself:

- the tick rate, from pings that arrived alone (no backlog) over at least `learn_s`, refitted
  each second over the last `fit_s`: the median of slopes between pings half that span apart,
  checked against every consecutive pair (an unusable counter, a replay or a counter that
  jumps, is noticed and not used);
- the offset, as the smallest `arrival - ticks * rate` in the last `window_s`: the mapping of
  the quickest pings, which slides with clock drift.

A ping is then stamped `min(arrival, predicted)`; one that arrives much later than predicted is
counted late and keeps its predicted stamp. Until the rate is known, or after anything the
clock cannot explain (a jump, a gap longer than the counter's wrap), pings are stamped on
arrival and the caller drops backlogs as before.
"""

from __future__ import annotations

import itertools
from collections import deque
from dataclasses import dataclass

LATE_S = 0.25  # a ping arriving this much after its predicted time is counted late
_MIN_SLOPE_SPAN_S = 1.0
_AGREE_S = 0.02  # a learning pair must agree with the fitted rate within 20 ms + 20 %


@dataclass(frozen=True)
class Stamp:
    """When a ping was taken (our clock), and how that was decided."""

    taken_ns: int
    from_sonar_clock: bool
    late_s: float  # arrival minus the predicted time; 0 when not from the sonar clock


class SonarClock:
    """Maps one stream's ping counter onto our clock; `reset()` on every new connection."""

    def __init__(
        self,
        *,
        modulus: float | None,
        learn_s: float = 3.0,
        window_s: float = 10.0,
        fit_s: float = 60.0,
    ):
        self.modulus = modulus  # the counter wraps at this (a u32: 2**32); None: it never does
        self.learn_s = learn_s
        self.window_s = window_s
        self.fit_s = fit_s
        self.resets = 0
        self.reset()

    def reset(self) -> None:
        self._last: tuple[float, int] | None = None  # (unwrapped ticks, arrival_ns)
        self._base = 0.0  # added to raw ticks to unwrap them
        self._alone: deque[tuple[float, int]] = deque()  # pings that came alone, last fit_s
        self._recent: deque[tuple[float, int]] = deque()  # every ping, last window_s
        self._rate_ns: float | None = None  # our nanoseconds per tick
        self._fitted_at = 0  # arrival_ns of the last fit

    @property
    def learnt(self) -> bool:
        return self._rate_ns is not None

    def stamp(self, ticks: float, arrival_ns: int, *, alone: bool) -> Stamp:
        """Stamp one ping; `alone`: it came in a read of its own (no backlog)."""
        unwrapped = self._unwrap(ticks, arrival_ns)
        if unwrapped is None:
            self.resets += 1
            self.reset()
            unwrapped = self._unwrap(ticks, arrival_ns)
            assert unwrapped is not None  # a fresh clock takes any first value
        self._last = (unwrapped, arrival_ns)
        _append(self._recent, (unwrapped, arrival_ns), self.window_s)
        if alone:
            _append(self._alone, (unwrapped, arrival_ns), self.fit_s)
            if arrival_ns - self._fitted_at >= 1e9:
                self._fit(arrival_ns)
        rate = self._rate_ns
        if rate is None:
            return Stamp(arrival_ns, from_sonar_clock=False, late_s=0.0)
        offset = min(arrival - t * rate for t, arrival in self._recent)
        predicted = unwrapped * rate + offset
        late_s = max(0.0, (arrival_ns - predicted) / 1e9)
        return Stamp(int(min(arrival_ns, predicted)), from_sonar_clock=True, late_s=late_s)

    def _unwrap(self, ticks: float, arrival_ns: int) -> float | None:
        """The counter made monotonic; None when the step cannot be explained."""
        if self._last is None:
            self._base = 0.0
            return ticks
        last_ticks, last_arrival = self._last
        value = ticks + self._base
        if value < last_ticks:
            if self.modulus is None:
                return None  # a counter that never wraps went backwards
            self._base += self.modulus
            value += self.modulus
        if self._rate_ns is not None:
            step_s = (value - last_ticks) * self._rate_ns / 1e9
            gap_s = (arrival_ns - last_arrival) / 1e9
            wrap_s = None if self.modulus is None else self.modulus * self._rate_ns / 1e9
            # The sonar says more time passed than we saw (by more than jitter), or so much
            # passed that the counter may have wrapped unseen: the mapping is void.
            if step_s > gap_s + 1.0 or (wrap_s is not None and gap_s > 0.5 * wrap_s):
                return None
        return value

    def _fit(self, now_ns: int) -> None:
        """The tick rate: the median slope between pings half the span apart (at least 1 s)."""
        samples = self._alone
        span_ns = samples[-1][1] - samples[0][1]
        if span_ns < self.learn_s * 1e9:
            return
        self._fitted_at = now_ns
        apart_ns = max(_MIN_SLOPE_SPAN_S * 1e9, 0.5 * span_ns)
        slopes = []
        j = 0
        for ticks, arrival in samples:
            while j + 1 < len(samples) and arrival - samples[j + 1][1] >= apart_ns:
                j += 1
            back_ticks, back_arrival = samples[j]
            if arrival - back_arrival >= apart_ns and ticks > back_ticks:
                slopes.append((arrival - back_arrival) / (ticks - back_ticks))
        if not slopes:
            return
        slopes.sort()
        rate = slopes[len(slopes) // 2]
        agree = sum(
            abs((a2 - a1) - (t2 - t1) * rate) <= _AGREE_S * 1e9 + 0.2 * abs(a2 - a1)
            for (t1, a1), (t2, a2) in itertools.pairwise(samples)
        )
        if rate <= 0.0 or agree < 0.8 * (len(samples) - 1):
            # Not a clock we can use (a replay, a counter that jumps): learn again from here.
            self._rate_ns = None
            self._alone.clear()
            return
        self._rate_ns = rate


def _append(samples: deque[tuple[float, int]], sample: tuple[float, int], keep_s: float) -> None:
    samples.append(sample)
    while samples[-1][1] - samples[0][1] > keep_s * 1e9:
        samples.popleft()
