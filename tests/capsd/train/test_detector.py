"""The detector training: its operating point's validation pings, its augmentation."""

from __future__ import annotations

from collections import Counter

import torch

from capsd.bench.detect import BENCH_STARTS_S
from capsd.services.sonar_detect.polar_input import NORM_HIGH, NORM_LOW
from capsd.services.sonar_detect.polar_net import PolarNet
from capsd.simulator.config import OFFLINE_START_NS
from capsd.train.detector import (
    VALIDATION_RUNS,
    VARIETIES,
    _augment,
    calibrate,
    validation_pings,
)


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


def test_look_augmentation_stays_in_the_normalised_span_and_leaves_the_range_plane() -> None:
    x = torch.rand(16, 3, 24, 24, generator=torch.Generator().manual_seed(1)) * 2.0 - 0.5
    plain = _augment(x.clone(), torch.Generator().manual_seed(0), image_planes=2, mode="gain")
    look = _augment(x.clone(), torch.Generator().manual_seed(0), image_planes=2, mode="look")
    again = _augment(x.clone(), torch.Generator().manual_seed(0), image_planes=2, mode="look")
    assert torch.equal(look, again)  # deterministic for a seed
    for out in (plain, look):
        assert float(out.min()) >= NORM_LOW
        assert float(out.max()) <= NORM_HIGH
        assert torch.equal(out[:, 2], x[:, 2])  # the range plane is geometry
    # Gain mode: one scale and offset per sample, so each sample's image is an affine map of
    # the original where nothing clipped; the look mode is not.
    inside = (x[:, :2] > -0.3) & (x[:, :2] < 1.0)
    for k in range(4):
        a, b = x[k, :2][inside[k]], plain[k, :2][inside[k]]
        fit = torch.linalg.lstsq(torch.stack([a, torch.ones_like(a)], 1), b[:, None]).solution
        residual = b - (fit[0] * a + fit[1])
        assert float(residual.abs().max()) < 1e-4
        c = look[k, :2][inside[k]]
        fit = torch.linalg.lstsq(torch.stack([a, torch.ones_like(a)], 1), c[:, None]).solution
        assert float((c - (fit[0] * a + fit[1])).abs().max()) > 0.01
