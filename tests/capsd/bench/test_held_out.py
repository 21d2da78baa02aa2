"""The held-out tank stays held out: nothing trains or tunes on it; the accuracy bench uses it."""

from __future__ import annotations

from capsd.bench.accuracy import RUNS
from capsd.bench.baseline import TRAINING_RUNS
from capsd.bench.detect import RUNS as DETECT_RUNS
from capsd.simulator.world import HELD_OUT_TANK, TUNING_TANKS, make_tank
from capsd.train.data import plan_runs
from capsd.train.detector import VALIDATION_RUNS


def test_nothing_is_trained_or_tuned_on_the_held_out_tank() -> None:
    assert HELD_OUT_TANK not in TUNING_TANKS
    training = plan_runs(runs=64, seed=0, duration_s=60.0, sonar_hz=2.0)
    assert {plan.tank for plan in training} == set(TUNING_TANKS)
    for tank, *_ in (*VALIDATION_RUNS, *TRAINING_RUNS, *DETECT_RUNS):
        assert tank in TUNING_TANKS


def test_the_accuracy_bench_includes_the_held_out_tank() -> None:
    assert any(tank == HELD_OUT_TANK for tank, _ in RUNS)
    pond, nfp = make_tank(HELD_OUT_TANK), make_tank("nfp")
    assert (pond.length_m, pond.width_m, pond.depth_m) != (nfp.length_m, nfp.width_m, nfp.depth_m)
