"""The whole pipeline without a bus: simulator events through the same code the services run.

One simulated run feeds, in time order, the same components the processes host: the ASV pose
estimator (IMU + LiDAR; ours or the paper's accelerometer-trusting tilt), the detector (the
polar CNN, the classical one, or the paper's box centre given a perfect box) with the depth gate
the detection service applies (the newest estimated ASV pose and depth reading, its default
settings) and one Locator per method variant, so a baseline, ours and every ablation are
measured on the very same pings.
Every fix is paired with the label of its ping. Nothing is taken from truth except the heading
prior the pose service is configured with (the start heading, deliberately 20 deg off), for
the paper's box-centre detector, the perfect box the paper's YOLO is granted, and for the
"perfect detector" ablation the ROV's true centre (what the rest of the pipeline costs), and
for the "detector ... exact" variants the truth along one axis or both of the detector's own
candidate on the ROV (what the detector's range or bearing error costs, on its own pings).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import msgspec
import numpy as np

from capsd.accuracy import Accuracy, score
from capsd.geometry import euler_zyx_to_matrix, matrix_to_euler_zyx
from capsd.mounts import RovConfig, SonarMountConfig
from capsd.payloads import (
    Detection,
    ImuSample,
    LidarScan,
    Payload,
    RovAttitude,
    RovDepth,
    RovVelocity,
    SonarDetections,
    SonarFrame,
    SonarLabel,
)
from capsd.progress import Progress
from capsd.services.asv_pose.estimator import AsvPoseEstimator, EstimatorSettings, pose_payload
from capsd.services.asv_pose.scan_match import tank_walls
from capsd.services.asv_pose.tilt import TiltSettings
from capsd.services.locator.service import Config as LocatorConfig
from capsd.services.locator.service import InstallationConfig, Locator, MethodConfig
from capsd.services.sonar_detect.paper_box import box_centre
from capsd.services.sonar_detect.service import (
    CnnConfig,
    DepthGateConfig,
    Detector,
    DetectorName,
    GateInputs,
    confidence_of,
    detect_gated,
)
from capsd.services.sonar_detect.service import Config as DetectConfig
from capsd.simulator.config import OFFLINE_START_NS
from capsd.simulator.config import Config as SimConfig
from capsd.simulator.sim import Simulation
from capsd.simulator.world import make_tank, tank_bounds
from capsd.sonar_geometry import fan_distance_m

# truth: the label's ROV centre as the one candidate, told tight sigmas (a perfect detector:
# what the rest of our pipeline costs without any detector error; never in a service).
DetectorKind = Literal["cnn", "classical", "box_centre", "truth"]
TRUTH_RANGE_SIGMA_M = 0.005
TRUTH_AZIMUTH_SIGMA_RAD = math.radians(0.05)
TiltKind = Literal["ours", "paper"]
HEADING_PRIOR_ERROR_RAD = math.radians(20.0)
PERFECT_DETECTOR = "ours, a perfect detector"
# What of the detector's candidate on the ROV a variant takes from the truth instead (a
# diagnostic: the cost of the detector's range or bearing error on the pings it finds).
ExactAxes = Literal["none", "range", "azimuth", "both"]
DETECTOR_EXACT = "ours + the detector's centre exact"
DETECTOR_RANGE_EXACT = "ours + the detector's range exact"
DETECTOR_BEARING_EXACT = "ours + the detector's bearing exact"
# The detector's candidate on the ROV: the one nearest the label's centre, this near at most
# in the fan's plane (`capsd bench detect`'s MATCH_M, there per axis: range and cross-range).
EXACT_MATCH_M = 0.5


@dataclass(frozen=True)
class Variant:
    """One way of making fixes: a detector, a tilt filter and the locator's method switches."""

    name: str
    detector: DetectorKind = "cnn"
    tilt: TiltKind = "ours"
    method: MethodConfig = field(default_factory=MethodConfig)
    beam_model: Literal["conical", "planar"] = "conical"  # what the locator assumes
    box_range_bias_m: float = 0.0  # added to the box centre's range (box_centre detector)
    # The sonar mount the locator is told (None: the nominal one, as the simulator's config
    # states it); e.g. what `capsd calibrate` found.
    sonar: SonarMountConfig | None = None
    # The ROV's pressure sensor as the locator is told (None: the simulator's nominal one);
    # e.g. with the depth offset `capsd calibrate` found at the surface.
    rov: RovConfig | None = None
    # What the locator is told the installation may still get wrong (None: its default).
    installation: InstallationConfig | None = None
    # The locator's covariance floor (None: its default); 0 to see the bare covariance.
    unmodelled_sigma_m: float | None = None
    # Whose speed of sound the ranges are in: the water's from the ROV's thermometer (the
    # locator's default), or the one the sonar assumed (the paper's method as published).
    sound_speed: Literal["rov_thermometer", "sonar"] = "rov_thermometer"
    # The detector's candidate on the ROV moved to the truth along these axes (`with_exact`);
    # its sigmas, confidence and every other candidate as the detector gave them.
    exact: ExactAxes = "none"


