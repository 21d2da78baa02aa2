"""The tank's box in the world frame W (corner origin, z up): what is inside it can be the ROV."""

from __future__ import annotations

from typing import Annotated

import msgspec

from capsd.config import ConfigSection
from capsd.geometry import Array


class TankFixture(ConfigSection, frozen=True, kw_only=True):
    """Something fixed in the tank (a rack, a pipe, a sandbag), as its box in W."""

    name: Annotated[str, msgspec.Meta(max_length=64)] = ""
    lo_m: tuple[float, float, float]
    hi_m: tuple[float, float, float]

    def __post_init__(self) -> None:
        super().__post_init__()
        if any(lo >= hi for lo, hi in zip(self.lo_m, self.hi_m, strict=True)):
            raise ValueError(f"fixture {self.name!r}: each of lo_m must be below hi_m")


class TankBounds(ConfigSection, frozen=True, kw_only=True):
    """The tank's box in W; a position outside it (plus `margin_m`) is not the ROV's.

    `fixtures` (racks, pipes) are what the operator's view draws; no fix is refused for them.
    """

    length_m: Annotated[float, msgspec.Meta(gt=0.0, le=10_000.0)] = 28.0
    width_m: Annotated[float, msgspec.Meta(gt=0.0, le=10_000.0)] = 16.0
    depth_m: Annotated[float, msgspec.Meta(gt=0.0, le=11_000.0)] = 8.0
    margin_m: Annotated[float, msgspec.Meta(ge=0.0, le=100.0)] = 0.3
    fixtures: Annotated[tuple[TankFixture, ...], msgspec.Meta(max_length=1000)] = ()

    def clear_of_walls(self, p: Array | tuple[float, float, float], clearance_m: float) -> bool:
        """Whether `p` is at least `clearance_m` inside every wall, the floor and the surface.

        A geofence for targets; `contains` is the tolerant test for estimates.
        """
        c = clearance_m
        return bool(
            c <= p[0] <= self.length_m - c
            and c <= p[1] <= self.width_m - c
            and -self.depth_m + c <= p[2] <= -c
        )

    def within_walls_xy(self, xy: Array, clearance_m: float) -> tuple[float, float]:
        """`xy` moved the least to where it is `clearance_m` inside the walls."""
        c = clearance_m
        x = min(max(float(xy[0]), c), max(c, self.length_m - c))
        y = min(max(float(xy[1]), c), max(c, self.width_m - c))
        return x, y

    def contains(self, p: Array | tuple[float, float, float]) -> bool:
        m = self.margin_m
        return bool(
            -m <= p[0] <= self.length_m + m
            and -m <= p[1] <= self.width_m + m
            and -self.depth_m - m <= p[2] <= m
        )
