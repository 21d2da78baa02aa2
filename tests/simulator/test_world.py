"""Tank layouts: each run's clutter laid out anew, inside the tank, the same for the same seed."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from capsd.simulator.config import Config
from capsd.simulator.world import TankName, make_tank


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
