"""What real sonars and tanks vary in, as knobs with physical ranges, drawn per run.

A detector trained on one rendering learns that rendering's look (its noise floor, its ROV
echo). Real Oculus images differ from sonar to sonar, setting to setting and tank to tank; each
knob below is one physical cause of that, with the range it spans in practice. A run draws
every knob from its range (`region="train"`), or from a band of each kept out of training
(`region="heldout"`: the detector bench's held-out settings), or, for five knobs (water level,
dynamic range, gamma, ROV strength, speckle shape), from beyond the range trained on
(`region="outside"`: the fine-tune demonstration). `variety: off` keeps the simulator's fixed
look (the demo's and the accuracy bench's world).

The knobs, their physical ranges and what each stands for: docs/SONAR-VARIETY.md.

Held-out bands are narrow slices inside each range (and both values of the two-valued knobs):
the bench sees combinations and values the network never saw together.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

Region = Literal["train", "heldout", "outside"]
Variety = Literal["off", "train", "heldout", "outside"]
# The knobs `region="outside"` can put beyond the range trained on (those with an outside band).
OutsideKnob = Literal["water_db", "dynamic_range_db", "gamma", "rov_reflectivity", "speckle_shape"]


@dataclass(frozen=True)
class Knob:
    """One knob: its physical range, the band kept out of training, log-uniform or not."""

    low: float
    high: float
    heldout: tuple[float, float]
    log: bool = False
    outside: tuple[float, float] | None = None  # beyond the physical range trained on

    def draw(self, rng: np.random.Generator, region: Region, *, beyond: bool = True) -> float:
        """One value; in the outside region past the trained range only if `beyond`."""
        if region == "heldout":
            lo, hi = self.heldout
            return self._uniform(rng, lo, hi)
        if region == "outside":
            # Past the training range on the side where a real sonar could still be: the
            # fine-tune demonstration's "a look the network never saw". One uniform draw
            # either way, so that looks differing in `beyond` alone share every other value.
            outside = self.outside if beyond else None
            lo, hi = outside if outside is not None else (self.low, self.high)
            return self._uniform(rng, lo, hi)
        # Training: the range less the held-out band, drawn by rejection (the band is narrow).
        for _ in range(1000):
            value = self._uniform(rng, self.low, self.high)
            if not self.heldout[0] <= value <= self.heldout[1]:
                return value
        raise AssertionError("held-out band covers the knob's range")  # pragma: no cover

    def _uniform(self, rng: np.random.Generator, lo: float, hi: float) -> float:
        if self.log:
            return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
        return float(rng.uniform(lo, hi))


KNOBS: dict[str, Knob] = {
    "water_db": Knob(-66.0, -20.0, (-44.0, -40.0), outside=(-19.0, -17.0)),
    "gain_db": Knob(-10.0, 10.0, (3.0, 5.0)),
    "tvg_residual_db": Knob(-20.0, 5.0, (-14.0, -11.0)),
    "gain_jitter_db": Knob(0.0, 3.0, (1.4, 1.8)),
    "dynamic_range_db": Knob(25.0, 65.0, (44.0, 48.0), outside=(66.0, 70.0)),
    "gamma": Knob(0.45, 1.3, (0.66, 0.74), outside=(1.32, 1.4)),
    "speckle_shape": Knob(0.7, 30.0, (2.0, 2.6), log=True, outside=(0.6, 0.68)),
    "speckle_corr_beams": Knob(0.0, 1.5, (0.85, 1.0)),
    "speckle_corr_bins": Knob(0.0, 1.5, (0.55, 0.7)),
    "side_lobe_db": Knob(-40.0, -18.0, (-27.0, -24.0)),
    "ringdown_m": Knob(0.0, 0.8, (0.42, 0.5)),
    "ringdown_db": Knob(-15.0, 3.0, (-6.0, -4.0)),
    "rov_reflectivity": Knob(0.3, 1.6, (0.6, 0.7), log=True, outside=(0.26, 0.29)),
    "rov_glint": Knob(0.0, 1.2, (0.5, 0.6)),
    "rov_interior": Knob(0.0, 0.5, (0.25, 0.3)),
    "rov_exponent": Knob(0.5, 3.0, (1.4, 1.6)),
    "floor_reflectivity": Knob(0.05, 0.5, (0.3, 0.34)),
    "fish": Knob(0.0, 12.0, (5.0, 6.0)),
    "floating_clutter": Knob(0.0, 8.0, (3.0, 4.0)),
    "n_ranges": Knob(512.0, 1500.0, (900.0, 1000.0)),
    "range_fraction": Knob(0.35, 1.0, (0.62, 0.68)),
}
RAYLEIGH_SHARE = 0.25  # of training runs with pure Rayleigh speckle (no texture)


@dataclass(frozen=True)
class Look:
    """One run's draw of every knob (the renderer's and the tank's)."""

    water_db: float
    gain_db: float
    tvg_residual_db: float
    gain_jitter_db: float
    compression: Literal["log", "linear"]
    dynamic_range_db: float
    gamma: float
    speckle_shape: float  # math.inf: Rayleigh
    speckle_corr_beams: float
    speckle_corr_bins: float
    side_lobe_db: float
    ringdown_m: float
    ringdown_db: float
    rov_reflectivity: float
    rov_glint: float
    rov_interior: float
    rov_exponent: float
    floor_reflectivity: float
    fish: int
    floating_clutter: int
    n_beams: int
    n_ranges: int
    range_max_m: float


