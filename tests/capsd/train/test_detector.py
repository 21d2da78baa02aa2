"""The detector training: its operating point's validation pings, its augmentation."""

from __future__ import annotations

import math
from collections import Counter

import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st
from msgspec.structs import replace

from capsd.bench.detect import BENCH_STARTS_S
from capsd.payloads import Detection
from capsd.services.sonar_detect.one_rov import exclusive
from capsd.services.sonar_detect.polar_input import NORM_HIGH, NORM_LOW
from capsd.services.sonar_detect.polar_net import PolarNet
from capsd.simulator.config import OFFLINE_START_NS
from capsd.train.detector import (
    VALIDATION_RUNS,
    VARIETIES,
    _augment,
    calibrate,
    exclusive_logits,
    operating_offset,
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


def _as_the_one_rov(logits: list[float], offset: float, fixed: list[float]) -> list[float]:
    """The service's exclusive confidences of `logits` at `offset` beside `fixed` (one_rov)."""
    echo = Detection(
        range_m=1.0, azimuth_rad=0.0, range_sigma_m=0.02, azimuth_sigma_rad=0.003, confidence=0.5
    )
    found = [replace(echo, confidence=1 / (1 + math.exp(offset - v))) for v in logits]
    found += [replace(echo, confidence=1 / (1 + math.exp(-v))) for v in fixed]
    return [d.confidence for d in exclusive(found)[: len(logits)]]


def test_a_lone_candidate_keeps_its_logit_and_a_tie_never_passes() -> None:
    assert exclusive_logits([1.5], []) == [1.5]
    assert exclusive_logits([2.0, 2.0], []) == [-math.inf, -math.inf]
    # A ROV at logit 3 beside clutter at 1: it passes 0.5 up to offset log(e^3 - e^1).
    rov, clutter = exclusive_logits([3.0, 1.0], [])
    assert rov == pytest.approx(math.log(math.exp(3.0) - math.exp(1.0)))
    assert clutter == -math.inf
    # A candidate at its own operating point (the near refiner's) takes its share.
    assert exclusive_logits([1.5], [0.0]) == pytest.approx([1.5 - math.log(2.0)])


@given(
    st.lists(st.floats(-6.0, 6.0), min_size=1, max_size=6),
    st.lists(st.floats(-6.0, 6.0), max_size=3),
    st.floats(-3.0, 3.0),
)
def test_exclusive_logits_pass_where_the_services_confidences_do(
    logits: list[float], fixed: list[float], offset: float
) -> None:
    bounds = exclusive_logits(logits, fixed)
    confidences = _as_the_one_rov(logits, offset, fixed)
    for bound, confidence in zip(bounds, confidences, strict=True):
        if abs(bound - offset) > 1e-6:  # not on the boundary itself
            assert (confidence >= 0.5) == (offset <= bound)


def test_the_offset_counts_false_alarms_as_the_service_scores_them() -> None:
    # Two frames: clutter at logit 2 alone, then clutter at 2 beside a ROV at 4. Scored alone
    # both clutters are false alarms until the offset passes 2; as the one ROV the second is
    # none at any offset, so a budget of one false alarm in two frames allows a lower offset.
    alone = [2.0, 2.0]
    as_one = exclusive_logits([2.0], []) + exclusive_logits([2.0, 4.0], [])[:1]
    assert operating_offset(alone, 2, 0.5) > 2.0
    assert operating_offset(as_one, 2, 0.5) == 0.0


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
