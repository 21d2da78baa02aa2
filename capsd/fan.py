"""The sonar frame as a Cartesian fan PNG, with truth and detections drawn on it."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from capsd.payloads import SonarDetections, SonarFrame, SonarLabel

Image = npt.NDArray[np.uint8]

_GREEN = (80, 220, 80)
_RED = (60, 60, 240)
_YELLOW = (40, 220, 240)
_GREY = (120, 120, 120)


def fan_image(frame: SonarFrame, *, width_px: int = 900) -> tuple[Image, float, tuple[int, int]]:
    """The polar image warped to a fan (apex at the bottom centre, port to the left).

    Returns the BGR image, metres per pixel and the apex pixel.
    """
    polar = np.frombuffer(frame.image, dtype=np.uint8 if frame.sample_bits == 8 else "<u2")
    polar = polar.reshape(frame.n_ranges, frame.n_beams).astype(np.float32)
    if frame.sample_bits == 16:
        polar /= 256.0
    azimuths = np.asarray(frame.azimuths_rad)
    r_max = frame.range_start_m + frame.n_ranges * frame.range_resolution_m
    half = float(np.max(np.abs(azimuths)))
    half_width_m = r_max * math.sin(min(half, math.pi / 2))
    scale = (2 * half_width_m) / (width_px - 40)
    height_px = int(r_max / scale) + 40
    apex = (width_px // 2, height_px - 20)
    u, v = np.meshgrid(
        np.arange(width_px, dtype=np.float32), np.arange(height_px, dtype=np.float32)
    )
    ahead = (apex[1] - v) * scale  # sonar x
    left = (apex[0] - u) * scale  # sonar y (port)
    rng = np.hypot(ahead, left)
    theta = np.arctan2(left, ahead)
    order = np.argsort(azimuths)
    beam = np.interp(theta, azimuths[order], order.astype(np.float64), left=-1, right=-1)
    row = (rng - frame.range_start_m) / frame.range_resolution_m
    outside = (beam < 0) | (row < 0) | (row > frame.n_ranges - 1) | (ahead < 0)
    map_x = np.where(outside, -1, beam).astype(np.float32)
    map_y = np.where(outside, -1, row).astype(np.float32)
    fan = cv2.remap(
        polar, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0
    )
    gray = np.clip(fan, 0, 255).astype(np.uint8)
    color = np.asarray(cv2.applyColorMap(gray, cv2.COLORMAP_BONE), dtype=np.uint8)
    color[outside] = (25, 25, 25)
    for ring in range(1, int(r_max) + 1):
        if ring % (5 if r_max > 12 else 1) == 0:
            cv2.ellipse(
                color,
                apex,
                (int(ring / scale),) * 2,
                -90,
                -math.degrees(half),
                math.degrees(half),
                _GREY,
                1,
            )
            p = _pixel(apex, scale, ring, half)
            _text(color, f"{ring} m", (p[0] + 4, p[1] + 4))
    _intensity_scale(color)
    return np.asarray(color, dtype=np.uint8), scale, apex


def _text(
    image: Image, text: str, at: tuple[int, int], colour: tuple[int, int, int] = _GREY
) -> None:
    """Readable on any background: the text on a dark box of its own size."""
    (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.5, 1)
    x, y = at
    cv2.rectangle(image, (x - 2, y - h - 3), (x + w + 2, y + base), (15, 15, 15), -1)
    cv2.putText(image, text, at, cv2.FONT_HERSHEY_SIMPLEX, 0.5, colour, 1, cv2.LINE_AA)


def _intensity_scale(image: Image) -> None:
    """A bar of the colour map (sample 0 at the bottom, 255 at the top), top right."""
    height, width = 160, 14
    x0, y0 = image.shape[1] - 70, 30
    ramp = np.linspace(255, 0, height).astype(np.uint8)[:, None].repeat(width, axis=1)
    image[y0 : y0 + height, x0 : x0 + width] = cv2.applyColorMap(ramp, cv2.COLORMAP_BONE)
    cv2.rectangle(image, (x0 - 1, y0 - 1), (x0 + width, y0 + height), _GREY, 1)
    _text(image, "255", (x0 + width + 4, y0 + 10))
    _text(image, "0", (x0 + width + 4, y0 + height))
    _text(image, "echo", (x0 - 8, y0 - 10))


def _pixel(apex: tuple[int, int], scale: float, range_m: float, azimuth: float) -> tuple[int, int]:
    ahead, left = range_m * math.cos(azimuth), range_m * math.sin(azimuth)
    return round(apex[0] - left / scale), round(apex[1] - ahead / scale)


def draw_fan(
    frame: SonarFrame, label: SonarLabel | None, detections: SonarDetections | None, out: Path
) -> None:
    """Write the fan PNG: truth in green (centre, footprint), ghosts in yellow, detections red."""
    write_png(out, fan_with_overlays(frame, label, detections))


def fan_with_overlays(
    frame: SonarFrame, label: SonarLabel | None, detections: SonarDetections | None
) -> Image:
    """The fan image with the truth (if any) and the detections drawn on it."""
    image, scale, apex = fan_image(frame)
    if label is not None:
        if (
            label.range_min_m is not None
            and label.range_max_m is not None
            and (label.azimuth_min_rad is not None and label.azimuth_max_rad is not None)
        ):
            corners = [
                (r, a)
                for r in (label.range_min_m, label.range_max_m)
                for a in (label.azimuth_min_rad, label.azimuth_max_rad)
            ]
            pts = np.array(
                [
                    _pixel(apex, scale, r, a)
                    for r, a in (corners[0], corners[1], corners[3], corners[2])
                ]
            )
            cv2.polylines(image, [pts], True, _GREEN, 1)
        centre = _pixel(apex, scale, label.range_m, label.azimuth_rad)
        cv2.circle(image, centre, 6, _GREEN, 1)
        text = f"truth r={label.range_m:.2f} m az={math.degrees(label.azimuth_rad):.1f} deg"
        if label.overlap:
            text += "  (clutter overlaps)"
        _text(image, text, (10, 20), _GREEN)
        for ghost in label.ghosts:
            cv2.circle(image, _pixel(apex, scale, ghost.range_m, ghost.azimuth_rad), 5, _YELLOW, 1)
    if detections is not None:
        for det in detections.detections:
            p = _pixel(apex, scale, det.range_m, det.azimuth_rad)
            cv2.drawMarker(image, p, _RED, cv2.MARKER_CROSS, 12, 1)
    _text(image, f"ping {frame.ping_id}", (10, 40))
    return image


def write_png(out: Path, image: Image) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), image):
        raise OSError(f"could not write {out}")
