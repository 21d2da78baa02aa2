"""Forming a multibeam sonar image (an Oculus M3000d in its 1.2 MHz mode) from the scene.

Per ping (FIELD-NOTES, as HoloOcean/Stonefish/DAVE do, condensed):
1. each of the `n_beams` beams (evenly spaced in sin(theta), as the real bearing table) casts
   `elevation_rays` rays over the vertical aperture (stratified, jittered per ping; the beams
   that may see the ROV up to 16 times as many, each standing for its share) and keeps the
   nearest hit, so objects shadow what lies behind them;
2. echo = reflectivity x cos(incidence)^n x vertical beam weight x residual absorption (time-
   varied gain has compensated spreading), accumulated into range bin x beam;
3. multipath ghosts: the ROV mirrored in the water surface and in the nearest wall, seen at
   half the bounce path's length, attenuated;
4. blur with the beam pattern (main lobe ~1 beam, side lobes ~-25 dB out to 10 beams) and the
   pulse (~1 range bin); exponential speckle; additive noise growing with range;
5. gain in dB and a gamma curve to uint8.
The truth label (the ROV centre's range/azimuth, its footprint and whether clutter overlaps it)
comes from the same rays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Literal

import cv2
import numpy as np
import numpy.typing as npt

from capsd.geometry import Array, IndexArray, MaskArray, Transform
from capsd.payloads import SonarFrame
from capsd.simulator import scene
from capsd.simulator.scene import Ellipsoid
from capsd.simulator.sonar_look import Look
from capsd.simulator.world import Tank
from capsd.sonar_geometry import BeamModel, to_polar

# Rays a beam casts over the ROV's height at the least, and the most times the usual rays a
# beam that may see the ROV casts for it (see SonarRenderer._rays).
SLABS_PER_ROV_HEIGHT = 8.0
MAX_RAYS_FACTOR = 16


@dataclass(frozen=True)
class SonarModel:
    """The sonar's geometry and the image-formation constants."""

    n_beams: int = 512
    half_fov_rad: float = math.radians(65.0)
    vertical_aperture_rad: float = math.radians(20.0)
    beam_model: BeamModel = "conical"
    range_max_m: float = 30.0
    n_ranges: int = 1000
    elevation_rays: int = 16
    frequency_hz: float = 1.2e6
    sound_speed_m_s: float = 1480.0
    gain_percent: float = 50.0  # 50% = 0 dB; each 10% = 4 dB
    absorption_db_per_m: float = 0.1  # what time-varied gain leaves uncompensated
    noise_level: float = 0.0004
    noise_growth: float = 3.0  # noise at max range = (1 + growth) x noise at the head
    ghost_gain: float = 0.12
    incidence_exponent: float = 2.0
    dynamic_range_db: float = 35.0
    gamma: float = 0.8
    # The knobs of capsd.simulator.sonar_look; these defaults are the fixed look (variety: off).
    tvg_residual_db: float = 0.0
    gain_jitter_db: float = 0.0
    compression: Literal["log", "linear"] = "log"
    speckle_shape: float = math.inf
    speckle_corr_beams: float = 0.0
    speckle_corr_bins: float = 0.0
    side_lobe_db: float = 10.0 * math.log10(0.003)
    ringdown_m: float = 0.0
    ringdown_db: float = -10.0
    rov_reflectivity: float = 1.0
    rov_glint: float = 0.0
    rov_interior: float = 0.0
    rov_exponent: float = 1.0
    fish: int = 0

    def with_look(self, look: Look) -> SonarModel:
        """The sonar as a run's draw of the look knobs renders it."""
        return replace(
            self,
            n_beams=look.n_beams,
            n_ranges=look.n_ranges,
            range_max_m=look.range_max_m,
            gain_percent=min(max(50.0 + look.gain_db / 0.4, 0.0), 100.0),
            noise_level=0.5 * 10.0 ** (look.water_db / 10.0),
            dynamic_range_db=look.dynamic_range_db,
            gamma=look.gamma,
            tvg_residual_db=look.tvg_residual_db,
            gain_jitter_db=look.gain_jitter_db,
            compression=look.compression,
            speckle_shape=look.speckle_shape,
            speckle_corr_beams=look.speckle_corr_beams,
            speckle_corr_bins=look.speckle_corr_bins,
            side_lobe_db=look.side_lobe_db,
            ringdown_m=look.ringdown_m,
            ringdown_db=look.ringdown_db,
            rov_reflectivity=look.rov_reflectivity,
            rov_glint=look.rov_glint,
            rov_interior=look.rov_interior,
            rov_exponent=look.rov_exponent,
            fish=look.fish,
        )

    @property
    def fixed_look(self) -> bool:
        """No look knob moved from the fixed look: the renderer keeps its original path."""
        return all(getattr(self, name) == getattr(_FIXED, name) for name in _LOOK_ONLY)

    @property
    def range_resolution_m(self) -> float:
        return self.range_max_m / self.n_ranges

    def azimuths(self) -> Array:
        """Beam azimuths (port positive), evenly spaced in sin(theta) like the Oculus table."""
        s = math.sin(self.half_fov_rad)
        return np.arcsin(np.linspace(-s, s, self.n_beams))


