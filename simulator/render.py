"""Pictures for people: a tank top view (the sonar fan is capsd.fan)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from capsd.fan import draw_fan, write_png
from capsd.geometry import Array
from capsd.simulator.world import Tank

Image = npt.NDArray[np.uint8]

_GREEN = (80, 220, 80)
_RED = (60, 60, 240)
_YELLOW = (40, 220, 240)
_GREY = (120, 120, 120)


def draw_top_view(
    tank: Tank, rov_xy: Array, asv_xy: Array, out: Path, *, px_per_m: float = 40.0
) -> None:
    """Write a top view of the tank: walls, clutter, the ROV's (green) and ASV's (red) tracks."""
    write_png(out, top_view(tank, rov_xy, asv_xy, px_per_m=px_per_m))


def top_view(tank: Tank, rov_xy: Array, asv_xy: Array, *, px_per_m: float = 40.0) -> Image:
    """The top view image (tracks may hold a single point: the current positions)."""
    margin = 30
    w = int(tank.length_m * px_per_m) + 2 * margin
    h = int(tank.width_m * px_per_m) + 2 * margin
    image = np.full((h, w, 3), 245, dtype=np.uint8)

    def px(x: float, y: float) -> tuple[int, int]:  # y up on the page
        return int(margin + x * px_per_m), int(h - margin - y * px_per_m)

    cv2.rectangle(image, px(0, 0), px(tank.length_m, tank.width_m), (40, 40, 40), 2)
    for box in tank.boxes:
        shade = {"rack": (160, 160, 160), "sandbag": (150, 190, 200)}.get(box.kind, (90, 90, 90))
        cv2.rectangle(image, px(box.lo[0], box.lo[1]), px(box.hi[0], box.hi[1]), shade, -1)
    for cyl in tank.cylinders:
        start = np.array(cyl.start)
        if cyl.axis == "z":
            cv2.circle(
                image, px(start[0], start[1]), max(2, int(cyl.radius * px_per_m)), (90, 90, 90), -1
            )
        else:
            end = start.copy()
            end["xyz".index(cyl.axis)] += cyl.length
            cv2.line(
                image,
                px(start[0], start[1]),
                px(end[0], end[1]),
                (90, 90, 90),
                max(2, int(2 * cyl.radius * px_per_m)),
            )
    for track, colour in ((rov_xy, (60, 160, 60)), (asv_xy, (60, 60, 220))):
        pts = np.array([px(x, y) for x, y in track[:: max(1, len(track) // 2000)]], dtype=np.int32)
        cv2.polylines(image, [pts], False, colour, 2)
        cv2.circle(image, tuple(int(c) for c in pts[0]), 5, colour, -1)
    cv2.putText(
        image,
        f"{tank.name}: {tank.length_m:g} x {tank.width_m:g} x {tank.depth_m:g} m   "
        "green ROV, red ASV, grey clutter",
        (margin, 20),
        cv2.FONT_HERSHEY_SIMPLEX,
        0.5,
        (40, 40, 40),
        1,
    )
    cv2.line(image, px(0.5, -0.4), px(1.5, -0.4), (40, 40, 40), 2)
    cv2.putText(image, "1 m", px(1.7, -0.55), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (40, 40, 40), 1)
    return image


__all__ = ["draw_fan", "draw_top_view", "top_view"]
