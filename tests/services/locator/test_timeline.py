"""Timelines interpolate at a ping's stamp and refuse stale or missing inputs."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from capsd.services.locator.timeline import Timeline


def _lerp(a: float, b: float, f: float) -> float:
    return a + f * (b - a)


def test_interpolates_between_samples_and_accepts_out_of_order() -> None:
    line: Timeline[float] = Timeline(_lerp, capacity=10, max_extrapolation_ns=50)
    line.add(200, 2.0)
    line.add(100, 1.0)  # late arrival
    found = line.at(150)
    assert found.value == 1.5
    assert found.failure is None
    assert line.at(100).value == 1.0


def test_refuses_too_old_too_new_and_empty() -> None:
    line: Timeline[float] = Timeline(_lerp, capacity=10, max_extrapolation_ns=50)
    assert line.at(5).failure == "no_samples"
    line.add(100, 1.0)
    line.add(200, 2.0)
    assert line.at(99).failure == "too_old"
    assert line.at(251).failure == "too_new"
    extrapolated = line.at(240)
    assert extrapolated.value == 2.4


def test_bounded_and_duplicates_replace() -> None:
    line: Timeline[float] = Timeline(_lerp, capacity=3, max_extrapolation_ns=0)
    for i in range(10):
        line.add(i * 10, float(i))
    line.add(90, 99.0)
    assert line.at(60).failure == "too_old"
    assert line.at(90).value == 99.0


@given(
    st.lists(st.integers(min_value=0, max_value=1000), min_size=2, max_size=30, unique=True),
    st.integers(min_value=0, max_value=1100),
)
def test_before_ignores_whatever_arrived_after_the_stamp(stamps: list[int], at_ns: int) -> None:
    """use="before" gives the same answer whether or not the later samples are in yet."""
    early: Timeline[float] = Timeline(_lerp, capacity=100, max_extrapolation_ns=200)
    full: Timeline[float] = Timeline(_lerp, capacity=100, max_extrapolation_ns=200)
    for s in stamps:
        full.add(s, float(s) * 0.01 + (s % 7))
        if s <= at_ns:
            early.add(s, float(s) * 0.01 + (s % 7))
    a, b = early.at(at_ns, use="before"), full.at(at_ns, use="before")
    if early.at(at_ns).failure == "no_samples":
        assert b.failure in ("too_old", "no_samples")
    else:
        assert (a.value, a.stamp_ns, a.failure) == (b.value, b.stamp_ns, b.failure)


def test_before_extrapolates_from_the_last_two_before_the_stamp() -> None:
    line: Timeline[float] = Timeline(_lerp, capacity=10, max_extrapolation_ns=100)
    for stamp, value in ((100, 1.0), (200, 2.0), (300, 5.0)):
        line.add(stamp, value)
    assert line.at(250).value == 3.5  # interpolated with the sample after the ping
    before = line.at(250, use="before")
    assert before.value == 2.5
    assert before.stamp_ns == 200
    assert line.at(300, use="before").value == 5.0  # a sample at the ping itself is used


def test_an_extrapolation_says_how_far_and_its_noise_gain_holds() -> None:
    """Two readings with independent noise, extrapolated 1.5 gaps on: noise x hypot(2.5, 1.5)."""
    rng = np.random.default_rng(3)
    values = []
    for _ in range(4000):
        line: Timeline[float] = Timeline(_lerp, capacity=4, max_extrapolation_ns=200)
        line.add(100, float(rng.normal(0.0, 0.01)))
        line.add(200, float(rng.normal(0.0, 0.01)))
        found = line.at(350, use="before")
        assert found.value is not None
        values.append(found.value)
    assert found.extrapolation == 1.5
    assert abs(float(np.std(values)) / (0.01 * found.noise_gain) - 1.0) < 0.05
    assert line.at(150).extrapolation == 0.0
    assert line.at(200).noise_gain == 1.0