@dataclass(frozen=True)
class Label:
    """The truth of one ping: where the ROV is in the polar image, and how visible."""

    visible: bool  # inside the fan and at least one ray hit it
    range_m: float
    azimuth_rad: float
    elevation_rad: float
    range_min_m: float
    range_max_m: float
    azimuth_min_rad: float
    azimuth_max_rad: float
    rov_rays: int
    overlap: bool  # other echoes inside the ROV's footprint (the paper's failure case)
    ghosts: tuple[tuple[float, float], ...]  # (range, azimuth) of multipath ghosts in the fan

    def as_reported(self, sound_speed_scale: float) -> Label:
        """Ranges as a sonar reports them that assumes a speed `sound_speed_scale` x too slow.

        A label describes the image: where the ROV's echo lies in it, in the sonar's own range
        units (what a detector, a person drawing boxes, or training sees).
        """
        if sound_speed_scale == 1.0:
            return self
        k = 1.0 / sound_speed_scale
        return replace(
            self,
            range_m=self.range_m * k,
            range_min_m=self.range_min_m * k,
            range_max_m=self.range_max_m * k,
            ghosts=tuple((r * k, a) for r, a in self.ghosts),
        )


@dataclass(frozen=True)
class Ping:
    image: Array  # uint8, n_ranges x n_beams
    label: Label


def _beam_kernel(side_lobe_db: float) -> Array:
    taps = np.arange(-10, 11, dtype=np.float64)
    main = np.exp(-0.5 * (taps / 0.7) ** 2)
    level = 10.0 ** (side_lobe_db / 10.0)
    side = np.where(np.abs(taps) >= 3, level * (np.abs(np.sinc(taps / 3.0)) + 0.3), 0.0)
    kernel = main + side
    return np.asarray(kernel / kernel.sum(), dtype=np.float32)


def _range_kernel() -> Array:
    taps = np.arange(-3, 4, dtype=np.float64)
    kernel = np.exp(-0.5 * (taps / 1.0) ** 2)
    return np.asarray(kernel / kernel.sum(), dtype=np.float32)


