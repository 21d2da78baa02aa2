"""The locator service: ROV fixes from detections, ASV pose and ROV depth/attitude, tracked.

Per ping: inputs are time-aligned at the ping's `stamp_ns` (pose: linear + slerp; depth: linear;
attitude: slerp), every candidate detection is solved exactly (capsd.services.locator.fix), ghosts
(no valid root, outside the tank) are dropped, and the tracker fuses the candidate consistent
with the track. The paper's method is one `method` preset away, for the benchmark; each of its
choices can also be switched alone (for ablations).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar

import msgspec
import numpy as np

from capsd import topics
from capsd.config import ConfigSection, ServiceConfig
from capsd.echo_cell import any_inside, cell_points, fixture_boxes
from capsd.geometry import Array, Transform, quat_slerp, quat_to_matrix
from capsd.keys import check_name
from capsd.logs import log_fields
from capsd.mounts import RovConfig, SonarMountConfig
from capsd.payloads import (
    AsvPose,
    Detection,
    LocatorMethod,
    RovAttitude,
    RovDepth,
    RovFix,
    RovVelocity,
    SonarDetections,
    SonarTilt,
)
from capsd.runner import Publisher, ServiceRunner
from capsd.services.locator.clutter import ClutterMap, ClutterSettings
from capsd.services.locator.fix import (
    FixUncertainty,
    InstallationSigmas,
    installation_covariance,
    rov_centre_z,
    solve_fix,
)
from capsd.services.locator.moving_echo import MovingEchoes, MovingEchoSettings
from capsd.services.locator.paper import paper_fix
from capsd.services.locator.relocation import LastSeen, Relocation, RelocationSettings
from capsd.services.locator.timeline import Lookup, Timeline
from capsd.services.locator.tracker import Association, Tracker, TrackerSettings
from capsd.services.locator.waiting import PoseWait
from capsd.servo_motion import ServoMotion, ServoState
from capsd.signing import SiteKey
from capsd.sonar_geometry import to_polar
from capsd.sound_speed import SoundSpeedError, relative_sigma, speed_of_sound_m_s
from capsd.tank import TankBounds

logger = logging.getLogger(__name__)

T = TypeVar("T")
# A change of the speed-of-sound correction this large (relative) is logged again.
LOG_SCALE_CHANGE = 0.0002

NonNeg = Annotated[float, msgspec.Meta(ge=0.0)]
Positive = Annotated[float, msgspec.Meta(gt=0.0)]


class LocatorInputs(ConfigSection, frozen=True, kw_only=True):
    """Whose streams the locator reads, and how far inputs may be stretched in time."""

    asv_vehicle: str = "asv"
    rov_vehicle: str = "rov"
    # How far past the newest sample an input may be extrapolated before the fix is refused.
    max_extrapolation_s: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)] = 0.15
    buffer_s: Annotated[float, msgspec.Meta(gt=0.0, le=30.0)] = 5.0
    # A ping whose ASV pose has not arrived yet waits this long for it (services/locator/
    # waiting.py); 0: located at once (refused as asv_pose_too_new).
    pose_wait_s: Annotated[float, msgspec.Meta(ge=0.0, le=2.0)] = 0.3

    def __post_init__(self) -> None:
        super().__post_init__()
        for field in ("asv_vehicle", "rov_vehicle"):
            try:
                check_name("vehicle", getattr(self, field))
            except ValueError as exc:
                raise ValueError(f"`{field}`: {exc}") from None


class MethodConfig(ConfigSection, frozen=True, kw_only=True):
    """How the fix is made. `preset` "paper" forces the paper's choices for all four."""

    preset: Literal["capsd", "paper", "custom"] = "capsd"
    geometry: Literal["exact", "paper"] = "exact"
    # causal: inputs stamped at or before the ping, extrapolated to it (deterministic under
    # replay: nothing stamped after the ping counts); interpolate: also the samples after it
    # when they are in by then; latest: the newest sample (the paper's matching).
    matching: Literal["causal", "interpolate", "latest"] = "causal"
    lever_arm: Literal["correct", "ignore"] = "correct"
    tracking: Literal["filter", "per_frame"] = "filter"

    def resolved(self) -> MethodConfig:
        """The effective switches: presets fix them, "custom" keeps what the file says."""
        if self.preset == "paper":
            return MethodConfig(
                preset="paper",
                geometry="paper",
                matching="latest",
                lever_arm="ignore",
                tracking="per_frame",
            )
        if self.preset == "capsd":
            return MethodConfig()
        return self


