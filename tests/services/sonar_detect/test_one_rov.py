"""One ROV in the tank: candidates' confidences as the probability each is the ROV."""

from __future__ import annotations

import itertools
import math

import msgspec
import pytest
from hypothesis import given
from hypothesis import strategies as st

from capsd.payloads import Detection
from capsd.services.sonar_detect.one_rov import exclusive, scored

ECHO = Detection(
    range_m=1.0, azimuth_rad=0.0, range_sigma_m=0.02, azimuth_sigma_rad=0.003, confidence=0.5
)


def _at(range_m: float, confidence: float) -> Detection:
    return msgspec.structs.replace(ECHO, range_m=range_m, confidence=confidence)


def test_a_lone_candidate_keeps_its_score() -> None:
    alone = [_at(5.0, 0.7)]
    assert exclusive(alone) == alone
    assert exclusive([]) == []


def test_clutter_beside_a_surer_rov_is_no_longer_sure_and_twins_are_neither() -> None:
    rov, clutter = exclusive([_at(5.0, 0.95), _at(6.2, 0.6)])
    assert rov.confidence == pytest.approx(0.38 / 0.43)  # 0.95 x 0.4 over 0.02 + 0.38 + 0.03
    assert clutter.confidence == pytest.approx(0.03 / 0.43)
    assert (rov.range_m, clutter.range_m) == (5.0, 6.2)  # only the confidence changes
    a, b = exclusive([_at(5.0, 0.9), _at(6.2, 0.9)])
    assert a.confidence == pytest.approx(0.09 / 0.19) == b.confidence
    assert a.confidence < 0.5


def test_independent_leaves_every_score() -> None:
    found = [_at(5.0, 0.9), _at(6.2, 0.9)]
    assert scored(found, "independent") == found
    assert scored(found, "exclusive") == exclusive(found)


scores = st.floats(min_value=0.0, max_value=1.0, allow_nan=False)


@given(st.lists(scores, min_size=1, max_size=40))
def test_exclusive_confidences_are_a_distribution_that_keeps_the_order(ps: list[float]) -> None:
    out = [d.confidence for d in exclusive([_at(1.0 + k, p) for k, p in enumerate(ps)])]
    assert all(math.isfinite(c) and 0.0 <= c <= 1.0 for c in out)
    # With "none of them" the probabilities sum to one; no score ever grows.
    assert sum(out) <= 1.0 + 1e-9
    for p, c in zip(ps, out, strict=True):
        assert c <= max(p, 1e-9) + 1e-9
    # The odds between two candidates are their own odds' ratio: the ranking is kept.
    order = sorted(range(len(ps)), key=lambda k: ps[k])
    assert all(out[i] <= out[j] + 1e-12 for i, j in itertools.pairwise(order))