def draw(
    rng: np.random.Generator,
    region: Region,
    *,
    tank_reach_m: float,
    outside_knobs: frozenset[OutsideKnob] | None = None,
) -> Look:
    """Every knob for one run; `tank_reach_m` bounds the range setting (5 m .. 30 m).

    In the outside region, `outside_knobs` (default: all five) are the knobs drawn beyond the
    range trained on; the others are drawn from their whole range, from the same values
    (which knob breaks a detector: `capsd bench detect --looks outside --outside-knobs K`).
    """
    v = {
        name: knob.draw(rng, region, beyond=outside_knobs is None or name in outside_knobs)
        for name, knob in KNOBS.items()
    }
    shape = v["speckle_shape"]
    if region == "train" and rng.random() < RAYLEIGH_SHARE:
        shape = math.inf
    longest = min(30.0, max(5.0, tank_reach_m))
    range_max = max(5.0, min(longest, 5.0 + v["range_fraction"] * (longest - 5.0)))
    return Look(
        water_db=v["water_db"],
        gain_db=v["gain_db"],
        tvg_residual_db=v["tvg_residual_db"],
        gain_jitter_db=v["gain_jitter_db"],
        compression="linear" if rng.random() < 0.3 else "log",
        dynamic_range_db=v["dynamic_range_db"],
        gamma=v["gamma"],
        speckle_shape=shape,
        speckle_corr_beams=v["speckle_corr_beams"],
        speckle_corr_bins=v["speckle_corr_bins"],
        side_lobe_db=v["side_lobe_db"],
        ringdown_m=v["ringdown_m"],
        ringdown_db=v["ringdown_db"],
        rov_reflectivity=v["rov_reflectivity"],
        rov_glint=v["rov_glint"],
        rov_interior=v["rov_interior"],
        rov_exponent=v["rov_exponent"],
        floor_reflectivity=v["floor_reflectivity"],
        fish=round(v["fish"]),
        floating_clutter=round(v["floating_clutter"]),
        n_beams=256 if rng.random() < 0.5 else 512,
        n_ranges=round(v["n_ranges"]),
        range_max_m=round(range_max, 2),
    )


def look_rng(seed: int) -> np.random.Generator:
    """The look's own generator for a run's seed (apart from the motion's and the sensors')."""
    return np.random.default_rng([seed, 0x5EA1])