class TrackingConfig(ConfigSection, frozen=True, kw_only=True):
    """Tracker tuning (capsd.services.locator.tracker)."""

    accel_density_xy: Positive = 0.02
    # 0.01 until session 69. The depth readings (10 Hz, the simulator's 1 cm noise) are most of
    # a fix's vertical error; a ROV changes depth gently, so the track may average more of
    # them. Chosen on `capsd bench accuracy --seed 1` (never the committed table's seed 0),
    # its nfp and mockup runs: 0.01 / 0.002 / 0.0005 / 0.0001 gave z RMSE 7.0 / 5.9 / 5.1 /
    # 4.1 mm on nfp square and MED lower at each step on every run but the mockup's at 0.0001
    # (16.0 -> 16.8 mm, z 6.2 -> 8.0: the track lags its depth changes): 0.0005
    # (docs/JOURNAL.md, the accuracy bench, session 69).
    accel_density_z: Positive = 0.0005
    gate_chi2: Positive = 16.27
    lost_after_s: Positive = 2.0
    reinit_after: Annotated[int, msgspec.Meta(ge=1)] = 5
    confirm_after: Annotated[int, msgspec.Meta(ge=1, le=100)] = 3
    # The manoeuvre gate (a ROV starting or ending a leg); density 0 turns it off.
    manoeuvre_accel_density_xy: NonNeg = 0.5
    manoeuvre_accel_density_z: NonNeg = 0.1
    manoeuvre_window_s: Positive = 1.0
    # Coasting this long, the track takes no echo of learned static clutter (the tracker).
    static_coast_s: Annotated[float, msgspec.Meta(ge=0.0, le=60.0)] = 0.5
    # Where the ROV could be since its last confirmed fix: within reach_radius_m +
    # reach_drift_m_s x elapsed of where its velocity then carried it for up to reach_carry_s.
    reach_radius_m: Annotated[float, msgspec.Meta(ge=0.0, le=20.0)] = 0.5
    reach_drift_m_s: Annotated[float, msgspec.Meta(ge=0.0, le=2.0)] = 0.2
    reach_carry_s: Annotated[float, msgspec.Meta(ge=0.0, le=30.0)] = 2.0
    # prove: a track starting where the ROV could not be is unsure until its echo moves as no
    # static one could, or for relocate_confirm_s; a candidate where the ROV could be takes
    # over (capsd.services.locator.relocation). off: hits alone confirm any new track.
    relocation: Literal["prove", "off"] = "prove"
    relocate_confirm_s: Annotated[float, msgspec.Meta(ge=0.0, le=600.0)] = 20.0

    def relocation_settings(self) -> RelocationSettings:
        return RelocationSettings(
            radius_m=self.reach_radius_m,
            drift_m_s=self.reach_drift_m_s,
            carry_s=self.reach_carry_s,
            confirm_after_s=self.relocate_confirm_s,
        )

    def settings(self) -> TrackerSettings:
        return TrackerSettings(
            accel_density_xy=self.accel_density_xy,
            accel_density_z=self.accel_density_z,
            gate_chi2=self.gate_chi2,
            lost_after_s=self.lost_after_s,
            reinit_after=self.reinit_after,
            confirm_after=self.confirm_after,
            manoeuvre_accel_density_xy=self.manoeuvre_accel_density_xy,
            manoeuvre_accel_density_z=self.manoeuvre_accel_density_z,
            manoeuvre_window_s=self.manoeuvre_window_s,
            static_coast_s=self.static_coast_s,
        )


class ClutterConfig(ConfigSection, frozen=True, kw_only=True):
    """Clutter that may not start a track: learned, and explained by the tank's map.

    Learned while tracking: capsd.services.locator.clutter; the map: capsd.echo_cell.
    """

    mode: Literal["learn", "off"] = "learn"
    # refuse_start: an echo whose range cell, at its bearing and anywhere in the vertical
    # aperture, holds a mapped fixture (`tank.fixtures`, grown by `map_margin_m`) may update a
    # track but never start one (the 2D image cannot tell the two apart), unless it lies where
    # the ROV was last confirmed (see `reacquire_window_s`); refuse_unless_moving: the same, unless
    # the echo has moved as no static source's could (capsd.services.locator.moving_echo,
    # `moving_*`); off.
    map_explained: Literal["refuse_start", "refuse_unless_moving", "off"] = "refuse_unless_moving"
    map_margin_m: Annotated[float, msgspec.Meta(ge=0.0, le=2.0)] = 0.3
    # A ROV lost over a rack is found again where it was: a map-explained echo may start a
    # track where the ROV could be since its last confirmed fix (`tracking.reach_*`), for
    # reacquire_window_s after it. A fixture's echo farther off still may not.
    reacquire_window_s: Annotated[float, msgspec.Meta(ge=0.0, le=600.0)] = 10.0
    # The moving-echo test: followed at least moving_min_age_s, then at least moving_shift_m
    # from wherever a static source of its first sighting would now appear.
    moving_min_age_s: Annotated[float, msgspec.Meta(ge=0.1, le=60.0)] = 1.0
    moving_shift_m: Annotated[float, msgspec.Meta(ge=0.05, le=5.0)] = 0.3
    # ... and its latest sightings within this (RMS) of a straight line: a ROV's path is
    # smooth, a fixture's brightest point jumps about it (capsd.services.locator.moving_echo).
    moving_max_scatter_m: Annotated[float, msgspec.Meta(ge=0.01, le=5.0)] = 0.1
    cell_m: Annotated[float, msgspec.Meta(ge=0.1, le=5.0)] = 0.5
    static_after_s: Annotated[float, msgspec.Meta(gt=0.0, le=600.0)] = 5.0
    min_sightings: Annotated[int, msgspec.Meta(ge=1)] = 10
    forget_after_s: Annotated[float, msgspec.Meta(gt=0.0, le=3600.0)] = 60.0
    # An echo this near the centre of a static cell's sightings is that clutter's.
    static_radius_m: Annotated[float, msgspec.Meta(gt=0.0, le=5.0)] = 0.5
    # Candidates nearer the tracked ROV than this are not learned (its own echo's spread).
    clear_of_track_m: Annotated[float, msgspec.Meta(gt=0.0, le=10.0)] = 1.0

    def moving_settings(self) -> MovingEchoSettings:
        return MovingEchoSettings(
            min_age_s=self.moving_min_age_s,
            min_shift_m=self.moving_shift_m,
            max_scatter_m=self.moving_max_scatter_m,
        )

    def settings(self) -> ClutterSettings:
        return ClutterSettings(
            cell_m=self.cell_m,
            static_after_s=self.static_after_s,
            min_sightings=self.min_sightings,
            forget_after_s=self.forget_after_s,
            radius_m=self.static_radius_m,
        )


