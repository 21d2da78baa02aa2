"""Per-vehicle clocks: what a vehicle's stamp says for a true instant (offset, drift, jitter).

stamp = true + offset + drift_ppm * 1e-6 * (true - start) + N(0, jitter). The ASV's sensors use
the ASV's clock, the ROV's the ROV's, so the locator sees the skew a real deployment has.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ClockModel:
    offset_s: float = 0.0
    drift_ppm: float = 0.0
    jitter_s: float = 0.0


class VehicleClock:
    def __init__(self, model: ClockModel, start_ns: int, rng: np.random.Generator):
        self.model = model
        self.start_ns = start_ns
        self.rng = rng

    def stamp(self, true_ns: int) -> int:
        m = self.model
        elapsed = (true_ns - self.start_ns) / 1e9
        error = m.offset_s + m.drift_ppm * 1e-6 * elapsed
        if m.jitter_s > 0.0:
            error += float(self.rng.normal(0.0, m.jitter_s))
        return max(0, true_ns + round(error * 1e9))