def locator_config(variant: Variant, sim: SimConfig) -> LocatorConfig:
    """The locator as deployed for this tank: the nominal mounts (or the variant's), its walls."""
    tank = sim.world_tank()
    sonar = variant.sonar if variant.sonar is not None else sim.sonar
    config = LocatorConfig(
        sonar=msgspec.structs.replace(sonar, beam_model=variant.beam_model),
        rov=variant.rov if variant.rov is not None else sim.rov,
        method=variant.method,
        tank=tank_bounds(tank),
    )
    if variant.installation is not None:
        config = msgspec.structs.replace(config, installation=variant.installation)
    if variant.sound_speed != config.sound_speed.source:
        config = msgspec.structs.replace(
            config,
            sound_speed=msgspec.structs.replace(config.sound_speed, source=variant.sound_speed),
        )
    if variant.unmodelled_sigma_m is not None:
        config = msgspec.structs.replace(config, unmodelled_sigma_m=variant.unmodelled_sigma_m)
    return config


def _estimator(kind: TiltKind, sim: SimConfig, heading_prior_rad: float) -> AsvPoseEstimator:
    tank = make_tank(sim.tank)
    roll, pitch, yaw = (math.radians(v) for v in sim.imu.mount_rpy_deg)
    mounting = euler_zyx_to_matrix(yaw, pitch, roll)
    if kind == "ours":
        tilt = TiltSettings(mounting=mounting)
        compensation: Literal["track", "none"] = "track"
    else:  # trusts the accelerometer: corrects within 0.2 s, never gates it, no compensation
        tilt = TiltSettings(kp=5.0, ki=0.0, accel_tolerance_m_s2=100.0, mounting=mounting)
        compensation = "none"
    return AsvPoseEstimator(
        tank_walls(tank.length_m, tank.width_m),
        heading_prior_rad=heading_prior_rad,
        settings=EstimatorSettings(
            lidar_position_m=sim.lidar.position_m,
            accel_compensation=compensation,
        ),
        tilt=tilt,
    )


# The sonar_detect service's defaults where the pipeline runs its detectors as the service.
DETECT_CONFIG = DetectConfig()


def _detectors(kinds: set[DetectorKind]) -> dict[DetectorName, Detector]:
    out: dict[DetectorName, Detector] = {}
    if "cnn" in kinds:
        from capsd.services.sonar_detect.cnn import CnnDetector

        out["cnn"] = CnnDetector()
    if "classical" in kinds:
        from capsd.services.sonar_detect.classical import ClassicalDetector

        out["classical"] = ClassicalDetector()
    return out