Sigma = Annotated[float, msgspec.Meta(ge=0.0, le=10.0)]


class InstallationConfig(ConfigSection, frozen=True, kw_only=True):
    """1-sigma of what the configured installation may still get wrong.

    Propagated through each fix's geometry into the covariance it reports (not into the
    filter's: these errors hold for a whole dive, so averaging pings does not shrink them).
    `capsd calibrate` writes what it determined and keeps the rest (docs/INSTALL-ERRORS.md).
    """

    range_scale: Annotated[float, msgspec.Meta(ge=0.0, le=0.1)] = 0.0  # the speed of sound
    sonar_position_m: tuple[Sigma, Sigma, Sigma] = (0.0, 0.0, 0.0)  # x, y, z on the ASV
    sonar_angles_deg: tuple[Sigma, Sigma, Sigma] = (0.0, 0.0, 0.0)  # yaw, pitch, roll
    depth_offset_m: Sigma = 0.0

    def sigmas(self) -> InstallationSigmas:
        """In the solver's units (radians)."""
        yaw, pitch, roll = (math.radians(v) for v in self.sonar_angles_deg)
        return InstallationSigmas(
            self.range_scale, self.sonar_position_m, (yaw, pitch, roll), self.depth_offset_m
        )


class SoundSpeedConfig(ConfigSection, frozen=True, kw_only=True):
    """Whose speed of sound the ranges are in (capsd.sound_speed; docs/INSTALL-ERRORS.md).

    rov_thermometer: each ping's ranges are rescaled from the speed the sonar assumed (it
    reports it) to the speed of the water the ROV's thermometer reads, at this salinity; the
    fix's covariance then allows for the thermometer's and the salinity's 1-sigma instead of
    installation.range_scale. Where a ping or the depth readings do not carry what it needs,
    the ranges stay the sonar's (counted in Health as sonar_speed_pings). sonar: as reported.
    """

    source: Literal["rov_thermometer", "sonar"] = "rov_thermometer"
    salinity_ppt: Annotated[float, msgspec.Meta(ge=0.0, le=45.0)] = 0.0  # demineralised pond
    salinity_sigma_ppt: Annotated[float, msgspec.Meta(ge=0.0, le=45.0)] = 0.0
    thermometer_sigma_c: Annotated[float, msgspec.Meta(ge=0.0, le=10.0)] = 0.5


class Config(ServiceConfig, frozen=True, kw_only=True):
    """Locator configuration."""

    vehicle: str = "topside"
    inputs: LocatorInputs = LocatorInputs()
    sonar: SonarMountConfig = SonarMountConfig()
    rov: RovConfig = RovConfig()
    method: MethodConfig = MethodConfig()
    tank: TankBounds | None = TankBounds()
    tracking: TrackingConfig = TrackingConfig()
    clutter: ClutterConfig = ClutterConfig()
    max_conditioning: Positive = 10.0
    # A fix may be taken up to this far beyond the aperture's nominal (-3 dB) edge, where the
    # other root is not: the vertical beam pattern still returns an echo there (a Gaussian
    # pattern is -5 dB at 1.3 times the half-aperture). Off by default: such fixes are biased
    # (only the part of the ROV inside the beam echoes; in `capsd bench accuracy`'s mockup
    # and pond random runs, by hand, the fixes 3 deg allowed had MEDs of 64 and 109 mm), though
    # in the closed loop they raised availability (docs/JOURNAL.md, the ASV keeps the ROV in view).
    aperture_skirt_deg: Annotated[float, msgspec.Meta(ge=0.0, le=15.0)] = 0.0
    min_confidence: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)] = 0.5
    # A detection whose own range 1-sigma (the refiner's Laplace scale) is over this is not
    # used: its echo is not the ROV's alone (clutter overlapping it), and its errors repeat
    # ping after ping, so the filter would average them into a confident wrong track. 5 cm:
    # three of them are issue 21's 0.15 m cross-track budget. On `capsd bench accuracy`'s
    # runs (session 53, by hand) the single-ping fixes of detections at 5-6 / 6-8 / 8-12 cm
    # were 84 / 135 / 202 mm off (median), at 1-2 cm 22 mm; nfp bouncing's MED 27.7 -> 19.6
    # mm for 4.5 points of availability. None: every detection is used (the paper's box
    # reports 5 cm, and is kept). Health counts them (`uncertain_detections`).
    max_range_sigma_m: Annotated[float, msgspec.Meta(gt=0.0, le=10.0)] | None = 0.05
    # Added (per axis, in quadrature) to the covariances a fix reports, not to the filter's:
    # errors no model here carries, correlated over seconds so the filter cannot average them
    # (where on the hull the echo's centre lies, map and mount errors). 15 mm was chosen in
    # issue 11. `capsd bench consistency` (session 20, after the ASV pose's two fixes) derives
    # 7.8 mm on its tuning runs (95 % of NEES under the chi-square bound); on the held-out
    # pond 94.7 % are within the bound with 15 mm, 89.1 % with 7.8 mm (a few far-off fixes),
    # so 15 mm stays until those are understood (issue 24 item 5). Session 35, with the
    # relocation rule: 7.2 mm derived; pond 94.8 % with 15 mm, 88.6 % with 7.2 mm.
    unmodelled_sigma_m: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)] = 0.015
    installation: InstallationConfig = InstallationConfig()
    sound_speed: SoundSpeedConfig = SoundSpeedConfig()
    # The site's fix key (64 hex digits, owner-only; make-site-certs.sh writes fix.key): every
    # fix is tagged with it, and the ROV's bridge acts only on tagged fixes (capsd.signing).
    fix_key: str | None = None


