"""What the polar network sees: a coarse whole-frame grid and metric crops around candidates.

Both are taken from the polar image itself (range bins x beams), never from a fan warp:
- the coarse grid pools the frame to cells of about `COARSE_RANGE_M` in range and
  `n_beams / COARSE_BEAMS` beams, two channels (mean and max, so a small bright ROV echo stands
  out from speckle), whatever the sonar's range setting or beam count;
- a crop resamples a window of `CROP_SIZE` x `CROP_SIZE` samples, `CROP_STEP_M` apart in range
  and in cross-range (azimuth x range), centred on a candidate: the ROV looks the same size at
  1 m and at 15 m, so one refinement network serves every range.
Both read the normalised image (`normalised_image`): the echo against its range row's
background, in units of the frame's own contrast, so neither a sonar's gain nor its noise
floor decides what the network sees.
numpy and OpenCV only: the training data generator and the detector share this code.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
import numpy.typing as npt

from capsd.payloads import SonarFrame
from capsd.sonar_image import Image, unit_image

COARSE_RANGE_M = 0.08
COARSE_BEAMS = 128
CROP_SIZE = 96
CROP_STEP_M = 0.02
CONTEXT_STEP_M = 0.08  # the context channel: the same grid 4x coarser, 7.7 m across


# The normalised input: each range row's background (the median over beams) at 0, the frame's
# bright echoes (its 99.5th percentile above the background) near 1, clipped to this span.
NORM_LOW = -0.5
NORM_HIGH = 1.5
MIN_CONTRAST = 0.1  # a frame with hardly any echo is not stretched more than 10x


def normalised_image(frame: SonarFrame) -> Image:
    """The frame's echoes against their background, in units of the frame's contrast.

    What the network sees, so that a sonar's gain, its time-varied gain and its noise floor
    (near black on a real Oculus, mid grey on some renderers) do not decide: per range row
    the background level is the median over beams (a CFAR-like reference along the range
    axis, where TVG and the water column change), the scale the frame's own bright echoes.
    Statistics from every 2nd row and 4th beam: ~0.5 ms for 512 x 1000.
    """
    image = unit_image(frame)
    sub = image[::2, ::4]
    background = row_medians(sub)
    above = (sub - background[:, None]).ravel()
    k = int(0.995 * (above.size - 1))
    contrast = float(np.partition(above, k)[k]) if above.size else 0.0
    rows = np.repeat(background, 2)[: frame.n_ranges, None]
    out = np.subtract(image, rows, dtype=np.float32)
    out *= np.float32(1.0 / max(contrast, MIN_CONTRAST))
    np.clip(out, NORM_LOW, NORM_HIGH, out=out)
    return out


def row_medians(a: Image) -> Image:
    """`np.median(a, axis=1)`, the same values, from a sort of each row.

    numpy sorts short float32 rows with SIMD; its median partitions them: 0.17 against 1.2 ms
    for the 500 x 128 statistics grid of a 512 x 1000 frame, a tenth of a whole-frame search.
    """
    n = a.shape[1]
    middle = np.sort(a, axis=1)[:, (n - 1) // 2 : n // 2 + 1]  # one value (odd n) or two
    return np.asarray(np.mean(middle, axis=1), dtype=np.float32)


RangeInput = Literal["none", "channel"]


@dataclass(frozen=True)
class Inputs:
    """What a network's weights expect besides the image (stored with them, polar_net).

    `range_input: channel` adds the range plane to the grid and the crops; `coarse_beams` is
    the grid's width in cells (a finer grid resolves a far ROV's few beams).
    """

    range_input: RangeInput = "none"
    coarse_beams: int = COARSE_BEAMS

    @property
    def extra_planes(self) -> int:
        """Planes each stage reads besides the image's: 1 with the range plane, else 0."""
        return 1 if self.range_input == "channel" else 0


DEFAULT_INPUTS = Inputs()  # what weights saved before `Inputs` existed expect


# The range plane (`range_input: channel`): 0 to RANGE_PLANE_M mapped onto the
# normalised span, so that it survives the 8-bit training sets like an image plane.
RANGE_PLANE_M = 30.0


def range_value(range_m: npt.ArrayLike) -> npt.NDArray[np.float32]:
    """Ranges (m) in the range plane's units."""
    share = np.clip(np.asarray(range_m, dtype=np.float64) / RANGE_PLANE_M, 0.0, 1.0)
    return np.asarray(NORM_LOW + (NORM_HIGH - NORM_LOW) * share, dtype=np.float32)


def with_range_rows(coarse: Image, frame: SonarFrame, grid: Grid) -> Image:
    """The coarse grid with a third plane: each row's centre range."""
    rows = np.arange(grid.rows, dtype=np.float64)
    ranges = frame.range_start_m + (rows + 0.5) * grid.range_factor * frame.range_resolution_m
    plane = np.broadcast_to(range_value(ranges)[:, None], (grid.rows, grid.cols))
    return np.concatenate([coarse, plane[None]]).astype(np.float32, copy=False)


def with_range_plane(crops: Image, range_m: float) -> Image:
    """Crops (channels x N x N) with one more plane: the crop's centre range, constant."""
    plane = np.full((1, *crops.shape[1:]), range_value(range_m), dtype=np.float32)
    return np.concatenate([crops, plane]).astype(np.float32, copy=False)


