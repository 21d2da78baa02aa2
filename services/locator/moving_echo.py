"""Echoes that move as no fixture's echo could: the moving-target test for map-explained echoes.

An echo in a range cell that also holds a mapped fixture (a rack's top, capsd.echo_cell) may be
that fixture, so it may not start a track. But a fixture does not move. Each candidate echo is
followed from ping to ping (a chain: each sighting within `step_m` + `max_speed_m_s` x dt of
the chain's last position on the ROV's depth plane). The chain's first sighting fixes where a
static source could be: somewhere on its arc, the (range, azimuth) cell seen from the sonar's
pose then, at any elevation inside the aperture. Seen from the sonar's pose now, each such
source would appear at a predictable (range, azimuth); if the echo now lies at least
`min_shift_m` from every one of them, after at least `min_age_s` and `min_sightings`, no static
source explains it: it moved. This holds whether the ASV moved or not (the prediction uses both
poses), and a ROV that hovers over a rack stays refused, as any static echo there is.

A point source is what that prediction assumes; a fixture is not one. As the ASV moves, the
brightest part of a rack's top slides along its edge and jumps from corner to corner, 0.3 m and
more between pings: away from where its first sighting's point would be, so "moved", though
nothing did. A ROV's fixes lie on a smooth path (a few centimetres about a straight line over a
second or two). So a chain also counts as moving only while its last `scatter_window`
sightings lie within `max_scatter_m` (RMS) of the straight line fitted through them at their
times. (In a recorded closed-loop run, by hand: chains on the ROV 0.02-0.06 m, chains on rack
tops 0.17-0.23 m, and those had started tracks 4-10 m off the ROV.)
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from capsd.geometry import Array, Transform
from capsd.sonar_geometry import BeamModel, beam_directions, to_polar

_ELEVATION_SAMPLES = 41


@dataclass(frozen=True)
class MovingEchoSettings:
    """How an echo is followed and when it counts as moving; see the module docstring."""

    min_age_s: float = 1.0
    min_sightings: int = 10
    min_shift_m: float = 0.3
    step_m: float = 0.3
    max_speed_m_s: float = 1.0
    forget_after_s: float = 1.0
    max_chains: int = 16
    max_scatter_m: float = 0.1
    scatter_window: int = 40


@dataclass
class _Chain:
    first_ns: int
    first_sonar: Transform
    first_range_m: float
    first_azimuth_rad: float
    last_ns: int
    last_position_m: Array
    sightings: int
    # The latest sightings, (seconds since the first, x, y, z), for the smoothness test.
    path: deque[tuple[float, float, float, float]]


class MovingEchoes:
    """Chains of sightings of candidate echoes, and whether a chain's echo has moved."""

    def __init__(
        self, settings: MovingEchoSettings, *, beam_model: BeamModel, half_aperture_rad: float
    ):
        self.settings = settings
        self.beam_model = beam_model
        self._elevations = np.linspace(-half_aperture_rad, half_aperture_rad, _ELEVATION_SAMPLES)
        self._chains: list[_Chain] = []

    def observe(
        self,
        stamp_ns: int,
        sonar_pose: Transform,
        *,
        range_m: float,
        azimuth_rad: float,
        position_m: Array,
    ) -> bool:
        """Follow one sighting (its cell and its fix on the depth plane); whether it moved."""
        s = self.settings
        self._chains = [
            c for c in self._chains if 0 <= stamp_ns - c.last_ns <= s.forget_after_s * 1e9
        ]
        chain = self._nearest(stamp_ns, position_m)
        if chain is None:
            if len(self._chains) >= s.max_chains:
                self._chains.remove(min(self._chains, key=lambda c: c.last_ns))
            path = deque[tuple[float, float, float, float]](maxlen=max(s.scatter_window, 3))
            chain = _Chain(
                stamp_ns, sonar_pose, range_m, azimuth_rad, stamp_ns, position_m, 0, path
            )
            self._chains.append(chain)
        chain.last_ns = stamp_ns
        chain.last_position_m = position_m
        chain.sightings += 1
        x, y, z = (float(v) for v in position_m[:3])
        chain.path.append(((stamp_ns - chain.first_ns) / 1e9, x, y, z))
        if chain.sightings < s.min_sightings or stamp_ns - chain.first_ns < s.min_age_s * 1e9:
            return False
        # The scatter first: it is the cheaper test, and the one a fixture's echo fails.
        return (
            _scatter_m(chain.path) <= s.max_scatter_m
            and self._shift_m(chain, sonar_pose, range_m, azimuth_rad) >= s.min_shift_m
        )

    def _nearest(self, stamp_ns: int, position_m: Array) -> _Chain | None:
        s = self.settings
        best: tuple[float, _Chain] | None = None
        for chain in self._chains:
            if chain.last_ns == stamp_ns:
                continue  # one sighting per chain and ping
            dt = (stamp_ns - chain.last_ns) / 1e9
            d = float(np.linalg.norm(position_m - chain.last_position_m))
            if d <= s.step_m + s.max_speed_m_s * dt and (best is None or d < best[0]):
                best = (d, chain)
        return None if best is None else best[1]

    def _shift_m(
        self, chain: _Chain, sonar_pose: Transform, range_m: float, azimuth_rad: float
    ) -> float:
        """Metres between the echo now and the nearest place a static source would appear."""
        local = beam_directions(self.beam_model, chain.first_azimuth_rad, self._elevations)
        world = chain.first_range_m * local @ chain.first_sonar.rotation.T
        world += chain.first_sonar.translation
        now = (world - sonar_pose.translation) @ sonar_pose.rotation  # into S now
        shifts = []
        for point in now:
            r, az, _ = to_polar(self.beam_model, point)
            shifts.append(math.hypot(r - range_m, range_m * (az - azimuth_rad)))
        return min(shifts)


def _scatter_m(path: deque[tuple[float, float, float, float]]) -> float:
    """RMS distance of the sightings from the straight line (in time) fitted through them."""
    samples = np.array(path, dtype=np.float64)
    t = samples[:, 0] - samples[:, 0].mean()
    positions = samples[:, 1:]
    centred = positions - positions.mean(axis=0)
    spread = float(t @ t)
    velocity = (t @ centred) / spread if spread > 0.0 else np.zeros(positions.shape[1])
    residual = centred - np.outer(t, velocity)
    return float(np.sqrt(np.mean(np.sum(residual**2, axis=1))))
