"""The locator on simulator data: the filter beats the raw fix; no fix while out of view."""

from __future__ import annotations

from typing import Literal

import msgspec
import numpy as np
import pytest

from capsd.accuracy import CHI2_3_95
from capsd.calibrate import tape_prior
from capsd.mounts import RovConfig, SonarMountConfig
from capsd.services.locator.offline import Scored, run_offline
from capsd.services.locator.service import (
    Config,
    MethodConfig,
    SoundSpeedConfig,
    TrackingConfig,
)
from capsd.simulator.config import Config as SimConfig
from capsd.simulator.config import Rates, Streams
from capsd.simulator.install_errors import InstallErrorsConfig
from capsd.simulator.sim import Simulation

START_NS = 1_800_000_000_000_000_000
# The simulator's truth-plus-noise pose and detections play asv_pose and sonar_detect here,
# handed to the locator in process (on the bus they are on sim/ keys no service reads).
DETECTION_LEVEL = Streams(
    sonar_frames="off",
    lidar="off",
    imu="off",
    asv_pose_truth_noise="on",
    detections_truth_noise="on",
)


PERFECT = InstallErrorsConfig(mode="off")  # the method, not an installation


def _run(sim: SimConfig, locator: Config, duration_s: float) -> list[Scored]:
    # Detection level: the locator needs no images, scans or IMU samples.
    sim = msgspec.structs.replace(sim, streams=DETECTION_LEVEL)
    events = Simulation(sim, horizon_s=duration_s + 5).events(
        start_ns=START_NS, duration_s=duration_s
    )
    return list(run_offline(locator, (e.payload for e in events)))


def _errors(scored: list[Scored], *, filtered: bool) -> list[float]:
    out = []
    for s in scored:
        position = s.fix.position_m if filtered else s.fix.raw_position_m
        truth = s.truth_position_m
        if truth is not None and position is not None and s.fix.quality == "good":
            out.append(float(np.linalg.norm(np.subtract(position, truth))))
    return out


def test_filter_beats_the_raw_fix_on_simulator_data() -> None:
    scored = _run(
        SimConfig(seed=5, trajectory="lawnmower", install_errors=PERFECT), Config(), duration_s=60
    )
    raw, filtered = _errors(scored, filtered=False), _errors(scored, filtered=True)
    assert len(filtered) > 500
    assert np.mean(filtered) < 0.8 * np.mean(raw)
    assert all(s.fix.method == "capsd" for s in scored)


def test_no_fix_while_out_of_view_longer_than_the_coast_time() -> None:
    lost_after_s = 1.5
    sim = SimConfig(seed=2, sonar_dropouts_s=((20.0, 26.0),), install_errors=PERFECT)
    scored = _run(sim, Config(tracking=TrackingConfig(lost_after_s=lost_after_s)), duration_s=30)
    dropout_start_ns = START_NS + 20 * 1_000_000_000
    coast_end_ns = dropout_start_ns + int(lost_after_s * 1e9)
    during = [s.fix for s in scored if dropout_start_ns <= s.fix.stamp_ns < START_NS + 26 * 10**9]
    assert during, "the dropout window must contain pings"
    for fix in during:
        assert fix.quality != "good"  # nothing measured: at best an "unsure" prediction
        if fix.stamp_ns > coast_end_ns:
            assert fix.quality == "invalid"
            assert fix.position_m is None
            assert fix.track_state == "lost"
    after = [s.fix for s in scored if s.fix.stamp_ns >= START_NS + 27 * 10**9]
    assert after
    assert all(f.quality == "good" for f in after), "the track restarts when the ROV is back"


def test_paper_baseline_is_selectable() -> None:
    paper = Config(method=MethodConfig(preset="paper"), sonar=SonarMountConfig(beam_model="planar"))
    scored = _run(SimConfig(seed=3, install_errors=PERFECT), paper, duration_s=20)
    fixes = [s.fix for s in scored]
    assert {f.method for f in fixes} == {"paper"}
    assert all(f.track_state == "none" and f.position_m is None for f in fixes)
    errors = _errors(scored, filtered=False)
    assert len(errors) > 150
    assert np.mean(errors) < 0.2  # a working baseline, not a broken one


