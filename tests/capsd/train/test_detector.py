"""The detector training's operating point: where in the validation runs it is set."""

from __future__ import annotations

from collections import Counter

from capsd.bench.detect import BENCH_STARTS_S
from capsd.services.sonar_detect.polar_net import PolarNet
from capsd.simulator.config import OFFLINE_START_NS
from capsd.train.detector import VALIDATION_RUNS, VARIETIES, calibrate, validation_pings


def test_validation_pings_come_from_the_start_and_later_in_every_run() -> None:
    stretch_s = 0.6 / len(BENCH_STARTS_S)
    seen: Counter[float] = Counter()
    for _done, t_s, frame, label in validation_pings(0.6):
        assert frame.stamp_ns == label.stamp_ns
        # The sonar's clock may be off from sim time by less than a second.
        assert abs((frame.stamp_ns - OFFLINE_START_NS) / 1e9 - t_s) < 1.0
        start = max(s for s in BENCH_STARTS_S if s <= t_s)
        assert t_s <= start + stretch_s + 1e-6
        seen[start] += 1
    assert max(BENCH_STARTS_S) >= 120.0
    # Every stretch of every run in both looks gave pings.
    assert set(seen) == set(BENCH_STARTS_S)
    assert all(n >= len(VALIDATION_RUNS) * len(VARIETIES) for n in seen.values())


def test_the_operating_point_records_its_stretches() -> None:
    result = calibrate(PolarNet(), duration_s=0.3)
    assert result["validation_stretches"]["start_s"] == list(BENCH_STARTS_S)
    assert result["frames"] > 0
