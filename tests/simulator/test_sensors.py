"""Every simulated sensor against hand-computed cases."""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import msgspec
import numpy as np
import pytest

from capsd.geometry import Transform, euler_zyx_to_matrix
from capsd.payloads import GroundTruth, ImuSample, LidarScan, RovDepth, SonarFrame, SonarLabel
from capsd.simulator import dataset
from capsd.simulator.config import ClockConfig, Clocks, Config, Noise, Streams, WavesConfig
from capsd.simulator.imu import Imu, ImuModel
from capsd.simulator.install_errors import InstallErrorsConfig
from capsd.simulator.lidar import LidarModel, scan
from capsd.simulator.scene import BLUEROV2_SEMI_AXES, Ellipsoid
from capsd.simulator.sim import Simulation
from capsd.simulator.sonar import SonarModel, SonarRenderer
from capsd.simulator.world import GRAVITY, TRAJECTORIES, make_tank, rov_motion

START_NS = 1_767_225_600_000_000_000


def _level_sonar(x: float, y: float, z: float, yaw: float = 0.0, pitch: float = 0.0) -> Transform:
    return Transform(euler_zyx_to_matrix(yaw, pitch, 0.0), np.array([x, y, z]))


def test_wall_at_known_range_appears_at_the_right_bin() -> None:
    tank = make_tank("nfp", clutter="off")
    model = SonarModel(range_max_m=10.0, n_ranges=500, noise_level=0.0)  # 2 cm bins
    renderer = SonarRenderer(model, tank)
    # Level sonar 6 m from the far wall (x = 28), looking straight at it, mid-depth.
    ping = renderer.render(_level_sonar(22.0, 8.0, -4.0), None, np.random.default_rng(1))
    centre = np.argsort(np.abs(renderer.azimuths))[:16]  # the beams around the boresight
    profile = ping.image[:, centre].astype(np.float64).mean(axis=1)
    expected_bin = 6.0 / model.range_resolution_m
    assert abs(int(np.argmax(profile)) - expected_bin) <= 2
    # Off-boresight beams see the same wall further away: range = 6 / cos(azimuth).
    j = int(np.argmin(np.abs(renderer.azimuths - math.radians(40.0))))
    side = ping.image[:, j - 2 : j + 3].astype(np.float64).mean(axis=1)
    expected_side = 6.0 / math.cos(renderer.azimuths[j]) / model.range_resolution_m
    assert abs(int(np.argmax(side)) - expected_side) <= 3


def test_rov_appears_where_its_label_says() -> None:
    tank = make_tank("nfp", clutter="off")
    model = SonarModel(range_max_m=12.0, n_ranges=600, noise_level=0.0)
    renderer = SonarRenderer(model, tank)
    sonar = _level_sonar(8.0, 8.0, -0.2, yaw=0.0, pitch=math.radians(30.0))
    # On the boresight 5 m out, 0.2 rad to port.
    direction = sonar.rotation @ np.array([math.cos(0.2), math.sin(0.2), 0.0])
    rov = Ellipsoid(sonar.translation + 5.0 * direction, np.eye(3), BLUEROV2_SEMI_AXES)
    ping = renderer.render(sonar, rov, np.random.default_rng(2))
    label = ping.label
    assert label.visible
    assert label.range_m == pytest.approx(5.0, abs=1e-9)
    assert label.azimuth_rad == pytest.approx(0.2, abs=1e-9)
    res = model.range_resolution_m
    image = ping.image.astype(np.float64)
    # Look for the ROV's echo near its true position; the floor (8 m down) is far behind it.
    window = image[int(4.0 / res) : int(6.0 / res)]
    i, j = np.unravel_index(int(np.argmax(window)), window.shape)
    peak_range = (i + int(4.0 / res)) * res
    assert label.range_min_m is not None
    assert label.range_max_m is not None
    assert label.range_min_m - 2 * res <= peak_range <= label.range_max_m + 2 * res
    # Intensity-weighted azimuth of the echo rows: within one beam of the truth.
    rows = window[max(i - 5, 0) : i + 6]
    weights = np.clip(rows - np.median(window), 0.0, None).sum(axis=0)
    centroid = float((weights * renderer.azimuths).sum() / weights.sum())
    beam_width = float(np.median(np.diff(renderer.azimuths)))
    assert abs(centroid - 0.2) <= 1.0 * beam_width * 3  # blur and speckle: about a beam
    # The brightest sample lies on the ROV (5 m off it spans about 29 beams).
    assert label.azimuth_min_rad is not None
    assert label.azimuth_max_rad is not None
    assert label.azimuth_min_rad - beam_width <= renderer.azimuths[j]
    assert renderer.azimuths[j] <= label.azimuth_max_rad + beam_width