def test_rov_velocity_input_helps_the_filter() -> None:
    with_dvl = SimConfig(seed=8, rates=Rates(velocity_hz=5.0), install_errors=PERFECT)
    without = SimConfig(seed=8, install_errors=PERFECT)
    err_with = _errors(_run(with_dvl, Config(), duration_s=60), filtered=True)
    err_without = _errors(_run(without, Config(), duration_s=60), filtered=True)
    assert np.mean(err_with) < np.mean(err_without)


def test_installation_uncertainty_makes_the_covariance_honest() -> None:
    # An installation measured with a tape and never calibrated: the fixes are off by what it
    # got wrong, and only a locator told how far that may be reports covariances that say so.
    sim = SimConfig(
        seed=7, trajectory="square", install_errors=InstallErrorsConfig(mode="realistic", seed=3)
    )
    told = Config(installation=tape_prior(InstallErrorsConfig()))

    def within(locator: Config) -> float:
        inside = []
        for s in _run(sim, locator, duration_s=40):
            fix, truth = s.fix, s.truth_position_m
            if fix.quality != "good" or fix.position_m is None or fix.covariance_m2 is None:
                continue
            assert truth is not None
            error = np.subtract(fix.position_m, truth)
            cov = np.array(fix.covariance_m2).reshape(3, 3)
            inside.append(float(error @ np.linalg.solve(cov, error)) <= CHI2_3_95)
        assert len(inside) > 300
        return float(np.mean(inside))

    assert within(Config()) < 0.5
    assert within(told) > 0.9


def test_the_depth_offset_is_added_to_every_reading() -> None:
    sim = SimConfig(seed=5, trajectory="square", install_errors=PERFECT)
    offset = RovConfig(depth_offset_m=0.05)

    def mean_z(locator: Config) -> float:
        zs = [
            s.fix.raw_position_m[2]
            for s in _run(sim, locator, duration_s=20)
            if s.fix.quality == "good" and s.fix.raw_position_m is not None
        ]
        assert len(zs) > 100
        return float(np.mean(zs))

    # A reading 5 cm deeper puts the ROV 5 cm lower.
    assert mean_z(Config(rov=offset)) - mean_z(Config()) == pytest.approx(-0.05, abs=1e-6)


def test_the_rov_s_thermometer_takes_the_speed_of_sound_out_of_the_fixes() -> None:
    # Only the speed of sound wrong, and far more than usual (the sonar assumes a speed 2 %
    # off, a wrong salinity setting would do it): rescaled to the water the ROV's thermometer
    # reads (its own bias drawn too), the fixes lose nearly all of that error.
    others = (
        "sonar_angle_sigma_deg",
        "sonar_position_sigma_m",
        "lidar_yaw_sigma_deg",
        "lidar_position_sigma_m",
        "pressure_arm_sigma_m",
        "depth_bias_sigma_m",
        "depth_drift_sigma_m_per_h",
        "depth_quantum_m",
        "attitude_bias_sigma_deg",
        "heading_error_sigma_deg",
        "attitude_noise_deg",
        "float_trim_sigma_m",
    )
    only_sound = msgspec.structs.replace(
        InstallErrorsConfig(mode="realistic", seed=4),
        **dict.fromkeys(others, 0.0),
        sound_speed_sigma=0.02,
    )
    sim = SimConfig(seed=5, trajectory="square", install_errors=only_sound)
    drawn = Simulation(sim, horizon_s=10).errors
    assert abs(drawn.sound_speed_scale - 1.0) > 0.005  # this seed's draw: worth correcting
    assert drawn.rov_thermometer_bias_c != 0.0

    def median_error(sim: SimConfig, source: Literal["rov_thermometer", "sonar"]) -> float:
        scored = _run(sim, Config(sound_speed=SoundSpeedConfig(source=source)), duration_s=20)
        errors = _errors(scored, filtered=True)
        assert len(errors) > 100
        return float(np.median(errors))

    rescaled = median_error(sim, "rov_thermometer")
    assert rescaled < 0.3 * median_error(sim, "sonar")
    perfect = msgspec.structs.replace(sim, install_errors=PERFECT)
    assert rescaled < median_error(perfect, "rov_thermometer") + 0.005