def run(
    sim_config: SimConfig,
    *,
    duration_s: float,
    variants: list[Variant],
    progress: Progress | None = None,
    progress_offset_s: float = 0.0,
    sink: Callable[[Payload], None] | None = None,
    depth_gate: Literal["reject", "off"] = "reject",
) -> dict[str, Accuracy]:
    """Simulate `duration_s` and score every variant on the same pings.

    `depth_gate` as the detection service's (`reject`, its default, or `off`): it reads the
    ASV pose of our estimator (the first variant's, without one of ours) and the depth as read.
    `sink` sees what a recording of the live system would hold: the sonar frames, the first
    variant's ASV poses (one per LiDAR scan) and its fixes, the ROV's depth and attitude.
    """
    config = msgspec.structs.replace(
        sim_config,
        streams=msgspec.structs.replace(
            sim_config.streams,
            sonar_frames="on",
            lidar="on",
            imu="on",
            asv_pose_truth_noise="off",
            detections_truth_noise="off",
        ),
    )
    sim = Simulation(config, horizon_s=duration_s + 5.0)
    start_yaw = matrix_to_euler_zyx(sim.asv_pose(0.0).rotation)[0]
    tilts = {v.tilt for v in variants}
    estimators = {k: _estimator(k, config, start_yaw + HEADING_PRIOR_ERROR_RAD) for k in tilts}
    detect = _detectors({v.detector for v in variants})
    # The CNN's range corrected by elevation as the service's default configures it.
    range_bias = CnnConfig().range_bias_correction() if "cnn" in detect else None
    gating = GateInputs(DepthGateConfig(mode=depth_gate, sonar=config.sonar))
    gate_tilt: TiltKind = "ours" if "ours" in tilts else variants[0].tilt
    locators = {v.name: Locator(locator_config(v, config)) for v in variants}
    accuracy = {v.name: Accuracy() for v in variants}
    by_tilt = {k: [locators[v.name] for v in variants if v.tilt == k] for k in tilts}
    every = list(locators.values())
    frame: SonarFrame | None = None
    found: dict[DetectorKind, list[Detection]] = {}
    pose_seq = 0
    for event in sim.events(start_ns=OFFLINE_START_NS, duration_s=duration_s):
        p = event.payload
        if isinstance(p, ImuSample):
            gyro = np.array(p.angular_velocity_rad_s)
            accel = np.array(p.linear_acceleration_m_s2)
            for kind, estimator in estimators.items():
                estimator.on_imu(p.stamp_ns, gyro, accel)
                pose = pose_payload(
                    estimator.estimate(p.stamp_ns), seq=pose_seq, source="scan_match"
                )
                for locator in by_tilt[kind]:
                    locator.on_pose(pose)
                if kind == gate_tilt:
                    gating.pose = pose
            pose_seq += 1
        elif isinstance(p, LidarScan):
            ranges = np.array(p.ranges_m)
            angles = np.asarray(
                p.angle_min_rad + p.angle_increment_rad * np.arange(len(ranges)), dtype=np.float64
            )
            for estimator in estimators.values():
                estimator.on_scan(p.stamp_ns, ranges, angles)
            if sink is not None:
                first = estimators[variants[0].tilt]
                sink(pose_payload(first.estimate(p.stamp_ns), seq=pose_seq, source="scan_match"))
        elif isinstance(p, RovDepth):
            gating.depth = p
            for locator in every:
                locator.on_depth(p)
            if sink is not None:
                sink(p)
        elif isinstance(p, RovAttitude):
            for locator in every:
                locator.on_attitude(p)
            if sink is not None:
                sink(p)
        elif isinstance(p, RovVelocity):
            for locator in every:
                locator.on_velocity(p)
        elif isinstance(p, SonarFrame):
            frame = p
            gate = gating.gate(p.stamp_ns)
            found = {
                kind: detect_gated(
                    d,
                    p,
                    gate,
                    min_confidence=0.5,
                    confidence=confidence_of(kind, DETECT_CONFIG.cnn),
                    range_bias=range_bias if kind == "cnn" else None,
                ).detections
                for kind, d in detect.items()
            }
            if sink is not None:
                sink(p)
        elif isinstance(p, SonarLabel) and frame is not None and frame.stamp_ns == p.stamp_ns:
            boxes = {
                bias: box_centre(p, range_bias_m=bias)
                for bias in {v.box_range_bias_m for v in variants if v.detector == "box_centre"}
            }
            for v in variants:
                if v.detector == "box_centre":
                    candidates = boxes[v.box_range_bias_m]
                elif v.detector == "truth":
                    candidates = true_centre(p)
                else:
                    candidates = with_exact(found[v.detector], p, axes=v.exact)
                detections = SonarDetections(
                    stamp_ns=frame.stamp_ns,
                    seq=frame.seq,
                    ping_id=frame.ping_id,
                    detector=v.detector,
                    detections=tuple(d for d in candidates if d.confidence >= 0.5),
                    sound_speed_m_s=frame.sound_speed_m_s,
                )
                fix = locators[v.name].locate(detections, seq=frame.seq)
                accuracy[v.name].add(score(fix, p))
                if sink is not None and v is variants[0]:
                    sink(fix)
            frame = None
            if progress is not None:
                progress.update(progress_offset_s + event.t_s)
    return accuracy