def test_a_far_rov_is_lit_by_several_rays_in_every_beam_it_spans() -> None:
    # 16 m off, a 0.25 m tall ROV spans 0.9 deg of elevation; one ray a 1.6 deg stratum
    # would hit it in about half its beams, each echo in one bin, a scatter of dots.
    tank = make_tank("nfp", clutter="off")
    model = SonarModel(noise_level=0.0)
    renderer = SonarRenderer(model, tank)
    sonar = _level_sonar(4.0, 8.0, -0.2, yaw=0.0, pitch=math.radians(12.0))
    direction = sonar.rotation @ np.array([1.0, 0.0, 0.0])
    rov = Ellipsoid(sonar.translation + 16.0 * direction, np.eye(3), BLUEROV2_SEMI_AXES)
    for seed in range(5):
        label = renderer.render(sonar, rov, np.random.default_rng(seed)).label
        assert label.visible
        assert label.azimuth_min_rad is not None
        assert label.azimuth_max_rad is not None
        beams = np.count_nonzero(
            (renderer.azimuths >= label.azimuth_min_rad)
            & (renderer.azimuths <= label.azimuth_max_rad)
        )
        assert beams >= 6  # 0.58 m wide: about 8 beams of 0.25 deg
        assert label.rov_rays >= 4 * beams


def test_bearings_are_evenly_spaced_in_sine() -> None:
    azimuths = SonarModel().azimuths()
    assert len(azimuths) == 512
    assert np.allclose(np.diff(np.sin(azimuths)), np.diff(np.sin(azimuths))[0])
    assert math.degrees(azimuths[-1]) == pytest.approx(65.0)
    spacing = np.diff(np.degrees(azimuths))
    assert spacing[0] > spacing[255]  # wider at the edges, as the real table


def test_lidar_sees_the_wall_above_water_and_nothing_below() -> None:
    tank = make_tank("nfp", clutter="off")
    model = LidarModel(sigma_m=0.0, dropout=0.0)
    # Level scanner 0.4 m above the water, 5 m from the x = 28 wall, facing it.
    ranges = scan(model, _level_sonar(23.0, 8.0, 0.4), tank, np.random.default_rng(0))
    ahead = int(np.argmin(np.abs(model.angles())))
    assert ranges[ahead] == pytest.approx(5.0, abs=1e-9)
    left = int(np.argmin(np.abs(model.angles() - math.pi / 2)))
    assert ranges[left] == pytest.approx(8.0, abs=1e-9)  # the y = 16 wall
    # Tilted 20 deg nose down: the beam meets the wall below the water line: no return.
    tilted = scan(
        model,
        _level_sonar(23.0, 8.0, 0.4, pitch=math.radians(20.0)),
        tank,
        np.random.default_rng(0),
    )
    assert tilted[ahead] == 0.0


def test_imu_static_and_rolling() -> None:
    imu = Imu(
        ImuModel(
            gyro_sigma_rad_s=0.0,
            accel_sigma_m_s2=0.0,
            gyro_bias_sigma_rad_s=0.0,
            accel_bias_sigma_m_s2=0.0,
        ),
        np.eye(3),
        np.random.default_rng(0),
    )
    gyro, accel = imu.sample(1.0, lambda _t: np.eye(3), np.zeros(3), np.random.default_rng(0))
    assert np.allclose(gyro, 0.0)
    assert np.allclose(accel, [0.0, 0.0, GRAVITY])

    # Rolling at 0.1 rad/s about x: gyro x = 0.1, gravity tilts into the body y/z axes.
    def rolling(t: float) -> np.ndarray:
        return euler_zyx_to_matrix(0.0, 0.0, 0.1 * t)

    gyro, accel = imu.sample(2.0, rolling, np.zeros(3), np.random.default_rng(0))
    assert gyro == pytest.approx([0.1, 0.0, 0.0], abs=1e-6)
    assert accel == pytest.approx([0.0, GRAVITY * math.sin(0.2), GRAVITY * math.cos(0.2)], abs=1e-6)
    # A mounting rotation turns the same motion into the IMU's axes (here: 90 deg about z).
    mounted = Imu(imu.model, euler_zyx_to_matrix(math.pi / 2, 0.0, 0.0).T, np.random.default_rng(0))
    gyro_m, _ = mounted.sample(2.0, rolling, np.zeros(3), np.random.default_rng(0))
    assert gyro_m == pytest.approx([0.0, -0.1, 0.0], abs=1e-6)


