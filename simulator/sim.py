"""The simulation: world and sensors as one time-ordered stream of bus payloads.

The same stream feeds the real-time service (paced by the wall clock) and offline datasets (as
fast as the CPU allows): for one seed both produce the same measurements. Every sensor draws
from its own random stream (spawned from the seed), so turning one stream off does not change
the others.

Stamps: sensor payloads carry their vehicle's clock (ASV: IMU, LiDAR, sonar, ASV pose; ROV:
depth, attitude, velocity); ground truth carries true time; a ping's label carries the frame's
stamp and ping id, so it joins the frame, its detections and the locator's fix.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import msgspec
import numpy as np

from capsd import topics
from capsd.geometry import Array, Transform, matrix_to_euler_zyx, matrix_to_quat
from capsd.payloads import (
    AsvPose,
    Detection,
    GhostEcho,
    GroundTruth,
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
from capsd.simulator.clock import VehicleClock
from capsd.simulator.config import Config
from capsd.simulator.guided import AsvLimits, GuidedAsv, GuidedLimits, GuidedRov
from capsd.simulator.imu import Imu
from capsd.simulator.install_errors import InstallErrors
from capsd.simulator.lidar import scan
from capsd.simulator.scene import BLUEROV2_SEMI_AXES, Ellipsoid
from capsd.simulator.sonar import Label, SonarRenderer
from capsd.simulator.tilt_servo import TiltServo
from capsd.simulator.world import (
    AsvMotion,
    RovMotion,
    RovState,
    asv_motion,
    floating,
    hovering,
    profile_depths,
    profile_span,
    profiling,
    rov_motion,
    symmetric_standoff_m,
    with_look,
)
from capsd.sonar_geometry import to_polar
from capsd.sound_speed import speed_of_sound_m_s
from capsd.topics import Topic


@dataclass(frozen=True)
class Event:
    """One payload at sim time `t_s`, for `topic` under `vehicle`."""

    t_s: float
    topic: Topic[Any]
    vehicle: str
    payload: Payload


def _vec3(v: Array) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def _quat(m: Array) -> tuple[float, float, float, float]:
    q = matrix_to_quat(m)
    return (float(q[0]), float(q[1]), float(q[2]), float(q[3]))


def _flat(m: Array) -> tuple[float, ...]:
    return tuple(float(v) for v in m.ravel())


_STREAMS = ("imu", "lidar", "pose", "depth", "attitude", "velocity", "sonar")


class Simulation:
    """Deterministic world and sensors for one config; `events()` yields what the bus carries."""

    def __init__(self, config: Config, *, horizon_s: float | None = None):
        self.config = config
        self.horizon_s = horizon_s or config.motion_horizon_s
        seeds = np.random.SeedSequence(config.seed).spawn(len(_STREAMS) + 3)
        self.rng = {
            name: np.random.default_rng(s) for name, s in zip(_STREAMS, seeds, strict=False)
        }
        clock_rng = np.random.default_rng(seeds[-1])
        self.tank = config.world_tank()
        look = config.look()
        if look is not None:
            look_seed = config.sonar_image.look_seed
            seed = config.seed if look_seed is None else look_seed
            self.tank = with_look(self.tank, look, np.random.default_rng([seed, 0xC1]))
        self.rov: RovMotion = rov_motion(
            self.tank,
            config.trajectory,
            speed_m_s=config.rov_speed_m_s,
            duration_s=self.horizon_s,
            seed=config.seed,
        )
        # What the ASV faces (and the boresight's depth): the trajectory, or, for a ROV flown
        # live, the ROV where it starts.
        planned = self.rov
        self.guided: GuidedRov | None = None
        if config.guided is not None:
            start = config.guided.start_m
            start_m = np.array(start) if start is not None else self.rov.track.p[0]
            self.guided = GuidedRov(
                start_m, limits=GuidedLimits(max_speed_m_s=config.guided.max_speed_m_s)
            )
            planned = hovering(start_m)
        # The world's mounts are the nominal ones (what the services are told) plus this run's
        # installation errors; the errors' own generator leaves every other stream as it was.
        install_seed = config.install_errors.seed
        self.errors = InstallErrors.draw(
            config.install_errors,
            np.random.default_rng([config.seed if install_seed is None else install_seed, 0xE7]),
        )
        self.mount = config.sonar.transform().compose(self.errors.sonar)
        # A sonar on a tilt servo: the ArduRover stand-in drives it (the mount's pitch it
        # reports at the servo's zero is the nominal pitch's, MAVLink's sign).
        self.tilt_servo = (
            None
            if config.sonar.tilt is None
            else TiltServo(
                config.sonar.tilt, zero_pitch_deg=-config.sonar.pitch_deg, pan=config.sonar.pan
            )
        )
        if config.rov_mode == "parked":
            self.rov = planned = hovering(self.rov.track.p[0], duration_s=self.horizon_s)
        elif config.rov_mode == "profile":
            top, bottom = profile_depths(self.tank)
            if config.asv_standoff_m is not None:
                # Planned on the nominal mount, as a team would: the aperture's edges from
                # the given distance, whatever depths they fall at.
                nominal = config.sonar
                top, bottom = profile_span(
                    self.tank,
                    distance_m=config.asv_standoff_m - nominal.position_m[0],
                    sonar_z_m=nominal.position_m[2],
                    pitch_rad=math.radians(nominal.pitch_deg),
                    half_aperture_rad=math.radians(0.5 * nominal.vertical_aperture_deg),
                    rov_half_height_m=float(BLUEROV2_SEMI_AXES[2]),
                )
            self.rov = planned = profiling(
                self.rov.track.p[0],
                top_z_m=top,
                bottom_z_m=bottom,
                duration_s=self.horizon_s,
                period_s=config.profile_period_s,
            )
        elif config.rov_mode == "surface":
            waves = config.waves.waves()
            self.rov = floating(
                self.rov.track.p[0],
                depth_m=config.rov.float_depth_m + self.errors.float_trim_m,
                heave_m=waves.heave_m,
                period_s=waves.heave_period_s,
                duration_s=self.horizon_s,
            )
        standoff = config.asv_standoff_m
        if standoff is None and config.rov_mode == "profile":
            # The ROV's top and bottom as far above the boresight as below it.
            top, bottom = profile_depths(self.tank)
            standoff = symmetric_standoff_m(
                float(self.mount.translation[2]) - top,  # W's z is up: heights below the sonar
                float(self.mount.translation[2]) - bottom,
                pitch_rad=math.radians(config.sonar.pitch_deg),
            ) + float(self.mount.translation[0])
        elif standoff is None:
            # Put the ROV on the boresight at its trajectory's mean depth.
            height = -float(np.mean(planned.track.p[:, 2])) + float(-self.mount.translation[2])
            pitch = max(math.radians(config.sonar.pitch_deg), math.radians(5.0))
            standoff = height / math.tan(pitch) + float(self.mount.translation[0])
        self.asv: AsvMotion | GuidedAsv
        self.guided_asv: GuidedAsv | None = None
        if config.asv_guided is not None:
            # Driven live: it starts where a stationary one would stand, facing the same way.
            still = asv_motion(
                self.tank,
                planned,
                mode="stationary",
                standoff_m=standoff,
                waves=config.waves.waves(),
                start_xy=config.asv_start_xy,
            )
            g = config.asv_guided
            start = still.track.p[0]
            yaw = (
                still.yaw_at(0.0)
                if g.start_heading_deg is None
                else math.radians(g.start_heading_deg)
            )
            self.asv = self.guided_asv = GuidedAsv(
                (float(start[0]), float(start[1])),
                yaw,
                waves=config.waves.waves(),
                mode=g.mode,
                limits=AsvLimits(max_speed_m_s=g.max_speed_m_s, drive=g.drive),
            )
        else:
            self.asv = asv_motion(
                self.tank,
                planned,
                mode="stationary" if config.asv_mode == "guided" else config.asv_mode,
                standoff_m=standoff,
                waves=config.waves.waves(),
                start_xy=config.asv_start_xy,
            )
        self.sonar_model = config.sonar_model()
        self.renderer = (
            SonarRenderer(self.sonar_model, self.tank)
            if (config.streams.sonar_frames == "on")
            else None
        )
        self.lidar_model = config.lidar_model()
        self.lidar_mount = config.lidar_mount().compose(self.errors.lidar)
        self.imu = Imu(
            config.imu_model(), config.imu_mounting().rotation, np.random.default_rng(seeds[-2])
        )
        self.lever_arm = np.array(config.rov.pressure_sensor_m) + self.errors.pressure_arm_m
        # The water's true speed of sound, and the one the sonar assumes (and reports).
        self.sound_speed_m_s = speed_of_sound_m_s(
            config.water_temperature_c, salinity_ppt=config.water_salinity_ppt
        )
        self.sonar_sound_speed_m_s = self.sound_speed_m_s / self.errors.sound_speed_scale
        self._clock_rng = clock_rng
        self._seq: dict[str, int] = {}
        # Real time only: says whether a ping at sim time t is already too late to render
        # (the world cannot keep up); such pings are skipped and counted, never sent late.
        self.too_late: Callable[[float], bool] | None = None
        self.skipped_pings = 0

    # ------------------------------------------------------------------ state

    def _wrap(self, t_s: float) -> float:
        return t_s % self.horizon_s

    def rov_state(self, t_s: float) -> RovState:
        if self.guided is not None:
            return self.guided.state(t_s)  # flown live: no repeat
        return self.rov.state(self._wrap(t_s))

    def _asv_time(self, t_s: float) -> float:
        return t_s if self.guided_asv is not None else self._wrap(t_s)  # live: no repeat

    def asv_pose(self, t_s: float) -> Transform:
        rotation, translation = self.asv.pose(self._asv_time(t_s))
        return Transform(rotation, translation)

    def sonar_mount(self, t_s: float, asv: Transform) -> Transform:
        """H_B_S at `t_s`, the ASV at `asv`: the mount, its servo's angle, this run's error."""
        if self.tilt_servo is None:
            return self.mount
        hull_pitch = matrix_to_euler_zyx(asv.rotation)[1]
        tilt = self.tilt_servo.tilt_rad(t_s, hull_pitch_rad=hull_pitch)
        pan = self.tilt_servo.pan_rad(t_s)
        return self.config.sonar.transform(tilt_rad=tilt, pan_rad=pan).compose(self.errors.sonar)

    def _rov_ellipsoid(self, rov: RovState) -> Ellipsoid:
        return Ellipsoid(rov.position_m, rov.rotation, BLUEROV2_SEMI_AXES)

    def _next_seq(self, stream: str) -> int:
        seq = self._seq.get(stream, 0)
        self._seq[stream] = seq + 1
        return seq

    # ------------------------------------------------------------------ the stream

    def labelled_pings(
        self, *, start_ns: int, duration_s: float, from_s: float = 0.0
    ) -> Iterator[tuple[float, SonarFrame, SonarLabel]]:
        """(sim time, frame, its label) for every ping: what detector training and scoring read.

        With `from_s`, the pings of sim time `from_s` to `from_s + duration_s` alone (the
        vehicles' paths are functions of time; no other stream is made).
        """
        if from_s > 0.0:
            yield from self._pings_from(start_ns=start_ns, from_s=from_s, duration_s=duration_s)
            return
        frame: SonarFrame | None = None
        for event in self.events(start_ns=start_ns, duration_s=duration_s):
            payload = event.payload
            if isinstance(payload, SonarFrame):
                frame = payload
            elif isinstance(payload, SonarLabel) and frame is not None:
                if payload.stamp_ns == frame.stamp_ns:
                    yield event.t_s, frame, payload
                frame = None

    def _clocks(self, start_ns: int) -> dict[str, VehicleClock]:
        """Each vehicle's clock, true time `start_ns` at sim time 0."""
        return {
            "asv": VehicleClock(self.config.clocks.asv.model(), start_ns, self._clock_rng),
            "rov": VehicleClock(self.config.clocks.rov.model(), start_ns, self._clock_rng),
        }

    def _pings_from(
        self, *, start_ns: int, from_s: float, duration_s: float
    ) -> Iterator[tuple[float, SonarFrame, SonarLabel]]:
        clocks = self._clocks(start_ns)
        period = 1.0 / self.config.rates.sonar_hz
        k = math.ceil(from_s / period)
        while k * period <= from_s + duration_s:
            t = k * period
            k += 1
            frame: SonarFrame | None = None
            for event in self._emit_sonar(t, start_ns + round(t * 1e9), clocks):
                if isinstance(event.payload, SonarFrame):
                    frame = event.payload
                elif isinstance(event.payload, SonarLabel) and frame is not None:
                    yield t, frame, event.payload

    def events(self, *, start_ns: int, duration_s: float | None = None) -> Iterator[Event]:
        """Every payload in time order from sim time 0; true time is `start_ns` + sim time."""
        cfg = self.config
        clocks = self._clocks(start_ns)
        periods: dict[str, float] = {
            "pose": 1.0 / cfg.rates.asv_pose_hz if cfg.streams.asv_pose_truth_noise == "on" else 0,
            "depth": 1.0 / cfg.rates.depth_hz,
            "attitude": 1.0 / cfg.rates.attitude_hz,
            "velocity": 1.0 / cfg.rates.velocity_hz if cfg.rates.velocity_hz > 0 else 0.0,
            "imu": 1.0 / cfg.imu.rate_hz if cfg.streams.imu == "on" else 0.0,
            "lidar": 1.0 / cfg.lidar.rate_hz if cfg.streams.lidar == "on" else 0.0,
            "sonar": 1.0 / cfg.rates.sonar_hz,
        }
        # Ties at the same instant: inputs first, the ping (which needs them) last.
        due = [(0.0, rank, name) for rank, name in enumerate(periods) if periods[name] > 0.0]
        heapq.heapify(due)
        counts = dict.fromkeys(periods, 0)
        while due:
            t, rank, name = heapq.heappop(due)
            if duration_s is not None and t > duration_s:
                return
            counts[name] += 1
            heapq.heappush(due, (counts[name] * periods[name], rank, name))
            true_ns = start_ns + round(t * 1e9)
            yield from getattr(self, f"_emit_{name}")(t, true_ns, clocks)

    # ------------------------------------------------------------------ sensors

    def _emit_imu(self, t: float, true_ns: int, clocks: dict[str, VehicleClock]) -> Iterator[Event]:
        gyro, accel = self.imu.sample(
            self._asv_time(t),
            lambda s: self.asv.pose(s)[0],
            self.asv.acceleration(self._asv_time(t)),
            self.rng["imu"],
        )
        yield Event(
            t,
            topics.ASV_IMU,
            self.config.asv_vehicle,
            ImuSample(
                stamp_ns=clocks["asv"].stamp(true_ns),
                seq=self._next_seq("imu"),
                angular_velocity_rad_s=_vec3(gyro),
                linear_acceleration_m_s2=_vec3(accel),
            ),
        )

    def _emit_lidar(
        self, t: float, true_ns: int, clocks: dict[str, VehicleClock]
    ) -> Iterator[Event]:
        m = self.lidar_model
        scanner = self.asv_pose(t).compose(self.lidar_mount)
        ranges = scan(m, scanner, self.tank, self.rng["lidar"])
        yield Event(
            t,
            topics.ASV_SCAN,
            self.config.asv_vehicle,
            LidarScan(
                stamp_ns=clocks["asv"].stamp(true_ns),
                seq=self._next_seq("lidar"),
                angle_min_rad=m.angle_min_rad,
                angle_increment_rad=m.angle_increment_rad,
                time_increment_s=m.scan_time_s / 1080.0,
                range_min_m=m.range_min_m,
                range_max_m=m.range_max_m,
                ranges_m=tuple(float(r) for r in ranges),
            ),
        )

    def _emit_pose(
        self, t: float, true_ns: int, clocks: dict[str, VehicleClock]
    ) -> Iterator[Event]:
        noise = self.config.noise
        asv = self.asv_pose(t)
        noisy = asv.translation + self.rng["pose"].normal(0.0, noise.pose_sigma_m, 3)
        var = noise.pose_sigma_m**2
        cov = _flat(np.diag([var, var, var] + [math.radians(0.1) ** 2] * 3))
        yield Event(
            t,
            topics.SIM_ASV_POSE,
            self.config.vehicle,
            AsvPose(
                stamp_ns=clocks["asv"].stamp(true_ns),
                seq=self._next_seq("pose"),
                position_m=_vec3(noisy),
                orientation_xyzw=_quat(asv.rotation),
                covariance=cov,
                source="sim",
            ),
        )

    def _emit_depth(
        self, t: float, true_ns: int, clocks: dict[str, VehicleClock]
    ) -> Iterator[Event]:
        rov = self.rov_state(t)
        sensor_z = float(rov.position_m[2] + (rov.rotation @ self.lever_arm)[2])
        sigma = self.config.noise.depth_sigma_m
        depth = self.errors.depth_reading(-sensor_z, t, float(self.rng["depth"].normal(0.0, sigma)))
        yield Event(
            t,
            topics.ROV_DEPTH,
            self.config.rov_vehicle,
            RovDepth(
                stamp_ns=clocks["rov"].stamp(true_ns),
                seq=self._next_seq("depth"),
                depth_m=depth,
                pressure_pa=101_325.0 + depth * 1000.0 * 9.80665,
                # As MAVLink carries it: centi-degrees.
                temperature_c=round(
                    self.config.water_temperature_c + self.errors.rov_thermometer_bias_c, 2
                ),
                sigma_m=max(sigma, 1e-4),
            ),
        )

    def _emit_attitude(
        self, t: float, true_ns: int, clocks: dict[str, VehicleClock]
    ) -> Iterator[Event]:
        rov = self.rov_state(t)
        yield Event(
            t,
            topics.ROV_ATTITUDE,
            self.config.rov_vehicle,
            RovAttitude(
                stamp_ns=clocks["rov"].stamp(true_ns),
                seq=self._next_seq("attitude"),
                orientation_xyzw=_quat(
                    self.errors.attitude_reading(rov.rotation, self.rng["attitude"])
                ),
            ),
        )

    def _emit_velocity(
        self, t: float, true_ns: int, clocks: dict[str, VehicleClock]
    ) -> Iterator[Event]:
        rov = self.rov_state(t)
        sigma = self.config.noise.velocity_sigma_m_s
        measured = rov.velocity_m_s + self.rng["velocity"].normal(0.0, sigma, 3)
        yield Event(
            t,
            topics.ROV_VELOCITY,
            self.config.rov_vehicle,
            RovVelocity(
                stamp_ns=clocks["rov"].stamp(true_ns),
                seq=self._next_seq("velocity"),
                velocity_m_s=_vec3(measured),
                covariance_m2_s2=_flat(np.eye(3) * max(sigma, 1e-4) ** 2),
            ),
        )

    def _emit_sonar(
        self, t: float, true_ns: int, clocks: dict[str, VehicleClock]
    ) -> Iterator[Event]:
        cfg = self.config
        if self.too_late is not None and self.too_late(t):
            self.skipped_pings += 1
            return
        rov = self.rov_state(t)
        asv = self.asv_pose(t)
        sonar_pose = asv.compose(self.sonar_mount(t, asv))
        stamp = clocks["asv"].stamp(true_ns)
        ping = self._next_seq("sonar")
        dropped = any(start <= t < end for start, end in cfg.sonar_dropouts_s)
        if self.renderer is not None:
            rendered = self.renderer.render(
                sonar_pose, None if dropped else self._rov_ellipsoid(rov), self.rng["sonar"]
            )
            label = rendered.label
            frame = self.renderer.frame(rendered, stamp_ns=stamp, seq=ping, ping_id=ping)
            # The sonar turns echo time into range with the speed it assumes (and reports it):
            # every range it gives is the true one divided by (true speed / assumed speed).
            scale = self.errors.sound_speed_scale
            frame = msgspec.structs.replace(
                frame,
                range_start_m=frame.range_start_m / scale,
                range_resolution_m=frame.range_resolution_m / scale,
                sound_speed_m_s=self.sonar_sound_speed_m_s,
            )
            yield Event(t, topics.SONAR_FRAME, cfg.asv_vehicle, frame)
        else:
            label = self._geometric_label(sonar_pose, rov, dropped)
        if dropped and self.renderer is not None:
            # The ROV was hidden from the image; the label still says where it truly was.
            label = self._geometric_label(sonar_pose, rov, dropped=True)
        # In the sonar's range units, as the frame is (the truth position stays on the label).
        label = label.as_reported(self.errors.sound_speed_scale)
        yield Event(t, topics.SIM_LABEL, cfg.vehicle, self._label_payload(stamp, ping, label, rov))
        if cfg.streams.detections_truth_noise == "on":
            found = self._truth_detection(label)
            yield Event(
                t,
                topics.SIM_DETECTIONS,
                cfg.vehicle,
                SonarDetections(
                    stamp_ns=stamp,
                    seq=ping,
                    ping_id=ping,
                    detector="sim_truth_noise",
                    detections=(found,) if found is not None else (),
                    sound_speed_m_s=self.sonar_sound_speed_m_s,
                ),
            )
        yield Event(
            t,
            topics.SIM_TRUTH,
            cfg.vehicle,
            GroundTruth(
                stamp_ns=true_ns,
                seq=self._next_seq("truth"),
                asv_position_m=_vec3(asv.translation),
                asv_orientation_xyzw=_quat(asv.rotation),
                rov_position_m=_vec3(rov.position_m),
                rov_orientation_xyzw=_quat(rov.rotation),
                rov_velocity_m_s=_vec3(rov.velocity_m_s),
            ),
        )

    def _geometric_label(self, sonar_pose: Transform, rov: RovState, dropped: bool) -> Label:
        """The label without rays: truth polar position; visible when in the fan (and shown)."""
        m = self.sonar_model
        p_s = sonar_pose.inverse().apply(rov.position_m)
        r, azimuth, elevation = to_polar(m.beam_model, p_s)
        inside = (
            p_s[0] > 0.0
            and r < m.range_max_m
            and abs(azimuth) <= m.half_fov_rad
            and abs(elevation) <= m.vertical_aperture_rad / 2.0
        )
        nan = float("nan")
        return Label(
            inside and not dropped, r, azimuth, elevation, nan, nan, nan, nan, 0, False, ()
        )

    def _truth_detection(self, label: Label) -> Detection | None:
        if not label.visible:
            return None
        noise, rng = self.config.noise, self.rng["sonar"]
        sigma_az = math.radians(noise.azimuth_sigma_deg)
        return Detection(
            range_m=max(0.05, label.range_m + float(rng.normal(0.0, noise.range_sigma_m))),
            azimuth_rad=label.azimuth_rad + float(rng.normal(0.0, sigma_az)),
            range_sigma_m=noise.range_sigma_m,
            azimuth_sigma_rad=sigma_az,
            confidence=0.95,
            range_extent_m=0.45,
            azimuth_extent_rad=0.6 / max(label.range_m, 0.6),
        )

    @staticmethod
    def _label_payload(stamp: int, ping: int, label: Label, rov: RovState) -> SonarLabel:
        def opt(v: float) -> float | None:
            return None if math.isnan(v) else v

        return SonarLabel(
            stamp_ns=stamp,
            seq=ping,
            ping_id=ping,
            visible=label.visible,
            range_m=label.range_m,
            azimuth_rad=label.azimuth_rad,
            elevation_rad=label.elevation_rad,
            range_min_m=opt(label.range_min_m),
            range_max_m=opt(label.range_max_m),
            azimuth_min_rad=opt(label.azimuth_min_rad),
            azimuth_max_rad=opt(label.azimuth_max_rad),
            overlap=label.overlap,
            ghosts=tuple(GhostEcho(range_m=r, azimuth_rad=a) for r, a in label.ghosts),
            rov_position_m=_vec3(rov.position_m),
        )
