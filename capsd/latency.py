"""Latency histograms: cheap to record on a hot path, reported in Health, subtracted by benches.

Bins are logarithmic (5 % wide from 1 us to ~1000 s), so a percentile read from them is within
2.5 % of the exact value and a recorder's size is bounded whatever it sees. Health carries the
cumulative counts; a benchmark takes two snapshots and subtracts them to get the figures of
exactly its measurement window (`difference`), with no reset and no extra traffic.
"""

from __future__ import annotations

import math
import threading

from capsd.payloads import LatencyStats

_RATIO = 1.05
_LOG_RATIO = math.log(_RATIO)
_MAX_INDEX = 430  # 1.05 ** 430 us ~ 1.3e9 us: slower than this is counted in the last bin


def bin_index(latency_ns: int) -> int:
    """The bin of one latency (>= 0): bin k holds [1.05**k, 1.05**(k+1)) microseconds."""
    us = latency_ns / 1000.0
    if us < 1.0:
        return 0
    return min(int(math.log(us) / _LOG_RATIO), _MAX_INDEX)


def bin_middle_ms(index: int) -> float:
    """The geometric middle of bin `index`, in milliseconds."""
    return float(_RATIO ** (index + 0.5)) / 1000.0


def bin_upper_ms(index: int) -> float:
    return float(_RATIO ** (index + 1)) / 1000.0


class LatencyRecorder:
    """Counts latencies of one named stage; thread-safe."""

    def __init__(self, name: str):
        self.name = name
        self._lock = threading.Lock()
        self._bins: dict[int, int] = {}
        self._count = 0
        self._negative = 0
        self._max_ns = 0

    def record_ns(self, latency_ns: int) -> None:
        """Count one latency; a negative one (clocks of two hosts disagree) is counted apart."""
        with self._lock:
            self._count += 1
            if latency_ns < 0:
                self._negative += 1
                return
            k = bin_index(latency_ns)
            self._bins[k] = self._bins.get(k, 0) + 1
            self._max_ns = max(self._max_ns, latency_ns)

    def snapshot(self) -> LatencyStats:
        with self._lock:
            return LatencyStats(
                name=self.name,
                count=self._count,
                negative=self._negative,
                max_ms=self._max_ns / 1e6,
                bins=dict(self._bins),
            )


def difference(later: LatencyStats, earlier: LatencyStats | None) -> LatencyStats:
    """What was recorded between two snapshots of one recorder (max: the later one's)."""
    if earlier is None:
        return later
    bins = {k: n - earlier.bins.get(k, 0) for k, n in later.bins.items()}
    return LatencyStats(
        name=later.name,
        count=later.count - earlier.count,
        negative=later.negative - earlier.negative,
        max_ms=later.max_ms,
        bins={k: n for k, n in bins.items() if n > 0},
    )


def percentile_ms(stats: LatencyStats, q: float) -> float | None:
    """The q-th percentile (0..100) of the non-negative latencies, or None when there are none."""
    total = sum(stats.bins.values())
    if total == 0:
        return None
    rank = q / 100.0 * total
    seen = 0
    for k in sorted(stats.bins):
        seen += stats.bins[k]
        if seen >= rank:
            return bin_middle_ms(k)
    return bin_middle_ms(max(stats.bins))


def count_above_ms(stats: LatencyStats, limit_ms: float) -> int:
    """How many latencies may exceed `limit_ms`: every bin reaching above it (conservative)."""
    return sum(n for k, n in stats.bins.items() if bin_upper_ms(k) > limit_ms)