def to_u8(a: Image) -> npt.NDArray[np.uint8]:
    """A normalised image (or crop, or grid) as 8 bits for training sets; `from_u8` inverts."""
    scaled = (a - NORM_LOW) * (255.0 / (NORM_HIGH - NORM_LOW)) + 0.5
    return np.asarray(np.clip(scaled, 0, 255), dtype=np.uint8)


U8_SCALE = (NORM_HIGH - NORM_LOW) / 255.0  # from_u8(u) = u * U8_SCALE + NORM_LOW


@dataclass(frozen=True)
class Grid:
    """How a frame maps to coarse cells: `range_factor` bins x `beam_factor` beams per cell."""

    range_factor: int
    beam_factor: int
    rows: int
    cols: int

    @staticmethod
    def of(frame: SonarFrame, *, beams: int = COARSE_BEAMS) -> Grid:
        fr = max(1, round(COARSE_RANGE_M / frame.range_resolution_m))
        fb = max(1, round(frame.n_beams / beams))
        return Grid(fr, fb, frame.n_ranges // fr, frame.n_beams // fb)


def coarse_input(image: Image, grid: Grid) -> Image:
    """2 x rows x cols: the mean and the max of each cell."""
    fr, fb = grid.range_factor, grid.beam_factor
    body = image[: grid.rows * fr, : grid.cols * fb]
    mean = cv2.resize(body, (grid.cols, grid.rows), interpolation=cv2.INTER_AREA)
    # Max pooling as a dilation then a strided pick: much faster than a reshape-max.
    peak = cv2.dilate(body, np.ones((fr, fb), np.uint8), anchor=(0, 0))[::fr, ::fb]
    return np.stack([mean, peak[: grid.rows, : grid.cols]]).astype(np.float32, copy=False)


class BeamTable:
    """Azimuth <-> fractional beam index, from the frame's bearing table (either order)."""

    def __init__(self, azimuths_rad: tuple[float, ...] | npt.NDArray[np.float64]):
        table = np.asarray(azimuths_rad, dtype=np.float64)
        self.azimuths = table
        self._ascending = bool(table[-1] >= table[0])
        self._index = np.arange(len(table), dtype=np.float64)
        # Read for every crop and candidate: computed once (0.3 ms a whole-frame search).
        self._half_fov_rad = float(np.max(np.abs(table)))

    def index(self, azimuth_rad: float | npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """Fractional beam indices; outside the fan the edge beam's index (the crop masks it)."""
        if self._ascending:
            out = np.interp(azimuth_rad, self.azimuths, self._index)
        else:
            out = np.interp(azimuth_rad, self.azimuths[::-1], self._index[::-1])
        return np.asarray(out, dtype=np.float64)

    def azimuth(self, index: float | npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        return np.asarray(np.interp(index, self._index, self.azimuths), dtype=np.float64)

    @property
    def half_fov_rad(self) -> float:
        return self._half_fov_rad


def crop(
    image: Image,
    frame: SonarFrame,
    table: BeamTable,
    *,
    range_m: float,
    azimuth_rad: float,
    step_m: float = CROP_STEP_M,
) -> Image:
    """CROP_SIZE x CROP_SIZE samples around (range_m, azimuth_rad); rows: range, cols: cross.

    Row i is at range `range_m + (i - c) * step_m`, column j at azimuth
    `azimuth_rad + (j - c) * step_m / range_m`, with c = (CROP_SIZE - 1) / 2. Samples
    outside the image or the fan are 0.
    """
    c = (CROP_SIZE - 1) / 2.0
    offsets = (np.arange(CROP_SIZE, dtype=np.float64) - c) * step_m
    ranges = range_m + offsets
    azimuths = azimuth_rad + offsets / max(range_m, 0.05)
    rows = (ranges - frame.range_start_m) / frame.range_resolution_m - 0.5
    cols = table.index(azimuths)
    outside = np.abs(azimuths) > table.half_fov_rad + 1e-9
    cols = np.where(outside, -10.0, cols)
    map_x = np.broadcast_to(cols.astype(np.float32)[None, :], (CROP_SIZE, CROP_SIZE))
    map_y = np.broadcast_to(rows.astype(np.float32)[:, None], (CROP_SIZE, CROP_SIZE))
    out = cv2.remap(
        image,
        np.ascontiguousarray(map_x),
        np.ascontiguousarray(map_y),
        interpolation=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0.0,
    )
    return np.asarray(out, dtype=np.float32)


def crop_pair(
    image: Image, frame: SonarFrame, table: BeamTable, *, range_m: float, azimuth_rad: float
) -> Image:
    """2 x CROP_SIZE x CROP_SIZE: the detail crop and, centred on it, the context crop.

    The context (7.7 m across) shows what the detail cannot: whether the blob lies on the
    floor's echo among the clutter (a sandbag, a rack corner) or hangs in the water column with
    its shadow behind it (the ROV).
    """
    return np.stack(
        [
            crop(image, frame, table, range_m=range_m, azimuth_rad=azimuth_rad),
            crop(
                image, frame, table, range_m=range_m, azimuth_rad=azimuth_rad, step_m=CONTEXT_STEP_M
            ),
        ]
    )