# A pose sample: position, orientation (xyzw), 6 x 6 covariance; a depth: metres, sigma and
# the water's temperature there (NaN: not reported).
PoseSample = tuple[Array, Array, Array]
DepthSample = tuple[float, float, float]


def _lerp_pose(a: PoseSample, b: PoseSample, f: float) -> PoseSample:
    # The uncertainty is the later sample's: the newest that went into the value.
    return a[0] + f * (b[0] - a[0]), quat_slerp(a[1], b[1], f), b[2]


def _lerp_depth(a: DepthSample, b: DepthSample, f: float) -> DepthSample:
    return a[0] + f * (b[0] - a[0]), b[1], a[2] + f * (b[2] - a[2])


def _vec3(v: Array) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def _flat(m: Array) -> tuple[float, ...]:
    return tuple(float(v) for v in m.ravel())


class Locator:
    """Aligned input timelines, the per-ping solver and the tracker: one RovFix per ping."""

    def __init__(self, config: Config):
        self.config = config
        self.method = config.method.resolved()
        self.label: LocatorMethod = (
            "ablation" if self.method.preset == "custom" else self.method.preset
        )
        # H_B_S; on a tilt servo, each ping's (the servo's reported angle added to the pitch,
        # a pan servo's to the yaw).
        self.mount = config.sonar.transform()
        tilt = config.sonar.tilt
        # Each report is where the servos are driven to; they slew there (capsd.servo_motion).
        self.servo_motion = ServoMotion(config.sonar)
        self.tilts: Timeline[ServoState] | None = (
            None
            if tilt is None
            else Timeline(
                self.servo_motion.between,
                capacity=int(config.inputs.buffer_s * 100),
                max_extrapolation_ns=int(tilt.max_age_s * 1e9),
            )
        )
        self.aperture_rad = math.radians(config.sonar.vertical_aperture_deg)
        self.lever_arm = (
            np.array(config.rov.pressure_sensor_m)
            if self.method.lever_arm == "correct"
            else np.zeros(3)
        )
        extrap = int(config.inputs.max_extrapolation_s * 1e9)
        buffer_s = config.inputs.buffer_s
        # Each sample keeps its own uncertainty, so a fix uses the one of the samples it used
        # (never whatever arrived last: a replay would then differ).
        self.poses: Timeline[PoseSample] = Timeline(
            _lerp_pose, capacity=int(buffer_s * 200), max_extrapolation_ns=extrap
        )
        self.depths: Timeline[DepthSample] = Timeline(
            _lerp_depth, capacity=int(buffer_s * 100), max_extrapolation_ns=extrap
        )
        self.attitudes: Timeline[Array] = Timeline(
            quat_slerp, capacity=int(buffer_s * 100), max_extrapolation_ns=extrap
        )
        self.tracker = Tracker(config.tracking.settings())
        self.clutter = ClutterMap(config.clutter.settings())
        # Candidates kept from starting a track (learned clutter or the map explains them).
        self.clutter_refusals = 0
        self.map_explained = 0  # candidate echoes the tank's fixtures could have made
        # ... of which moved as no fixture's echo could (they may start a track)
        self.moving_echoes = 0
        self._movers = MovingEchoes(
            config.clutter.moving_settings(),
            beam_model=config.sonar.beam_model,
            half_aperture_rad=self.aperture_rad / 2.0,
        )
        fixtures = () if config.tank is None else config.tank.fixtures
        self._fixture_boxes = fixture_boxes(fixtures, config.clutter.map_margin_m)
        self._installation = config.installation.sigmas()
        # Pings whose ranges were rescaled to the water's speed of sound, and those that stayed
        # the sonar's though the config asks for the thermometer's; the scale last logged.
        self.water_speed_pings = 0
        self.sonar_speed_pings = 0
        self.uncertain_detections = 0  # detections over max_range_sigma_m
        self._logged_scale: float | None = None
        self._installed = np.zeros((3, 3))  # the last fix's installation covariance
        # Where and when the ROV was last seen by a confirmed track (the reacquire and
        # relocation rules), and whether the current track is an unproven relocation.
        self._last_confirmed: LastSeen | None = None
        self.relocation = Relocation(
            config.tracking.relocation_settings(),
            config.clutter.moving_settings(),
            beam_model=config.sonar.beam_model,
            half_aperture_rad=self.aperture_rad / 2.0,
        )
        # Velocities wait here until the ping they precede, so the tracker sees time in order.
        self._velocities: list[tuple[int, Array, Array]] = []
        # Zenoh may run different subscribers' callbacks on different threads at once.
        self._lock = threading.Lock()
        # Inputs stamped before a ping already solved: the fix went without them (a replay,
        # where they come in time, then differs from the live fix).
        self.late_inputs = 0
        self._solved_until_ns = 0

    def _note_arrival(self, stamp_ns: int) -> None:
        if stamp_ns < self._solved_until_ns:
            self.late_inputs += 1

    def pose_covers(self, stamp_ns: int) -> bool:
        """Whether the poses reach the ping at `stamp_ns` (within the extrapolation allowed)."""
        return self._lookup(self.poses, stamp_ns).failure not in ("too_new", "no_samples")

    def on_pose(self, pose: AsvPose) -> None:
        if pose.status == "lost":
            return  # a lost pose is not a pose: fixes needing it are refused as missing
        self._note_arrival(pose.stamp_ns)
        self.poses.add(
            pose.stamp_ns,
            (
                np.array(pose.position_m),
                np.array(pose.orientation_xyzw),
                np.array(pose.covariance).reshape(6, 6),
            ),
        )

    def on_tilt(self, tilt: SonarTilt) -> None:
        """The sonar's servos (taken only where the mount has a tilt; the pan where it has one)."""
        if self.tilts is None:
            return
        self._note_arrival(tilt.stamp_ns)
        pan = tilt.pan_rad if self.config.sonar.pan is not None else 0.0
        newest = self.tilts.latest().value  # a report older than it is taken as it says
        self.tilts.add(
            tilt.stamp_ns, self.servo_motion.report(newest, tilt.stamp_ns, tilt.tilt_rad, pan)
        )

    def on_depth(self, depth: RovDepth) -> None:
        self._note_arrival(depth.stamp_ns)
        # The reading as this boot of the autopilot reports it, plus the surface check's offset.
        corrected = depth.depth_m + self.config.rov.depth_offset_m
        temperature = math.nan if depth.temperature_c is None else depth.temperature_c
        self.depths.add(depth.stamp_ns, (corrected, depth.sigma_m, temperature))

    def on_attitude(self, attitude: RovAttitude) -> None:
        self._note_arrival(attitude.stamp_ns)
        self.attitudes.add(attitude.stamp_ns, np.array(attitude.orientation_xyzw))

    def on_velocity(self, velocity: RovVelocity) -> None:
        sample = (
            velocity.stamp_ns,
            np.array(velocity.velocity_m_s),
            np.array(velocity.covariance_m2_s2).reshape(3, 3),
        )
        with self._lock:
            if len(self._velocities) < 1000:  # bounded: without pings nothing drains it
                self._velocities.append(sample)

    def _fuse_velocities_until(self, stamp_ns: int) -> None:
        self._velocities.sort(key=lambda v: v[0])
        while self._velocities and self._velocities[0][0] <= stamp_ns:
            stamp, velocity, covariance = self._velocities.pop(0)
            self.tracker.update_velocity(stamp, velocity, covariance)

    def _lookup(self, line: Timeline[T], stamp_ns: int) -> Lookup[T]:
        if self.method.matching == "latest":
            return line.latest()
        return line.at(stamp_ns, use="before" if self.method.matching == "causal" else "around")

    def _solve(
        self, detection: Detection, asv: Transform, depth: DepthSample, attitude: Array, cov: Array
    ) -> tuple[Array, Array | None] | str:
        """(position, covariance) of one candidate, or why it is no fix."""
        if self.method.geometry == "paper":
            position = paper_fix(
                sonar_pose=asv.compose(self.mount),
                range_m=detection.range_m,
                azimuth_rad=detection.azimuth_rad,
                depth_m=depth[0],
            )
            if position is None:
                return "no_intersection"
            if self.method.tracking == "per_frame":
                return position, None  # the paper's method: no uncertainty at all
            # The paper's geometry under our tracker (the ablation): the tracker needs a
            # covariance; the exact model's at the same inputs is the honest stand-in.
            exact = self._solve_exact(detection, asv, depth, attitude, cov)
            fix_cov = exact[1] if not isinstance(exact, str) else np.eye(3) * 0.1**2
            return position, fix_cov
        return self._solve_exact(detection, asv, depth, attitude, cov)

    def _solve_exact(
        self, detection: Detection, asv: Transform, depth: DepthSample, attitude: Array, cov: Array
    ) -> tuple[Array, Array] | str:
        result = solve_fix(
            asv_pose=asv,
            sonar_mount=self.mount,
            range_m=detection.range_m,
            azimuth_rad=detection.azimuth_rad,
            rov_z_m=rov_centre_z(depth[0], quat_to_matrix(attitude), self.lever_arm),
            vertical_aperture_rad=self.aperture_rad
            + 2.0 * math.radians(self.config.aperture_skirt_deg),
            beam_model=self.config.sonar.beam_model,
            max_conditioning=self.config.max_conditioning,
            uncertainty=FixUncertainty(
                range_sigma_m=max(detection.range_sigma_m, 1e-4),
                azimuth_sigma_rad=max(detection.azimuth_sigma_rad, 1e-5),
                rov_z_sigma_m=depth[1],
                asv_pose_covariance=cov,
            ),
        )
        if result.position_m is None or result.covariance_m2 is None:
            return result.reason or "no_fix"
        return result.position_m, result.covariance_m2

    def _reacquires(self, stamp: int, position: Array) -> bool:
        """Whether a map-explained echo lies where the ROV was last confirmed (may restart)."""
        if self._last_confirmed is None:
            return False
        elapsed_s = (stamp - self._last_confirmed.stamp_ns) / 1e9
        if not 0.0 <= elapsed_s <= self.config.clutter.reacquire_window_s:
            return False
        return self.relocation.reachable(stamp, position, self._last_confirmed)

    def _track(
        self,
        stamp: int,
        usable: list[tuple[Array, Array]],
        may_start: list[bool],
        static: list[bool],
    ) -> Association:
        """The tracker's update, under the relocation rule (capsd.services.locator.relocation)."""
        last = self._last_confirmed
        if self.config.tracking.relocation == "off":
            return self.tracker.update(stamp, usable, may_start=may_start, static=static)
        if self.relocation.active:
            # The ROV reappearing where it could be wins over an unproven far track; not the
            # track's own echo, which the reach, growing with the time since, may come to hold.
            own = self.tracker.gated(stamp, usable)
            near = [
                i
                for i, (p, _) in enumerate(usable)
                if may_start[i] and not own[i] and self.relocation.reachable(stamp, p, last)
            ]
            if near:
                best = min(near, key=lambda i: float(np.trace(usable[i][1])))
                self.tracker.restart(stamp, *usable[best])
                self.relocation.take_over()
                return Association(best, None, reinitialised=True)
        association = self.tracker.update(stamp, usable, may_start=may_start, static=static)
        if association.reinitialised and association.index is not None:
            if self.relocation.reachable(stamp, usable[association.index][0], last):
                self.relocation.end()
            else:
                self.relocation.begin(stamp)
        return association

    def _learn_clutter(
        self,
        stamp: int,
        usable: list[tuple[Array, Array]],
        taken: int | None,
        track_m: Array | None,
    ) -> None:
        """Candidates away from a confirmed, fresh track are not the ROV: remember where."""
        if track_m is None or self.tracker.state != "tracking" or not self.tracker.confirmed:
            return
        clear = self.config.clutter.clear_of_track_m
        for i, (position, _) in enumerate(usable):
            if i != taken and float(np.linalg.norm(position[:2] - track_m[:2])) > clear:
                self.clutter.observe(stamp, position)

    def counters(self) -> dict[str, int]:
        """Health counters (Zenoh's thread: under the lock the pings take)."""
        with self._lock:
            return {
                "late_inputs": self.late_inputs,
                "clutter_refusals": self.clutter_refusals,
                "track_manoeuvres": self.tracker.manoeuvres,
                "static_clutter_cells": self.clutter.static_cells(self._solved_until_ns),
                "map_explained_echoes": self.map_explained,
                "moving_map_explained_echoes": self.moving_echoes,
                "relocations": self.relocation.started,
                "relocations_moved": self.relocation.proven_moving,
                "relocations_waited": self.relocation.proven_waiting,
                "relocations_taken_over": self.relocation.taken_over,
                "water_speed_pings": self.water_speed_pings,
                "uncertain_detections": self.uncertain_detections,
                "sonar_speed_pings": self.sonar_speed_pings,
            }

    def locate(self, detections: SonarDetections, *, seq: int) -> RovFix:
        """The fix for one ping, tracked; an invalid RovFix says why there is none."""
        with self._lock:
            self._solved_until_ns = max(self._solved_until_ns, detections.stamp_ns)
            return self._locate(detections, seq=seq)

    def _locate(self, detections: SonarDetections, *, seq: int) -> RovFix:
        stamp = detections.stamp_ns
        out = RovFix(stamp_ns=stamp, seq=seq, method=self.label, quality="invalid")
        offset = self.config.sonar.range_offset_m
        candidates = [
            d if offset == 0.0 else msgspec.structs.replace(d, range_m=d.range_m + offset)
            for d in detections.detections
            if d.confidence >= self.config.min_confidence and d.range_m + offset > 0.0
        ]
        limit = self.config.max_range_sigma_m
        uncertain_dropped = False
        if limit is not None:
            kept = [d for d in candidates if d.range_sigma_m <= limit]
            uncertain_dropped = len(kept) < len(candidates)
            self.uncertain_detections += len(candidates) - len(kept)
            candidates = kept
        pose = self._lookup(self.poses, stamp)
        depth = self._lookup(self.depths, stamp)
        attitude = self._lookup(self.attitudes, stamp)
        installation = self._installation
        if depth.value is not None and self.config.sound_speed.source == "rov_thermometer":
            rescaled = self._rescale(candidates, detections.sound_speed_m_s, depth.value[2])
            if rescaled is None:
                self.sonar_speed_pings += 1
            else:
                candidates, installation = rescaled
        out = msgspec.structs.replace(
            out,
            candidates=len(candidates),
            asv_pose_stamp_ns=pose.stamp_ns,
            depth_stamp_ns=depth.stamp_ns,
            attitude_stamp_ns=attitude.stamp_ns,
        )
        reasons: list[str] = []
        fixes: list[tuple[Array, Array | None, Detection]] = []
        sonar: Transform | None = None
        if not candidates:
            reasons.append("detection_uncertain" if uncertain_dropped else "no_detection")
        inputs: list[tuple[str, Lookup[Any]]] = [
            ("asv_pose", pose),
            ("depth", depth),
            ("attitude", attitude),
        ]
        tilted = True
        if self.tilts is not None:
            # A ping without the servo's angle is no fix (its elevation would be a guess).
            tilt = self._lookup(self.tilts, stamp)
            inputs.append(("sonar_tilt", tilt))
            tilted = tilt.value is not None
            if tilt.value is not None:
                self.mount = self.config.sonar.transform(
                    tilt_rad=tilt.value.tilt_rad, pan_rad=tilt.value.pan_rad
                )
        for name, lookup in inputs:
            if lookup.failure is not None:
                reasons.append(f"{name}_{lookup.failure}")
        if (
            tilted
            and pose.value is not None
            and depth.value is not None
            and attitude.value is not None
        ):
            asv = Transform(quat_to_matrix(pose.value[1]), pose.value[0])
            sonar = asv.compose(self.mount)
            # A depth extrapolated from its last two readings carries their noise amplified
            # (x2.2 one reading gap past the newest; more when readings are lost on a link).
            depth_m, depth_sigma_m, temperature_c = depth.value
            depth_sample = (depth_m, depth_sigma_m * depth.noise_gain, temperature_c)
            for detection in candidates:
                solved = self._solve(detection, asv, depth_sample, attitude.value, pose.value[2])
                if isinstance(solved, str):
                    reasons.append(solved)
                elif self.config.tank is not None and not self.config.tank.contains(solved[0]):
                    reasons.append("outside_tank")
                else:
                    fixes.append((solved[0], solved[1], detection))
            explained = [
                self._explained(sonar, d, p) and not self._moved(stamp, sonar, d, p)
                for p, _, d in fixes
            ]
            installed = [
                self._installation_cov(asv, d, depth_sample, attitude.value, p, installation)
                for p, _, d in fixes
            ]
        else:
            explained, installed = [], []
        return self._finish(out, stamp, fixes, reasons, explained, installed, sonar)

    def _rescale(
        self, candidates: list[Detection], assumed_m_s: float | None, temperature_c: float
    ) -> tuple[list[Detection], InstallationSigmas] | None:
        """The candidates' ranges in the water's speed of sound, and what is then still unknown.

        None where the ping does not say what speed the sonar assumed, the depth readings carry
        no temperature, or the temperature is outside the equation's range.
        """
        water = self.config.sound_speed
        if assumed_m_s is None or math.isnan(temperature_c):
            return None
        try:
            speed = speed_of_sound_m_s(temperature_c, salinity_ppt=water.salinity_ppt)
        except SoundSpeedError:
            return None
        scale = speed / assumed_m_s
        self.water_speed_pings += 1
        if self._logged_scale is None or abs(scale - self._logged_scale) > LOG_SCALE_CHANGE:
            self._logged_scale = scale
            logger.info(
                "ranges rescaled to the water's speed of sound",
                extra=log_fields(
                    scale_ppm=round((scale - 1.0) * 1e6),
                    temperature_c=round(temperature_c, 2),
                    water_m_s=round(speed, 1),
                    sonar_m_s=round(assumed_m_s, 1),
                ),
            )
        left = relative_sigma(
            temperature_c,
            salinity_ppt=water.salinity_ppt,
            temperature_sigma_c=water.thermometer_sigma_c,
            salinity_sigma_ppt=water.salinity_sigma_ppt,
        )
        rescaled = [
            msgspec.structs.replace(
                d,
                range_m=d.range_m * scale,
                range_sigma_m=d.range_sigma_m * scale,
                range_extent_m=d.range_extent_m * scale,
            )
            for d in candidates
        ]
        return rescaled, dataclasses.replace(self._installation, range_scale=left)

    def _installation_cov(
        self,
        asv: Transform,
        detection: Detection,
        depth: DepthSample,
        attitude: Array,
        at: Array,
        sigmas: InstallationSigmas,
    ) -> Array:
        """The fix's covariance from what the installation may still get wrong (0 if nothing)."""
        if not sigmas.any:
            return np.zeros((3, 3))
        sonar = asv.compose(self.mount)
        elevation = to_polar(self.config.sonar.beam_model, sonar.inverse().apply(at))[2]
        try:
            return installation_covariance(
                asv_pose=asv,
                sonar_mount=self.mount,
                range_m=detection.range_m,
                azimuth_rad=detection.azimuth_rad,
                rov_z_m=rov_centre_z(depth[0], quat_to_matrix(attitude), self.lever_arm),
                model=self.config.sonar.beam_model,
                elevation_rad=elevation,
                sigmas=sigmas,
            )
        except ArithmeticError:  # grazing geometry: the solver's own covariance says so
            return np.zeros((3, 3))

    def _explained(self, sonar: Transform, detection: Detection, position: Array) -> bool:
        """Whether a mapped fixture shares this echo's range cell (capsd.echo_cell)."""
        if self.config.clutter.map_explained == "off" or not len(self._fixture_boxes[0]):
            return False
        own = to_polar(self.config.sonar.beam_model, sonar.inverse().apply(position))[2]
        points = cell_points(
            sonar,
            range_m=detection.range_m,
            azimuth_rad=detection.azimuth_rad,
            beam_model=self.config.sonar.beam_model,
            vertical_aperture_rad=self.aperture_rad,
            half_width_m=self.config.clutter.map_margin_m,
            skip_elevation_rad=own,
        )
        found = any_inside(points, self._fixture_boxes)
        self.map_explained += int(found)
        return found

    def _moved(self, stamp: int, sonar: Transform, detection: Detection, position: Array) -> bool:
        """Whether a map-explained echo has moved as no fixture's could (it may then start)."""
        if self.config.clutter.map_explained != "refuse_unless_moving":
            return False
        moved = self._movers.observe(
            stamp,
            sonar,
            range_m=detection.range_m,
            azimuth_rad=detection.azimuth_rad,
            position_m=position,
        )
        self.moving_echoes += int(moved)
        return moved

    def _finish(
        self,
        out: RovFix,
        stamp: int,
        fixes: list[tuple[Array, Array | None, Detection]],
        reasons: list[str],
        explained: list[bool],
        installed: list[Array],
        sonar: Transform | None,
    ) -> RovFix:
        reason = ",".join(sorted(set(reasons))) or None
        if self.method.tracking == "per_frame":
            if not fixes:
                return msgspec.structs.replace(out, no_fix_reason=reason)
            position, covariance, _ = max(fixes, key=lambda f: f[2].confidence)
            return msgspec.structs.replace(
                out,
                quality="good",
                raw_position_m=_vec3(position),
                raw_covariance_m2=None if covariance is None else _flat(covariance),
            )
        usable = [(p, c) for p, c, _ in fixes if c is not None]
        echoes = [d for _, c, d in fixes if c is not None]
        by_map = [e for (_, c, _), e in zip(fixes, explained, strict=True) if c is not None]
        by_install = [i for (_, c, _), i in zip(fixes, installed, strict=True) if c is not None]
        self._fuse_velocities_until(stamp)
        learning = self.config.clutter.mode == "learn"
        static = [learning and self.clutter.is_static(stamp, p) for p, _ in usable]
        may_start = [
            not learned and (not mapped or self._reacquires(stamp, p))
            for (p, _), learned, mapped in zip(usable, static, by_map, strict=True)
        ]
        association = self._track(stamp, usable, may_start, static)
        if association.index is not None and sonar is not None:
            echo = echoes[association.index]
            self.relocation.observe(
                stamp,
                sonar,
                range_m=echo.range_m,
                azimuth_rad=echo.azimuth_rad,
                position_m=usable[association.index][0],
            )
        estimate = self.tracker.estimate()
        if estimate.state in ("none", "lost"):
            self.relocation.end()
        unproven = self.relocation.active
        if (
            association.index is not None
            and estimate.state == "tracking"
            and estimate.position_m is not None
            and estimate.velocity_m_s is not None
            and not unproven
        ):
            self._last_confirmed = LastSeen(stamp, estimate.position_m, estimate.velocity_m_s)
        if learning and not unproven:
            self._learn_clutter(stamp, usable, association.index, estimate.position_m)
        raw = usable[association.index] if association.index is not None else None
        if raw is None and usable:
            if estimate.state in ("none", "lost") and not any(may_start):
                self.clutter_refusals += len(usable)
                reason = "map_clutter" if any(by_map) else "static_clutter"
            else:
                reason = "outside_gate"
        if association.index is not None:
            # Held for a coasted estimate: the installation's errors do not go away with it.
            self._installed = by_install[association.index]
        floor = np.eye(3) * self.config.unmodelled_sigma_m**2 + self._installed
        if raw is not None:
            out = msgspec.structs.replace(
                out, raw_position_m=_vec3(raw[0]), raw_covariance_m2=_flat(raw[1] + floor)
            )
        out = msgspec.structs.replace(
            out,
            no_fix_reason=None if raw is not None else reason,
            # An unproven relocation is reported as the new track it is.
            track_state="tentative"
            if unproven and estimate.state == "tracking"
            else estimate.state,
            track_resets=estimate.resets,
        )
        if estimate.position_m is None or estimate.covariance_m2 is None:
            return out
        assert estimate.velocity_m_s is not None
        # Only a measured, gated update of a confirmed track is "good"; a coasted prediction,
        # a tentative track or an unproven relocation is honest but "unsure".
        quality: Literal["good", "unsure"] = (
            "good"
            if estimate.state == "tracking" and raw is not None and not unproven
            else "unsure"
        )
        return msgspec.structs.replace(
            out,
            quality=quality,
            position_m=_vec3(estimate.position_m),
            velocity_m_s=_vec3(estimate.velocity_m_s),
            covariance_m2=_flat(estimate.covariance_m2 + floor),
        )


