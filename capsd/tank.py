"""The tank's box in the world frame W (corner origin, z up): what is inside it can be the ROV."""

from __future__ import annotations

from typing import Annotated

import msgspec

from capsd.config import ConfigSection
from capsd.geometry import Array


class TankBounds(ConfigSection, frozen=True, kw_only=True):
    """The tank's box in W; a position outside it (plus `margin_m`) is not the ROV's."""

    length_m: Annotated[float, msgspec.Meta(gt=0.0, le=10_000.0)] = 28.0
    width_m: Annotated[float, msgspec.Meta(gt=0.0, le=10_000.0)] = 16.0
    depth_m: Annotated[float, msgspec.Meta(gt=0.0, le=11_000.0)] = 8.0
    margin_m: Annotated[float, msgspec.Meta(ge=0.0, le=100.0)] = 0.3

    def contains(self, p: Array | tuple[float, float, float]) -> bool:
        m = self.margin_m
        return bool(
            -m <= p[0] <= self.length_m + m
            and -m <= p[1] <= self.width_m + m
            and -self.depth_m - m <= p[2] <= m
        )
