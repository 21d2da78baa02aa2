"""Tank layouts: each run's clutter laid out anew, inside the tank, the same for the same seed."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capsd.simulator.config import Config
from capsd.simulator.scene import BLUEROV2_SEMI_AXES
from capsd.simulator.world import (
    MIN_RACK_HEIGHT_M,
    RACK_CLEARANCE_M,
    ROV_HULL_HALF_HEIGHT_M,
    TankName,
    make_tank,
)


@settings(max_examples=40, deadline=None)
@given(name=st.sampled_from(["nfp", "mockup", "pond"]), seed=st.integers(-(2**40), 2**40))
def test_a_drawn_layout_keeps_the_presets_clutter_inside_the_tank(
    name: TankName, seed: int
) -> None:
    preset, drawn = make_tank(name), make_tank(name, layout_seed=seed)
    assert [b.kind for b in drawn.boxes] == [b.kind for b in preset.boxes]
    assert [c.kind for c in drawn.cylinders] == [c.kind for c in preset.cylinders]
    for a, b in zip(preset.boxes, drawn.boxes, strict=True):
        assert 0.0 <= b.lo[0] < b.hi[0] <= drawn.length_m
        assert 0.0 <= b.lo[1] < b.hi[1] <= drawn.width_m
        # Same size and height: moved, not reshaped.
        for k in range(3):
            assert abs((b.hi[k] - b.lo[k]) - (a.hi[k] - a.lo[k])) < 1e-9
        assert (b.lo[2], b.hi[2]) == (a.lo[2], a.hi[2])
    for c in drawn.cylinders:
        assert 0.0 <= c.start[0] <= drawn.length_m
        assert 0.0 <= c.start[1] <= drawn.width_m
        assert -drawn.depth_m <= c.start[2] <= 0.0
    assert make_tank(name, layout_seed=seed) == drawn  # the same seed, the same layout


def test_runs_get_their_own_layout_unless_asked_for_the_preset() -> None:
    layouts = {Config(seed=s).world_tank().boxes for s in range(5)}
    assert len(layouts) == 5
    assert Config(seed=3).world_tank() == Config(seed=9, layout_seed=3).world_tank()
    assert Config(seed=3, clutter_layout="preset").world_tank() == make_tank("nfp")
    assert Config(seed=3, clutter="off").world_tank().boxes == ()


@settings(max_examples=40, deadline=None)
@given(name=st.sampled_from(["nfp", "mockup", "pond"]), seed=st.integers(-(2**40), 2**40))
def test_drawn_rack_heights_leave_the_rov_its_clearance_and_the_layout_its_place(
    name: TankName, seed: int
) -> None:
    layout = make_tank(name, layout_seed=seed)
    tall = make_tank(name, layout_seed=seed, rack_heights="drawn")
    assert make_tank(name, layout_seed=seed, rack_heights="drawn") == tall  # same seed, same
    lowest_hull = tall.rov_depths[1] - ROV_HULL_HALF_HEIGHT_M
    for a, b in zip(layout.boxes, tall.boxes, strict=True):
        # Where it stands and its footprint as the layout drew them: only a height changes.
        assert (b.kind, b.lo, b.hi[:2]) == (a.kind, a.lo, a.hi[:2])
        if b.kind not in ("rack", "skip") or b.hi[2] == a.hi[2]:
            continue
        clearance = lowest_hull - b.hi[2]
        assert b.hi[2] - b.lo[2] >= MIN_RACK_HEIGHT_M - 1e-9
        if b.hi[2] - b.lo[2] > MIN_RACK_HEIGHT_M + 1e-9:  # not held up by its least height
            assert RACK_CLEARANCE_M[0] <= clearance <= RACK_CLEARANCE_M[1]


def test_some_drawn_racks_stand_just_under_the_rovs_lower_flight_level() -> None:
    # The presets never leave less than 36 cm under the ROV's centre (mockup); drawn heights
    # put some racks within 20 cm of its hull over a handful of seeds.
    tops = [
        (tank.rov_depths[1] - ROV_HULL_HALF_HEIGHT_M) - b.hi[2]
        for tank in (make_tank("nfp", layout_seed=s, rack_heights="drawn") for s in range(8))
        for b in tank.boxes
        if b.kind == "rack"
    ]
    assert min(tops) < 0.2
    assert Config(seed=3, rack_heights="drawn").world_tank() == make_tank(
        "nfp", layout_seed=3, rack_heights="drawn"
    )
    assert BLUEROV2_SEMI_AXES[2] == ROV_HULL_HALF_HEIGHT_M
    # Only a per-seed layout has racks to draw: said before the first ping, not ignored.
    for wrong in ({"clutter_layout": "preset"}, {"clutter": "off"}):
        with pytest.raises(ValueError, match="rack_heights: drawn"):
            Config(seed=3, rack_heights="drawn", **wrong)  # type: ignore[arg-type]