def main(config: Config) -> int:
    """Run the locator until stopped."""
    locator = Locator(config)
    signer = (
        None if config.fix_key is None else SiteKey.load(Path(config.fix_key), config_key="fix_key")
    )
    with ServiceRunner("locator", config) as runner:
        fixes: Publisher[RovFix] = runner.publisher(topics.ROV_FIX, signer=signer)
        stage = runner.latency("fix")  # detections arrival to fix put
        runner.add_counters(locator.counters)

        def locate(detections: SonarDetections, received_ns: int) -> None:
            fixes.put(locator.locate(detections, seq=fixes.next_seq()))
            stage.record_ns(time.time_ns() - received_ns)

        wait = PoseWait(
            wait_s=config.inputs.pose_wait_s, covered=locator.pose_covers, release=locate
        )

        def on_detections(detections: SonarDetections) -> None:
            received_ns = runner.received_ns()
            wait.offer(detections, now_s=time.monotonic(), received_ns=received_ns)

        def on_pose(pose: AsvPose) -> None:
            locator.on_pose(pose)
            wait.poll(time.monotonic())

        runner.add_counters(lambda: {"pings_waited_for_pose": wait.waited,
                                     "pings_waited_in_vain": wait.expired})  # fmt: skip
        asv, rov = config.inputs.asv_vehicle, config.inputs.rov_vehicle
        runner.subscribe(topics.ASV_POSE, on_pose, vehicle=asv)
        runner.subscribe(topics.ROV_DEPTH, locator.on_depth, vehicle=rov)
        runner.subscribe(topics.ROV_ATTITUDE, locator.on_attitude, vehicle=rov)
        runner.subscribe(topics.ROV_VELOCITY, locator.on_velocity, vehicle=rov)
        runner.subscribe(topics.SONAR_DETECTIONS, on_detections, vehicle=asv)
        if config.sonar.tilt is not None:
            runner.subscribe(topics.SONAR_TILT, locator.on_tilt, vehicle=asv)
        logger.info("locator ready", extra={"fields": {"method": locator.label}})
        runner.run(lambda: wait.poll(time.monotonic()), period_s=0.02)
    return 0
