"""The classical ROV detector on the polar frame: background, CFAR, blobs, weighted centre.

Steps, all in the polar image (range bins x beams), no fan warping:
1. smooth with the beam/pulse scale (3 x 3) to tame speckle;
2. background: an exponential moving average of past frames, and a local mean around each
   cell (cell-averaging CFAR with a guard band); a cell is "on" when it exceeds both by a
   margin (in the image's log-compressed units);
3. connected blobs whose extent in metres fits a BlueROV2 (range and cross-range extent);
4. the intensity-weighted centre of each blob, its azimuth read off the bearing table, and
   its range moved back by `range_bias_m`: the echo comes from the ROV's near side, its centre
   lies further (calibrated on simulated labels by `capsd bench detect`);
5. confidence from the blob's contrast and size fit; candidates sorted by confidence.
It needs numpy and OpenCV only (no torch), for light installs and as a cross-check of the CNN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from capsd.payloads import Detection, SonarFrame

Image = npt.NDArray[np.float32]


@dataclass(frozen=True)
class ClassicalSettings:
    margin: float = 70.0  # above the local mean (image units, 0..255 log-compressed)
    # Above a moving-average background; None turns it off. Off by default: an ASV that follows
    # the ROV keeps it at the same place in the image, where a background model learns it.
    background_margin: float | None = None
    background_alpha: float = 0.05  # EMA weight of a new frame
    guard_m: float = 0.6  # CFAR guard half-size in range (m); the window is 3x that
    guard_beams: int = 8
    min_extent_m: float = 0.08
    max_extent_m: float = 0.9
    range_bias_m: float = 0.12
    max_candidates: int = 3
    energy_scale: float = 4000.0  # energy at which confidence reaches 63%
    # The near-field ring-down at the apex (the transducer ringing after transmit) makes
    # bright blobs there on every ping: nothing closer is a candidate.
    ringdown_m: float = 1.0


@dataclass(frozen=True)
class Blob:
    range_m: float
    azimuth_rad: float
    range_extent_m: float
    azimuth_extent_rad: float
    energy: float  # summed excess over the local mean: dense bright echoes score high


def _image(frame: SonarFrame) -> Image:
    dtype = np.uint8 if frame.sample_bits == 8 else np.dtype("<u2")
    raw = np.frombuffer(frame.image, dtype=dtype).reshape(frame.n_ranges, frame.n_beams)
    image = raw.astype(np.float32)
    if frame.sample_bits == 16:
        image *= np.float32(255.0 / 65535.0)
    return image


class ClassicalDetector:
    """Stateful (the background model): feed frames in order with `detect`."""

    def __init__(self, settings: ClassicalSettings | None = None):
        self.settings = settings or ClassicalSettings()
        self._background: Image | None = None

    def detect(
        self, frame: SonarFrame, *, range_window: tuple[float, float] | None = None
    ) -> list[Detection]:
        """ROV candidates, strongest first; only blobs inside `range_window` if given."""
        s = self.settings
        image: Image = np.asarray(cv2.GaussianBlur(_image(frame), (5, 5), 1.2), dtype=np.float32)
        res = frame.range_resolution_m
        guard_bins = max(3, int(s.guard_m / res))
        window = (2 * s.guard_beams * 3 + 1, 2 * guard_bins * 3 + 1)
        guard = (2 * s.guard_beams + 1, 2 * guard_bins + 1)
        # CFAR: the mean of the window minus its guard region.
        big = cv2.boxFilter(image, -1, window, normalize=False, borderType=cv2.BORDER_REFLECT)
        small = cv2.boxFilter(image, -1, guard, normalize=False, borderType=cv2.BORDER_REFLECT)
        local = (big - small) / float(window[0] * window[1] - guard[0] * guard[1])
        background = self._background
        if background is None or background.shape != image.shape:
            background = self._background = image.copy()
        on = image > local + s.margin
        if s.background_margin is not None:
            on &= image > background + s.background_margin
            cv2.accumulateWeighted(image, background, s.background_alpha)
        # Close small gaps so one ROV echo broken up by speckle stays one blob.
        closed = cv2.morphologyEx(on.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((5, 3), np.uint8))
        mask = np.asarray(closed, dtype=np.uint8)
        lo, hi = range_window if range_window is not None else (0.0, math.inf)
        blobs = [
            b
            for b in self._blobs(frame, image, local, mask)
            if b.range_m >= s.ringdown_m and lo <= b.range_m + s.range_bias_m <= hi
        ]
        detections = []
        for blob in sorted(blobs, key=lambda b: -b.energy)[: s.max_candidates]:
            confidence = float(1.0 - math.exp(-blob.energy / s.energy_scale))
            r = blob.range_m + s.range_bias_m
            detections.append(
                Detection(
                    range_m=r,
                    azimuth_rad=blob.azimuth_rad,
                    range_sigma_m=max(res, 0.02),
                    azimuth_sigma_rad=0.004,
                    confidence=min(max(confidence, 0.0), 1.0),
                    range_extent_m=blob.range_extent_m,
                    azimuth_extent_rad=blob.azimuth_extent_rad,
                )
            )
        return detections

    def _blobs(
        self, frame: SonarFrame, image: Image, local: Image, mask: npt.NDArray[np.uint8]
    ) -> list[Blob]:
        s = self.settings
        res = frame.range_resolution_m
        azimuths = np.asarray(frame.azimuths_rad)
        count, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        blobs = []
        for k in range(1, count):
            x, y, w, h, area = (int(v) for v in stats[k])
            if area < 4:
                continue
            rows = slice(y, y + h)
            cols = slice(x, x + w)
            inside = labels[rows, cols] == k
            weights = (image[rows, cols] - local[rows, cols]) * inside
            weights = np.clip(weights, 0.0, None)
            total = float(weights.sum())
            if total <= 0.0:
                continue
            r_idx = (np.arange(y, y + h, dtype=np.float64) + 0.5)[:, None]
            b_idx = np.arange(x, x + w, dtype=np.float64)[None, :]
            row_c = float((weights * r_idx).sum() / total)
            beam_c = float((weights * b_idx).sum() / total)
            range_c = frame.range_start_m + row_c * res
            azimuth = float(np.interp(beam_c, np.arange(len(azimuths)), azimuths))
            range_extent = h * res
            span = abs(azimuths[min(x + w - 1, len(azimuths) - 1)] - azimuths[x])
            cross_extent = range_c * float(span)
            if not (
                s.min_extent_m <= range_extent <= s.max_extent_m and cross_extent <= s.max_extent_m
            ):
                continue
            blobs.append(Blob(range_c, azimuth, range_extent, float(span), total))
        return blobs
