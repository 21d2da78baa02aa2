"""The faults bench's verdict on what reached the autopilot: stale, invalid, wrong, ok."""

from __future__ import annotations

import math

import numpy as np

from capsd.bench.faults import judge
from capsd.services.mav_bridge.service import NedConfig

NED = NedConfig().tank_to_ned()
TRUTH = (5.0, 4.0, -2.0)


def _estimate(*, arrival_s: float, usec: int, offset_m: float, sigma_m: float) -> dict[str, object]:
    x, y, z = (float(v) for v in NED.position(np.array(TRUTH)))
    cov = [0.0] * 21
    cov[0] = cov[6] = cov[11] = sigma_m**2
    return {"arrival_s": arrival_s, "usec": usec, "x": x + offset_m, "y": y, "z": z,
            "covariance": cov}  # fmt: skip


def test_verdicts() -> None:
    usec = 1_000_000_000_000_000
    t = usec / 1e6
    labels = {usec: TRUTH}
    cases = [
        _estimate(arrival_s=t + 0.05, usec=usec, offset_m=0.02, sigma_m=0.01),  # ok (2 sigma)
        _estimate(arrival_s=t + 0.05, usec=usec, offset_m=0.04, sigma_m=0.01),  # 4 sigma
        _estimate(arrival_s=t + 0.31, usec=usec, offset_m=0.0, sigma_m=0.01),  # stale
        _estimate(arrival_s=t + 0.05, usec=usec + 1, offset_m=0.0, sigma_m=0.01),  # no truth
        {**_estimate(arrival_s=t, usec=usec, offset_m=0.0, sigma_m=0.01), "x": math.nan},
    ]
    judged = judge(cases, labels, NED)
    assert [v.verdict for v in judged] == ["ok", "wrong_3sigma", "stale", "no_truth", "invalid"]
    assert [v.sigmas for v in judged[2:]] == [None, None, None]
    assert judged[0].sigmas is not None
    assert abs(judged[0].sigmas - 2.0) < 1e-9
    assert judged[1].sigmas is not None
    assert abs(judged[1].sigmas - 4.0) < 1e-9
