"""Static clutter learned on the fly: where fixes that are not the ROV keep coming from.

A sandbag, a rack edge or a wall bracket inside the sonar's view gives a detection that the
locator turns into a fix at the ROV's depth: a plausible position that stays put. While a
confirmed track says where the ROV is, every other candidate fix lands in a horizontal grid
cell; a cell that keeps collecting them over `static_after_s` is static clutter. Such a cell
may not start (or restart) a track: after a loss the ROV must be found where nothing static
echoed before. It can still be tracked through one, since association follows the track. A
moving ROV never fills a cell for long (0.5 m at 0.3 m/s is under 2 s), so it is not learned
even when the track is wrongly on something else. Cells forget after `forget_after_s` unseen.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from capsd.geometry import Array


@dataclass(frozen=True)
class ClutterSettings:
    """Grid and persistence of the clutter map; see the module docstring."""

    cell_m: float = 0.5
    static_after_s: float = 5.0  # seen in one cell over at least this long: static
    min_sightings: int = 10
    forget_after_s: float = 60.0
    radius_m: float = 0.5  # an echo this near a static cell's centre of sightings is its echo


@dataclass
class _Cell:
    first_ns: int
    last_ns: int
    sightings: int
    sum_x: float  # of the sightings' positions: their centre
    sum_y: float


class ClutterMap:
    """Cells of the horizontal plane where non-ROV fixes persist."""

    def __init__(self, settings: ClutterSettings):
        self.settings = settings
        self._cells: dict[tuple[int, int], _Cell] = {}
        self._cap = 10_000  # bounded: a noisy tank must not grow it without limit

    def _key(self, position_m: Array) -> tuple[int, int]:
        size = self.settings.cell_m
        return math.floor(float(position_m[0]) / size), math.floor(float(position_m[1]) / size)

    def observe(self, stamp_ns: int, position_m: Array) -> None:
        """A candidate fix at `position_m` that is not the tracked ROV."""
        key = self._key(position_m)
        cell = self._cells.get(key)
        forget_ns = int(self.settings.forget_after_s * 1e9)
        if cell is None or stamp_ns - cell.last_ns > forget_ns:
            if cell is None and len(self._cells) >= self._cap:
                self._forget(stamp_ns)
                if len(self._cells) >= self._cap:
                    return
            x, y = float(position_m[0]), float(position_m[1])
            self._cells[key] = _Cell(stamp_ns, stamp_ns, 1, x, y)
            return
        cell.last_ns = max(cell.last_ns, stamp_ns)
        cell.sightings += 1
        cell.sum_x += float(position_m[0])
        cell.sum_y += float(position_m[1])

    def is_static(self, stamp_ns: int, position_m: Array) -> bool:
        """Whether `position_m` lies within `radius_m` of a static cell's centre of sightings."""
        cx, cy = self._key(position_m)
        reach = math.ceil(self.settings.radius_m / self.settings.cell_m)
        x, y = float(position_m[0]), float(position_m[1])
        for dx in range(-reach, reach + 1):
            for dy in range(-reach, reach + 1):
                cell = self._cells.get((cx + dx, cy + dy))
                if cell is not None and self._static(stamp_ns, cell):
                    centre_x, centre_y = cell.sum_x / cell.sightings, cell.sum_y / cell.sightings
                    if math.hypot(x - centre_x, y - centre_y) <= self.settings.radius_m:
                        return True
        return False

    def _static(self, stamp_ns: int, cell: _Cell) -> bool:
        s = self.settings
        return (
            stamp_ns - cell.last_ns <= s.forget_after_s * 1e9
            and cell.sightings >= s.min_sightings
            and cell.last_ns - cell.first_ns >= s.static_after_s * 1e9
        )

    def _forget(self, stamp_ns: int) -> None:
        forget_ns = int(self.settings.forget_after_s * 1e9)
        self._cells = {k: c for k, c in self._cells.items() if stamp_ns - c.last_ns <= forget_ns}

    def static_cells(self, stamp_ns: int) -> int:
        """How many cells are static clutter now (a health counter)."""
        return sum(self._static(stamp_ns, c) for c in self._cells.values())