def true_centre(label: SonarLabel) -> list[Detection]:
    """A perfect detector's output: the ROV centre where the label says it is, if in view."""
    if not label.visible or label.range_m <= 0.0:
        return []
    return [
        Detection(
            range_m=label.range_m,
            azimuth_rad=label.azimuth_rad,
            range_sigma_m=TRUTH_RANGE_SIGMA_M,
            azimuth_sigma_rad=TRUTH_AZIMUTH_SIGMA_RAD,
            confidence=1.0,
        )
    ]


def with_exact(
    candidates: list[Detection], label: SonarLabel, *, axes: ExactAxes
) -> list[Detection]:
    """`candidates` with the one on the ROV given the label's range and/or azimuth (`axes`).

    The one on the ROV is the candidate nearest the ROV's true centre, within EXACT_MATCH_M;
    without one (a miss, or the ROV out of view) the candidates are returned as they are.
    """
    if axes == "none" or not label.visible or not candidates:
        return candidates
    gaps = [fan_distance_m(d, label) for d in candidates]
    k = int(np.argmin(gaps))
    if gaps[k] > EXACT_MATCH_M:
        return candidates
    d = candidates[k]
    moved = msgspec.structs.replace(
        d,
        range_m=label.range_m if axes in ("range", "both") else d.range_m,
        azimuth_rad=label.azimuth_rad if axes in ("azimuth", "both") else d.azimuth_rad,
    )
    return [*candidates[:k], moved, *candidates[k + 1 :]]


def ablations(*, box_range_bias_m: float | None = None) -> list[Variant]:
    """The paper's method, ours, and ours without each improvement in turn.

    With `box_range_bias_m` (measured on training runs), also the paper's method with its box
    centre's range corrected by it: the strongest form of the baseline (which also gets
    the ranges in the water's speed of sound, as ours).
    """
    paper = MethodConfig(preset="paper")
    custom = MethodConfig(preset="custom")
    baseline = Variant(
        "paper (baseline)",
        detector="box_centre",
        tilt="paper",
        method=paper,
        beam_model="planar",
        sound_speed="sonar",
    )
    calibrated = (
        []
        if box_range_bias_m is None
        else [
            dataclasses.replace(
                baseline,
                name="paper, box range calibrated",
                box_range_bias_m=box_range_bias_m,
                sound_speed="rov_thermometer",
            )
        ]
    )
    return [
        baseline,
        *calibrated,
        Variant("ours (CAP-SD)"),
        Variant("ours - time alignment", method=replace_method(custom, matching="latest")),
        Variant("ours - lever arm", method=replace_method(custom, lever_arm="ignore")),
        Variant("ours - beam model (planar)", beam_model="planar"),
        Variant("ours - exact tilted geometry", method=replace_method(custom, geometry="paper")),
        Variant("ours - polar CNN (box centre)", detector="box_centre"),
        Variant("ours - tracking filter", method=replace_method(custom, tracking="per_frame")),
        Variant("ours - gyro-dominant tilt", tilt="paper"),
        Variant(PERFECT_DETECTOR, detector="truth"),
        # Ours with the CNN's own candidates, its error on the ROV taken off along one axis or
        # both: what its range and its bearing error each cost, on the pings it finds (the
        # perfect detector's gap to ours less these is what it misses, or its false alarms).
        Variant(DETECTOR_EXACT, exact="both"),
        Variant(DETECTOR_RANGE_EXACT, exact="range"),
        Variant(DETECTOR_BEARING_EXACT, exact="azimuth"),
    ]


def replace_method(method: MethodConfig, **changes: str) -> MethodConfig:
    return msgspec.structs.replace(method, **changes)


__all__ = ["Variant", "ablations", "box_centre", "locator_config", "run", "with_exact"]