class SonarRenderer:
    """Renders pings for one sonar model in one tank."""

    def __init__(self, model: SonarModel, tank: Tank):
        self.model = model
        self.tank = tank
        self.azimuths = model.azimuths()
        self._azimuth_tuple = tuple(float(a) for a in self.azimuths)  # the same every ping
        half = model.vertical_aperture_rad / 2.0
        # Rays reach a little past the nominal aperture: the vertical pattern has skirts.
        self._elev_edges = np.linspace(-1.3 * half, 1.3 * half, model.elevation_rays + 1)
        self._beam_kernel = _beam_kernel(model.side_lobe_db)
        self._range_kernel = _range_kernel()
        ranges = (np.arange(model.n_ranges) + 0.5) * model.range_resolution_m
        noise = model.noise_level * (1.0 + model.noise_growth * ranges / model.range_max_m)
        self._noise_profile = noise.astype(np.float32)[:, None]
        # Exponential draws are the costliest step: a pool twice the image, read at a random
        # offset per ping, is as random to the eye and to a detector.
        levels = np.linspace(0.0, 1.0, 4096)
        self._gamma_lut = np.asarray(levels**model.gamma * 255.0 + 0.5, dtype=np.uint8)
        pool_rng = np.random.default_rng(7)
        self._pool = pool_rng.standard_exponential(
            2 * model.n_ranges * model.n_beams, dtype=np.float32
        )
        look_rng = np.random.default_rng(
            [7, round(model.ringdown_m * 1e6), round(model.speckle_corr_beams * 1e6)]
        )
        self._look = None if model.fixed_look else _LookFields(model, ranges, look_rng)

    def _directions(self, azimuths: Array, elevations: Array) -> Array:
        """Unit vectors in S for rays at these azimuths and elevations: N x 3."""
        ct, st = np.cos(azimuths), np.sin(azimuths)
        ce, se = np.cos(elevations), np.sin(elevations)
        if self.model.beam_model == "planar":
            return np.stack([ce * ct, ce * st, se], axis=-1)
        return np.stack([ct * ce, st, ct * se], axis=-1)

    def _rays(
        self, sonar_pose: Transform, rov: Ellipsoid | None, rng: np.random.Generator
    ) -> tuple[IndexArray, Array, Array]:
        """Each ray's beam, elevation and weight (the share of its beam's stratum it stands for).

        Every beam casts `elevation_rays` rays, one per stratum of the aperture (jittered per
        ping, so that over pings the floor and walls fill in continuously instead of in
        stripes). The beams that may see the ROV cast k times as many over the same strata,
        each of weight 1/k, k chosen so that a ray's slab is at most an eighth of the ROV's
        height at its distance: a stratum is 1.6 deg, 0.45 m at 16 m, taller than the ROV, so
        one ray a beam would hit it or not by chance and put all its echo in one bin (a far ROV
        a scatter of random dots, not the compact echo of its front a sonar sees).
        """
        m = self.model
        n_b, n_e = m.n_beams, m.elevation_rays
        fine = np.ones(n_b, dtype=np.int64)
        if rov is not None:
            distance, azimuth, _ = to_polar(m.beam_model, sonar_pose.inverse().apply(rov.centre))
            stratum = float(self._elev_edges[1] - self._elev_edges[0])
            height = 2.0 * float(rov.semi_axes.min())
            k = math.ceil(SLABS_PER_ROV_HEIGHT * stratum * distance / height)
            k = min(max(k, 1), MAX_RAYS_FACTOR)
            if k > 1:
                reach = math.asin(min(1.0, 1.2 * float(rov.semi_axes.max()) / distance))
                spacing = 2.0 * m.half_fov_rad / max(n_b - 1, 1)
                near = np.abs(self.azimuths - azimuth) <= reach + 2.0 * spacing
                fine[near] = k
        counts = fine * n_e
        beams = np.repeat(np.arange(n_b), counts)
        # The ray's stratum within its beam: rays 0..k*n_e-1 over n_e strata split k ways.
        first = np.cumsum(counts) - counts
        slot = np.arange(len(beams)) - np.repeat(first, counts)
        per_beam = np.repeat(fine, counts)
        edges = self._elev_edges
        lo_all, span = float(edges[0]), float(edges[-1] - edges[0])
        elevations = lo_all + span * (slot + rng.random(len(beams))) / (n_e * per_beam)
        return beams, elevations, 1.0 / per_beam

    def render(
        self, sonar_pose: Transform, rov: Ellipsoid | None, rng: np.random.Generator
    ) -> Ping:
        m = self.model
        n_e = m.elevation_rays
        beams, elevations, ray_weight = self._rays(sonar_pose, rov, rng)
        dirs_s = self._directions(self.azimuths[beams], elevations)
        dirs_w = dirs_s @ sonar_pose.rotation.T
        hits = scene.cast(sonar_pose.translation, dirs_w, self.tank, rov=rov)
        half = m.vertical_aperture_rad / 2.0
        weight_e = ray_weight * np.exp(-math.log(2.0) * (elevations / half) ** 2)
        cos_inc = np.abs(np.einsum("ij,ij->i", hits.normal, -dirs_w))
        exponent = np.where(hits.label == scene.ROV, m.rov_exponent, m.incidence_exponent)
        reflectivity, distance = hits.reflectivity, hits.distance
        if self._look is not None:
            reflectivity, distance = self._look.rov_detail(hits, rng)
        in_range = np.isfinite(distance) & (distance < m.range_max_m)
        echo = (
            reflectivity
            * cos_inc**exponent
            * weight_e
            * 10.0 ** (-2.0 * m.absorption_db_per_m * np.where(in_range, distance, 0.0) / 10.0)
        )
        # Each stratum stands for a slab of elevations: spread its echo over the bins it spans.
        bins = np.where(in_range, distance / m.range_resolution_m, -1.0)
        image = self._accumulate(bins, beams, np.where(in_range, echo, 0.0), rng)
        if self._look is not None:
            self._look.add_fish(image, rng)
        label = self._label(sonar_pose, rov, hits, bins, beams, echo, in_range)
        if rov is not None:
            for ghost_range, ghost_az, ghost_weight in self._ghosts(sonar_pose, rov):
                self._splat(image, ghost_range, ghost_az, ghost_weight * m.ghost_gain * n_e / 4)
        return Ping(self._finish(image, rng), label)

    def _accumulate(
        self, bins: Array, beams: IndexArray, echo: Array, rng: np.random.Generator
    ) -> Array:
        m = self.model
        valid = bins >= 0.0
        # A pulse is ~2 bins long: place each echo with sub-bin jitter.
        b = np.clip(
            (bins[valid] + rng.normal(0.0, 0.5, int(valid.sum()))).astype(np.int64),
            0,
            m.n_ranges - 1,
        )
        flat = b * m.n_beams + beams[valid]
        image = np.bincount(flat, weights=echo[valid], minlength=m.n_ranges * m.n_beams)
        return image.reshape(m.n_ranges, m.n_beams).astype(np.float32)

    def _splat(self, image: Array, range_m: float, azimuth: float, weight: float) -> None:
        m = self.model
        i = int(range_m / m.range_resolution_m)
        j = int(np.argmin(np.abs(self.azimuths - azimuth)))
        if 0 <= i < m.n_ranges - 3 and 0 <= j < m.n_beams:
            image[i : i + 3, max(j - 1, 0) : j + 2] += weight

    def _ghosts(self, sonar_pose: Transform, rov: Ellipsoid) -> list[tuple[float, float, float]]:
        """Multipath images of the ROV: via the water surface and via the nearest wall."""
        m = self.model
        s = sonar_pose.translation
        p = rov.centre
        mirrors = [np.array([p[0], p[1], -p[2]])]  # the surface, z = 0
        walls = [(0, 0.0), (0, self.tank.length_m), (1, 0.0), (1, self.tank.width_m)]
        axis, plane = min(walls, key=lambda w: abs(p[w[0]] - w[1]))
        mirror = p.copy()
        mirror[axis] = 2 * plane - p[axis]
        mirrors.append(mirror)
        out = []
        to_sonar = sonar_pose.inverse()
        direct = float(np.linalg.norm(p - s))
        for image_point in mirrors:
            bounce = float(np.linalg.norm(image_point - s))
            _, azimuth, elevation = to_polar(m.beam_model, to_sonar.apply(image_point))
            if abs(azimuth) > m.half_fov_rad:
                continue
            weight = math.exp(-math.log(2.0) * (elevation / (m.vertical_aperture_rad / 2)) ** 2)
            if weight > 0.05:
                out.append(((direct + bounce) / 2.0, azimuth, weight))
        return out

    def _finish(self, image: Array, rng: np.random.Generator) -> Array:
        m = self.model
        blurred = np.asarray(
            cv2.sepFilter2D(
                image,
                cv2.CV_32F,
                self._beam_kernel,
                self._range_kernel,
                borderType=cv2.BORDER_CONSTANT,
            ),
            dtype=np.float32,
        )
        size = blurred.size
        a, b = rng.integers(0, size, 2)
        speckle = self._pool[a : a + size].reshape(blurred.shape)
        grain = self._pool[b : b + size].reshape(blurred.shape)
        gain_db = (m.gain_percent - 50.0) * 0.4
        if self._look is not None:
            blurred, speckle = self._look.before_speckle(blurred, rng)
            gain_db += self._look.gain_jitter(rng)
        intensity = blurred * speckle + self._noise_profile * grain + np.float32(1e-12)
        if m.compression == "linear":
            # Amplitude, not dB: the top echo white, the gamma curve alone shapes the rest.
            level = intensity * np.float32(10.0 ** (gain_db / 10.0) / 0.5)
            scaled = np.sqrt(level)
            np.clip(scaled, 0.0, 1.0, out=scaled)
            return np.asarray(np.take(self._gamma_lut, (scaled * 4095.0).astype(np.int32)))
        top = 10.0 * math.log10(0.5)  # a near, square-on ROV return sits at the top
        low = top - m.dynamic_range_db - gain_db
        # dB = 10 log10(I); scaled = (dB - low) / range, in float32 through OpenCV (fast).
        scaled = cv2.log(intensity) * np.float32(10.0 / math.log(10.0) / m.dynamic_range_db)
        scaled -= np.float32(low / m.dynamic_range_db)
        np.clip(scaled, 0.0, 1.0, out=scaled)
        # Gamma through a 4096-entry table: a float power per pixel costs ~6 ms a ping.
        return np.take(self._gamma_lut, (scaled * 4095.0).astype(np.int32))

    def _label(
        self,
        sonar_pose: Transform,
        rov: Ellipsoid | None,
        hits: scene.Hits,
        bins: Array,
        beams: IndexArray,
        echo: Array,
        in_range: MaskArray,
    ) -> Label:
        m = self.model
        nan = float("nan")
        if rov is None:
            return Label(False, nan, nan, nan, nan, nan, nan, nan, 0, False, ())
        r, azimuth, elevation = to_polar(m.beam_model, sonar_pose.inverse().apply(rov.centre))
        on_rov = (hits.label == scene.ROV) & in_range
        count = int(on_rov.sum())
        inside = abs(azimuth) <= m.half_fov_rad and r < m.range_max_m
        ghosts = tuple((g[0], g[1]) for g in self._ghosts(sonar_pose, rov))
        if count == 0 or not inside:
            return Label(False, r, azimuth, elevation, nan, nan, nan, nan, count, False, ghosts)
        res = m.range_resolution_m
        rov_bins, rov_beams = bins[on_rov], beams[on_rov]
        b0, b1 = float(rov_bins.min()), float(rov_bins.max())
        j0, j1 = int(rov_beams.min()), int(rov_beams.max())
        # Overlap: other echoes inside the ROV's footprint carry a fair share of its energy.
        other = (
            ~on_rov
            & in_range
            & (bins >= b0 - 2)
            & (bins <= b1 + 2)
            & (beams >= j0 - 1)
            & (beams <= j1 + 1)
        )
        overlap = bool(echo[other].sum() > 0.3 * echo[on_rov].sum())
        return Label(
            True,
            r,
            azimuth,
            elevation,
            b0 * res,
            (b1 + 1) * res,
            float(self.azimuths[j0]),
            float(self.azimuths[j1]),
            count,
            overlap,
            ghosts,
        )

    def frame(self, ping: Ping, *, stamp_ns: int, seq: int, ping_id: int) -> SonarFrame:
        """The bus payload of a rendered ping (what a real driver would publish)."""
        m = self.model
        return SonarFrame(
            stamp_ns=stamp_ns,
            seq=seq,
            ping_id=ping_id,
            n_ranges=m.n_ranges,
            n_beams=m.n_beams,
            sample_bits=8,
            image=memoryview(ping.image.tobytes()),
            azimuths_rad=self._azimuth_tuple,
            range_start_m=0.0,
            range_resolution_m=m.range_resolution_m,
            sound_speed_m_s=m.sound_speed_m_s,
            gain_percent=m.gain_percent,
            frequency_hz=m.frequency_hz,
            vertical_aperture_rad=m.vertical_aperture_rad,
        )


