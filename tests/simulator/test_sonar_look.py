"""The look knobs: the outside region, all of its knobs beyond the range trained on or some."""

from __future__ import annotations

import dataclasses

import pytest

from capsd.simulator import sonar_look
from capsd.simulator.config import SonarImageConfig

REACH_M = 25.0


def _draw(seed: int, knobs: frozenset[sonar_look.OutsideKnob] | None) -> sonar_look.Look:
    rng = sonar_look.look_rng(seed)
    return sonar_look.draw(rng, "outside", tank_reach_m=REACH_M, outside_knobs=knobs)


@pytest.mark.parametrize("seed", [0, 1, 7])
def test_one_knob_outside_changes_that_knob_alone(seed: int) -> None:
    none = _draw(seed, frozenset())
    water = _draw(seed, frozenset({"water_db"}))
    lo, hi = sonar_look.KNOBS["water_db"].outside or (0.0, 0.0)
    assert lo <= water.water_db <= hi
    knob = sonar_look.KNOBS["water_db"]
    assert knob.low <= none.water_db <= knob.high
    # Every other knob is the same draw.
    assert dataclasses.replace(water, water_db=none.water_db) == none


@pytest.mark.parametrize("seed", [0, 3])
def test_by_default_all_five_are_outside_and_none_means_the_trained_ranges(seed: int) -> None:
    every = _draw(seed, None)
    assert every == _draw(seed, frozenset(("water_db", "dynamic_range_db", "gamma",
                                           "rov_reflectivity", "speckle_shape")))  # fmt: skip
    none = _draw(seed, frozenset())
    for name in ("water_db", "dynamic_range_db", "gamma", "rov_reflectivity", "speckle_shape"):
        knob = sonar_look.KNOBS[name]
        lo, hi = knob.outside or (0.0, 0.0)
        assert lo <= getattr(every, name) <= hi
        assert knob.low <= getattr(none, name) <= knob.high


def test_outside_knobs_need_the_outside_look() -> None:
    with pytest.raises(ValueError, match="outside_knobs"):
        SonarImageConfig(variety="heldout", outside_knobs=("gamma",))
    assert SonarImageConfig(variety="outside", outside_knobs=()).outside_knobs == ()
