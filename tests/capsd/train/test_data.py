"""The training plan: far runs on request, the plan otherwise as it was for a seed."""

from __future__ import annotations

import dataclasses
import math

from capsd.bench.detect import band_of
from capsd.simulator.config import OFFLINE_START_NS
from capsd.simulator.sim import Simulation
from capsd.train.data import FAR_PITCH_DEG, FAR_STANDOFF_M, plan_runs


def test_far_runs_replace_a_share_and_leave_the_rest_as_planned() -> None:
    plain = plan_runs(runs=40, seed=3, duration_s=10.0, sonar_hz=2.0)
    assert plain == plan_runs(runs=40, seed=3, duration_s=10.0, sonar_hz=2.0, far_share=0.0)
    assert all(p.sonar_pitch_deg is None for p in plain)
    mixed = plan_runs(runs=40, seed=3, duration_s=10.0, sonar_hz=2.0, far_share=0.5)
    far = [k for k, p in enumerate(mixed) if p.sonar_pitch_deg is not None]
    assert 10 <= len(far) <= 30
    for k, (p, q) in enumerate(zip(plain, mixed, strict=True)):
        if k not in far:
            assert p == q
            continue
        assert (q.tank, q.asv_mode) == ("nfp", "follow")
        assert q.standoff_m is not None
        assert q.sonar_pitch_deg is not None
        assert FAR_STANDOFF_M[0] <= q.standoff_m <= FAR_STANDOFF_M[1]
        assert FAR_PITCH_DEG[0] <= q.sonar_pitch_deg <= FAR_PITCH_DEG[1]
        # The rest of the run (its seed, look, gains) as planned.
        assert (
            dataclasses.replace(
                q, tank=p.tank, asv_mode=p.asv_mode, standoff_m=p.standoff_m, sonar_pitch_deg=None
            )
            == p
        )


def test_a_far_run_puts_the_rov_far_inside_the_aperture() -> None:
    plan = dataclasses.replace(
        plan_runs(runs=1, seed=5, duration_s=4.0, sonar_hz=5.0, far_share=1.0)[0],
        trajectory="lawnmower",
        standoff_m=16.0,
        sonar_pitch_deg=12.0,
    )
    assert plan.config().sonar.pitch_deg == 12.0
    sim = Simulation(plan.config(), horizon_s=8.0)
    far = [
        label
        for _, _, label in sim.labelled_pings(start_ns=OFFLINE_START_NS, duration_s=4.0)
        if label.visible and abs(label.elevation_rad) <= math.radians(10.0)
    ]
    assert far
    assert all(band_of(label.range_m) == "14-20 m" for label in far)