_FIXED = SonarModel()
# The fields that only shape the look (geometry, gain and noise level are the sonar's own).
_LOOK_ONLY = (
    "tvg_residual_db",
    "gain_jitter_db",
    "compression",
    "speckle_shape",
    "speckle_corr_beams",
    "speckle_corr_bins",
    "ringdown_m",
    "rov_reflectivity",
    "rov_glint",
    "rov_interior",
    "fish",
)
F32 = npt.NDArray[np.float32]
INTERIOR_DEPTH_M = 0.45  # how far behind its front face the open frame's inside echoes


class _LookFields:
    """Per-run fields of a varied look: correlated textured speckle, TVG residual, ring-down."""

    def __init__(
        self, model: SonarModel, ranges: npt.NDArray[np.floating[Any]], rng: np.random.Generator
    ):
        self.model = model
        rows, cols = 2 * model.n_ranges, model.n_beams
        # Correlated speckle: a complex Gaussian field blurred over beams and bins, |.|^2.
        re = rng.standard_normal((rows, cols), dtype=np.float32)
        im = rng.standard_normal((rows, cols), dtype=np.float32)
        sx, sy = model.speckle_corr_beams, model.speckle_corr_bins
        if sx > 0.05 or sy > 0.05:
            ksize = (2 * math.ceil(3 * max(sx, 0.3)) + 1, 2 * math.ceil(3 * max(sy, 0.3)) + 1)
            gx, gy = max(sx, 0.3), max(sy, 0.3)
            re = np.asarray(cv2.GaussianBlur(re, ksize, gx, sigmaY=gy), dtype=np.float32)
            im = np.asarray(cv2.GaussianBlur(im, ksize, gx, sigmaY=gy), dtype=np.float32)
        speckle = re * re + im * im
        if math.isfinite(model.speckle_shape):
            # K-distribution: a gamma-distributed texture (mean 1) under the speckle, varying
            # over a few cells: spiky, heavy-tailed returns from rough or patchy scatterers.
            nu = model.speckle_shape
            coarse = rng.gamma(nu, 1.0 / nu, ((rows + 3) // 4, (cols + 1) // 2))
            texture = cv2.resize(
                coarse.astype(np.float32), (cols, rows), interpolation=cv2.INTER_LINEAR
            )
            speckle *= texture
        speckle /= np.float32(max(float(speckle.mean()), 1e-12))
        self.speckle_pool = speckle
        r_ref = model.range_max_m / 2.0
        tvg = (np.maximum(ranges, 0.05) / r_ref) ** (model.tvg_residual_db / 10.0)
        self.tvg = tvg.astype(np.float32)[:, None]
        ring = np.zeros((0, cols), dtype=np.float32)
        if model.ringdown_m > 0.0:
            # The transducer rings after transmit: bright at the apex, 30 dB down at
            # `ringdown_m`, gone (90 dB down) at three times that; uneven across beams.
            depth = ranges[ranges < 3.0 * model.ringdown_m]
            stripes = rng.uniform(0.5, 1.5, cols).astype(np.float32)
            level = 0.5 * 10.0 ** (model.ringdown_db / 10.0)
            fall = level * 10.0 ** (-3.0 * depth / model.ringdown_m)
            ring = fall.astype(np.float32)[:, None] * stripes
        self.ring = ring

    def rov_detail(self, hits: scene.Hits, rng: np.random.Generator) -> tuple[Array, Array]:
        """Reflectivity and distance per ray with the ROV's glints and open-frame echoes."""
        m = self.model
        on_rov = hits.label == scene.ROV
        n = int(on_rov.sum())
        reflectivity = hits.reflectivity.copy()
        distance = hits.distance.copy()
        if n:
            gain = m.rov_reflectivity * np.exp(rng.normal(0.0, m.rov_glint, n) - m.rov_glint**2)
            reflectivity[on_rov] *= gain
            inside = rng.random(n) < m.rov_interior
            distance[np.flatnonzero(on_rov)[inside]] += rng.uniform(
                0.0, INTERIOR_DEPTH_M, int(inside.sum())
            )
        return reflectivity, distance

    def add_fish(self, image: Array, rng: np.random.Generator) -> None:
        m = self.model
        for _ in range(m.fish):
            i = int(rng.integers(0, m.n_ranges - 3))
            j = int(rng.integers(1, m.n_beams - 1))
            image[i : i + 2, j - 1 : j + 1] += m.elevation_rays / 4 * rng.uniform(0.02, 0.3)

    def before_speckle(self, blurred: F32, rng: np.random.Generator) -> tuple[F32, F32]:
        """The echo after TVG's residual and ring-down, and this ping's speckle."""
        out = np.multiply(blurred, self.tvg, dtype=np.float32)
        if len(self.ring):
            out[: len(self.ring)] += self.ring
        start = int(rng.integers(0, self.model.n_ranges))
        return out, self.speckle_pool[start : start + self.model.n_ranges]

    def gain_jitter(self, rng: np.random.Generator) -> float:
        jitter = self.model.gain_jitter_db
        return float(rng.normal(0.0, jitter)) if jitter > 0.0 else 0.0
