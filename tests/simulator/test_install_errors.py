"""Installation errors: drawn per run, unknown to the services, felt by the fixes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from capsd.geometry import matrix_to_euler_zyx, quat_to_matrix
from capsd.offline_pipeline import ablations, run
from capsd.payloads import RovAttitude, RovDepth, SonarFrame
from capsd.simulator.config import OFFLINE_START_NS, Config
from capsd.simulator.install_errors import InstallErrors, InstallErrorsConfig
from capsd.simulator.sim import Simulation
from capsd.simulator.world import TankName, make_tank, profile_distances_m
from capsd.sonar_geometry import to_polar
from capsd.sound_speed import speed_of_sound_m_s

REALISTIC = InstallErrorsConfig(mode="realistic")
OFF = InstallErrorsConfig(mode="off")


def test_realistic_is_the_default() -> None:
    assert Config().install_errors.mode == "realistic"
    assert Simulation(Config(seed=4), horizon_s=20).errors.sound_speed_scale != 1.0


def test_off_leaves_the_world_at_its_nominal_mounts() -> None:
    sim = Simulation(Config(seed=4, install_errors=OFF), horizon_s=20)
    assert np.allclose(sim.mount.rotation, Config().sonar.transform().rotation)
    assert np.allclose(sim.mount.translation, Config().sonar.transform().translation)
    assert sim.errors.sound_speed_scale == 1.0


def test_errors_are_drawn_per_seed_at_their_documented_size() -> None:
    draws = [InstallErrors.draw(REALISTIC, np.random.default_rng(s)).summary() for s in range(400)]
    again = InstallErrors.draw(REALISTIC, np.random.default_rng(7)).summary()
    assert again == draws[7]
    assert draws[0] != draws[1]
    yaw = np.array([d["sonar_yaw_deg"] for d in draws])
    assert 0.55 < yaw.std() < 0.85  # 0.7 deg
    heading = np.array([d["rov_heading_error_deg"] for d in draws])
    assert 1.7 < heading.std() < 2.3
    ppm = np.array([d["sound_speed_ppm"] for d in draws])
    assert 2500 < ppm.std() < 3500
    thermometer = np.array([d["rov_thermometer_bias_c"] for d in draws])
    assert 0.4 < thermometer.std() < 0.6


def test_the_sensors_report_what_an_installation_with_errors_would() -> None:
    sim = Simulation(Config(seed=11, install_errors=REALISTIC), horizon_s=20)
    nominal = Simulation(Config(seed=11, install_errors=OFF), horizon_s=20)
    scale = sim.errors.sound_speed_scale
    frames = depths = attitudes = 0
    for event, plain in zip(
        sim.events(start_ns=OFFLINE_START_NS, duration_s=2.0),
        nominal.events(start_ns=OFFLINE_START_NS, duration_s=2.0),
        strict=True,
    ):
        p, q = event.payload, plain.payload
        if isinstance(p, SonarFrame) and isinstance(q, SonarFrame):
            assert p.range_resolution_m == pytest.approx(q.range_resolution_m / scale)
            # The speed it assumed, reported with the frame; the water's when nothing is off.
            assert q.sound_speed_m_s is not None
            assert q.sound_speed_m_s == pytest.approx(speed_of_sound_m_s(24.0, salinity_ppt=0.0))
            assert p.sound_speed_m_s == pytest.approx(q.sound_speed_m_s / scale)
            frames += 1
        elif isinstance(p, RovDepth) and isinstance(q, RovDepth):
            assert abs(round(p.depth_m / 0.002) * 0.002 - p.depth_m) < 1e-9  # quantised
            # Bias, plus the pressure port's misplacement along the vertical, plus rounding.
            arm_m = float(np.linalg.norm(sim.errors.pressure_arm_m))
            assert abs(p.depth_m - q.depth_m - sim.errors.depth_bias_m) < arm_m + 0.002
            # The water's temperature as the ROV's thermometer reads it, in centi-degrees.
            assert q.temperature_c == 24.0
            assert p.temperature_c == pytest.approx(
                24.0 + sim.errors.rov_thermometer_bias_c, abs=0.006
            )
            depths += 1
        elif isinstance(p, RovAttitude) and isinstance(q, RovAttitude):
            yaw_p = matrix_to_euler_zyx(quat_to_matrix(np.array(p.orientation_xyzw)))[0]
            yaw_q = matrix_to_euler_zyx(quat_to_matrix(np.array(q.orientation_xyzw)))[0]
            off = math.remainder(yaw_p - yaw_q - sim.errors.heading_error_rad, math.tau)
            assert abs(off) < math.radians(1.5)
            attitudes += 1
    assert frames > 10
    assert depths > 5
    assert attitudes > 10


def test_an_uncalibrated_installation_costs_accuracy() -> None:
    variants = [v for v in ablations() if v.name == "ours - polar CNN (box centre)"]
    config = Config(tank="nfp", trajectory="square", seed=5, install_errors=OFF)
    off = run(config, duration_s=6.0, variants=variants)
    errors = Config(tank="nfp", trajectory="square", seed=5, install_errors=REALISTIC)
    on = run(errors, duration_s=6.0, variants=variants)
    name = variants[0].name
    drawn = Simulation(errors, horizon_s=10).errors.summary()
    # The sonar's heading error alone moves a fix by about range x angle (8 m x 1 deg = 14 cm).
    assert on[name].summary()["med_mm"] > off[name].summary()["med_mm"] + 10.0, drawn


def test_the_calibration_manoeuvre_turns_the_asv_on_the_spot() -> None:
    sim = Simulation(Config(asv_mode="spin", seed=2), horizon_s=80)
    start, later = sim.asv_pose(5.0), sim.asv_pose(20.0)
    # A quarter turn in 15 s (one turn a minute), within the waves' few centimetres of drift.
    turned = matrix_to_euler_zyx(start.rotation.T @ later.rotation)[0]
    assert math.degrees(turned) == pytest.approx(90.0, abs=2.0)
    assert np.linalg.norm(later.translation[:2] - start.translation[:2]) < 0.2


def test_the_range_offset_manoeuvre_swings_the_asv_round_a_parked_rov_looking_aside() -> None:
    sim = Simulation(Config(asv_mode="orbit", rov_mode="parked", seed=2), horizon_s=130)
    rov = [sim.rov_state(t).position_m for t in range(0, 121, 5)]
    assert np.ptp(np.array(rov), axis=0).max() == 0.0  # parked
    bearings, facing = [], []
    for t in range(0, 121, 5):
        asv = sim.asv_pose(float(t))
        to_rov = rov[0][:2] - asv.translation[:2]
        bearing = math.atan2(to_rov[1], to_rov[0])
        bearings.append(bearing)
        heading = matrix_to_euler_zyx(asv.rotation)[0]
        facing.append(abs(math.degrees(math.remainder(heading - bearing, math.tau))))
    # The line of sight turns far enough for capsd.range_calibration, the sonar on the ROV,
    # seen to either side of the boresight (the forward position), well inside the fan.
    assert math.degrees(np.ptp(np.unwrap(bearings))) > 60.0
    assert 20.0 < max(facing) < 35.0
    assert np.median(facing) > 8.0


@pytest.mark.parametrize("tank", ["pond", "nfp", "mockup"])
def test_the_pitch_manoeuvre_takes_the_rov_through_the_aperture_and_back(tank: TankName) -> None:
    sim = Simulation(
        Config(tank=tank, asv_mode="follow", rov_mode="profile", seed=2), horizon_s=130
    )
    rov = np.array([sim.rov_state(float(t)).position_m for t in range(0, 121, 5)])
    assert np.ptp(rov[:, :2], axis=0).max() < 1e-9  # its place in the plane held
    assert rov[0, 2] == pytest.approx(-0.4)  # from just under the surface
    assert rov[12, 2] < -0.79  # down to the lower flight level at half time
    assert rov[24, 2] == pytest.approx(-0.4)  # and back up
    elevations = []
    for t in (0.0, 60.0):
        asv = sim.asv_pose(t)
        assert np.linalg.norm(asv.translation[:2] - sim.asv_pose(100.0).translation[:2]) < 0.1
        sonar = asv.compose(sim.mount)
        _, _, elevation = to_polar("conical", sonar.inverse().apply(sim.rov_state(t).position_m))
        elevations.append(math.degrees(elevation))
    top, bottom = elevations
    # Beyond both edges of the 20 deg aperture and its skirts, about evenly (the mount's drawn
    # errors and the waves aside).
    assert top > 15.0
    assert bottom < -15.0
    assert abs(top + bottom) < 3.0


@pytest.mark.parametrize("tank", ["pond", "nfp"])
def test_the_pitch_manoeuvre_from_near_and_far_spans_the_aperture_from_both(
    tank: TankName,
) -> None:
    # The sonar's height needs a second distance: the tank's near and far profiles, each from
    # above the aperture to below it as seen from its own distance, the far one over the floor.
    nominal = Config().sonar
    distances = profile_distances_m(
        make_tank(tank),
        sonar_z_m=nominal.position_m[2],
        pitch_rad=math.radians(nominal.pitch_deg),
        half_aperture_rad=math.radians(0.5 * nominal.vertical_aperture_deg),
    )
    assert len(distances) == 2
    assert distances[1] > distances[0] + 2.0
    for distance in distances:
        standoff = distance + nominal.position_m[0]
        config = Config(
            tank=tank, asv_mode="follow", rov_mode="profile", asv_standoff_m=standoff, seed=2
        )
        sim = Simulation(config, horizon_s=130)
        rov = np.array([sim.rov_state(float(t)).position_m for t in range(0, 121, 5)])
        assert np.ptp(rov[:, :2], axis=0).max() < 1e-9
        assert rov[:, 2].min() >= -sim.tank.depth_m + 0.6 - 1e-9  # over the floor's debris
        elevations = []
        for t in (0.0, 60.0):
            sonar = sim.asv_pose(t).compose(sim.mount)
            place = sim.rov_state(t).position_m
            apart = float(np.hypot(*(place[:2] - sonar.translation[:2])))
            assert apart == pytest.approx(distance, abs=0.15)
            p_s = sonar.inverse().apply(place)
            elevations.append(math.degrees(to_polar("conical", p_s)[2]))
        top, bottom = elevations
        # Beyond both edges of the aperture and its skirts (wider near: the ROV's own size).
        assert top > 13.0
        assert bottom < -15.0


def test_a_tank_too_shallow_for_a_far_profile_gets_the_one_profile() -> None:
    nominal = Config().sonar
    distances = profile_distances_m(
        make_tank("mockup"),
        sonar_z_m=nominal.position_m[2],
        pitch_rad=math.radians(nominal.pitch_deg),
        half_aperture_rad=math.radians(0.5 * nominal.vertical_aperture_deg),
    )
    assert distances == ()


def test_labels_are_in_the_sonar_s_range_units_as_its_frames() -> None:
    # The label describes the image: with a sound-speed error its ranges are scaled as the
    # frame's are; the truth position stays the truth.
    sim = Simulation(Config(seed=11, install_errors=REALISTIC), horizon_s=20)
    scale = sim.errors.sound_speed_scale
    checked = 0
    for t_s, _, label in sim.labelled_pings(start_ns=OFFLINE_START_NS, duration_s=2.0):
        sonar = sim.asv_pose(t_s).compose(sim.mount)
        true_range = float(np.linalg.norm(sonar.inverse().apply(np.array(label.rov_position_m))))
        assert label.range_m == pytest.approx(true_range / scale, abs=1e-6)
        checked += 1
    assert checked > 10
