"""A sonar frame's samples as an array: the one place the wire bytes become numbers."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from capsd.payloads import SonarFrame

Image = npt.NDArray[np.float32]


def unit_image(frame: SonarFrame) -> Image:
    """The frame's samples as float32 in 0..1 (8- and 16-bit alike), n_ranges x n_beams."""
    if frame.sample_bits == 8:
        raw = np.frombuffer(frame.image, dtype=np.uint8).reshape(frame.n_ranges, frame.n_beams)
        return np.asarray(np.multiply(raw, np.float32(1.0 / 255.0), dtype=np.float32))
    raw16 = np.frombuffer(frame.image, dtype="<u2").reshape(frame.n_ranges, frame.n_beams)
    return np.asarray(np.multiply(raw16, np.float32(1.0 / 65535.0), dtype=np.float32))