def _quiet(**changes: object) -> Config:
    base = Config(
        noise=Noise(pose_sigma_m=0.0, range_sigma_m=0.0, azimuth_sigma_deg=0.0, depth_sigma_m=0.0),
        streams=Streams(sonar_frames="off", lidar="off", imu="on"),
        install_errors=InstallErrorsConfig(mode="off"),
    )
    return msgspec.structs.replace(base, **changes)


def test_depth_lever_arm_as_documented() -> None:
    sim = Simulation(_quiet(trajectory="two_floor"), horizon_s=420)
    checked = 0
    for event in sim.events(start_ns=START_NS, duration_s=30):
        if isinstance(event.payload, RovDepth):
            rov = sim.rov_state(event.t_s)
            sensor_z = rov.position_m[2] + (rov.rotation @ np.array([-0.2, 0.0, 0.0]))[2]
            assert event.payload.depth_m == pytest.approx(-sensor_z, abs=1e-12)
            checked += 1
    assert checked > 250
    # Pitch does move the tail sensor: in two_floor's descent the lever arm shows (cm).
    offsets = []
    for t in np.arange(0.0, 400.0, 0.1):
        rov = sim.rov_state(float(t))
        offsets.append(abs((rov.rotation @ np.array([-0.2, 0.0, 0.0]))[2]))
    assert max(offsets) > 0.015


def test_clock_offsets_appear_in_stamps() -> None:
    clocks = Clocks(asv=ClockConfig(offset_s=0.5), rov=ClockConfig(offset_s=-0.25, drift_ppm=100.0))
    sim = Simulation(_quiet(clocks=clocks), horizon_s=20)
    seen = set()
    for event in sim.events(start_ns=START_NS, duration_s=10):
        true_ns = START_NS + round(event.t_s * 1e9)
        p = event.payload
        if isinstance(p, ImuSample):
            assert p.stamp_ns - true_ns == 500_000_000
            seen.add("imu")
        elif isinstance(p, RovDepth):
            drift = round(100e-6 * event.t_s * 1e9)
            assert p.stamp_ns - true_ns == pytest.approx(-250_000_000 + drift, abs=1)
            seen.add("depth")
        elif isinstance(p, GroundTruth):
            assert p.stamp_ns == true_ns  # truth is at true time
            seen.add("truth")
        elif isinstance(p, SonarLabel):
            assert p.stamp_ns - true_ns == 500_000_000  # the frame's (ASV) stamp
            seen.add("label")
    assert seen == {"imu", "depth", "truth", "label"}


@pytest.mark.parametrize("name", TRAJECTORIES)
def test_trajectories_stay_in_the_tank_at_realistic_speed(name: str) -> None:
    tank = make_tank("nfp")
    motion = rov_motion(tank, name, speed_m_s=0.5, duration_s=300.0, seed=4)  # type: ignore[arg-type]
    p, v = motion.track.p, motion.track.v
    assert np.linalg.norm(v, axis=1).max() <= 0.5 + 1e-9
    assert p[:, 0].min() > 0.5
    assert p[:, 0].max() < tank.length_m - 0.5
    assert p[:, 1].min() > 0.5
    assert p[:, 1].max() < tank.width_m - 0.5
    assert (p[:, 2] < -0.5).all()
    assert (p[:, 2] > -tank.depth_m + 1.0).all()
    tilt = [
        abs(math.degrees(math.asin(-motion.state(float(t)).rotation[2, 0])))
        for t in np.arange(0.0, 300.0, 0.5)
    ]
    assert max(tilt) < 15.0


def test_offline_dataset_is_deterministic(tmp_path: Path) -> None:
    config = Config(seed=5, waves=WavesConfig(roll_deg=2.0))

    def digest(directory: Path, cfg: Config) -> str:
        dataset.write(directory, cfg, duration_s=2.0, progress=False)
        data = (directory / "events.bin").read_bytes() + (directory / "dataset.json").read_bytes()
        return hashlib.sha256(data).hexdigest()

    first = digest(tmp_path / "a", config)
    assert digest(tmp_path / "b", config) == first
    assert digest(tmp_path / "c", msgspec.structs.replace(config, seed=6)) != first
    records = list(dataset.read(tmp_path / "a"))
    frames = [r.payload for r in records if isinstance(r.payload, SonarFrame)]
    assert len(frames) == 41  # 20 Hz for 2 s, both ends included
    assert frames[0].n_beams == 512
    scans = [r.payload for r in records if isinstance(r.payload, LidarScan)]
    assert len(scans[0].ranges_m) == 811
