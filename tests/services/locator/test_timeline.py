"""Timelines interpolate at a ping's stamp and refuse stale or missing inputs."""

from __future__ import annotations

from services.locator.timeline import Timeline


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
