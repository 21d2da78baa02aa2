"""Latency histograms: bins, percentiles within the bin width, window differences."""

from __future__ import annotations

import statistics

from hypothesis import given
from hypothesis import strategies as st

from capsd.codec import Codec
from capsd.latency import (
    LatencyRecorder,
    bin_index,
    bin_middle_ms,
    count_above_ms,
    difference,
    percentile_ms,
)
from capsd.payloads import Health

latencies_ns = st.lists(st.integers(min_value=1_000, max_value=10**10), min_size=1, max_size=300)


@given(st.integers(min_value=1_000, max_value=10**11))
def test_a_latency_lies_in_its_bin(latency_ns: int) -> None:
    k = bin_index(latency_ns)
    assert 1.05**k * 1000 <= latency_ns * (1 + 1e-9)
    assert latency_ns < 1.05 ** (k + 1) * 1000 * (1 + 1e-9)
    assert abs(bin_middle_ms(k) - latency_ns / 1e6) <= 0.025 * latency_ns / 1e6


@given(latencies_ns)
def test_median_is_within_the_bin_width(values: list[int]) -> None:
    recorder = LatencyRecorder("stage")
    for v in values:
        recorder.record_ns(v)
    stats = recorder.snapshot()
    assert stats.count == len(values)
    assert stats.max_ms == max(values) / 1e6
    median = percentile_ms(stats, 50)
    assert median is not None
    # The histogram's median is a middle of a bin that holds an order statistic near 50 %.
    ordered = sorted(values)
    lower = ordered[max(0, (len(values) - 1) // 2 - 1)] / 1e6
    upper = ordered[min(len(values) - 1, len(values) // 2 + 1)] / 1e6
    assert lower / 1.05 <= median <= upper * 1.05
    assert abs(median - statistics.median(values) / 1e6) <= max(upper - lower, 0) + 0.05 * upper


@given(latencies_ns, latencies_ns)
def test_difference_holds_only_the_window(before: list[int], window: list[int]) -> None:
    recorder = LatencyRecorder("stage")
    for v in before:
        recorder.record_ns(v)
    first = recorder.snapshot()
    for v in window:
        recorder.record_ns(v)
    only = difference(recorder.snapshot(), first)
    alone = LatencyRecorder("stage")
    for v in window:
        alone.record_ns(v)
    assert only.bins == alone.snapshot().bins
    assert only.count == len(window)


def test_negative_latencies_are_counted_apart_and_limits_are_conservative() -> None:
    recorder = LatencyRecorder("transport")
    for v in (-5_000_000, 10_000_000, 30_000_000):
        recorder.record_ns(v)
    stats = recorder.snapshot()
    assert stats.negative == 1
    assert sum(stats.bins.values()) == 2
    assert count_above_ms(stats, 25.0) == 1
    assert count_above_ms(stats, 9.9) == 2  # 10 ms shares a bin reaching above 9.9 ms
    assert percentile_ms(LatencyRecorder("empty").snapshot(), 50) is None


def test_health_carries_latencies_through_the_codec() -> None:
    recorder = LatencyRecorder("fix")
    recorder.record_ns(2_000_000)
    health = Health(
        stamp_ns=1,
        seq=0,
        service="locator",
        state="ok",
        pid=1,
        host="h",
        software_version="0",
        uptime_s=1.0,
        latencies=(recorder.snapshot(),),
    )
    codec = Codec(Health)
    back = codec.decode(codec.encode(health), encoding=codec.encoding, key_expr="k")
    assert back.latencies == health.latencies
