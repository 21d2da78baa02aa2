"""Every payload on the bus: frozen msgspec Structs, the single source of truth for the wire.

Rules (CONVENTIONS.md): each payload carries `stamp_ns` (Unix ns at the instant of measurement,
on the producer's clock) and a per-publisher `seq` starting at 0. SI units and radians inside.
Orientations are quaternions (x, y, z, w). Covariances are row-major flattened square matrices.
Optional values are `None`, never NaN: every float on the wire must be finite.

A payload's `schema_version` is the major version of its schema. Adding an optional field keeps
the version (decoders tolerate unknown fields); any incompatible change bumps it, and decoders
reject versions they were not built for.
"""

from __future__ import annotations

import math
from typing import Annotated, ClassVar, Literal

import msgspec

WireFormat = Literal["json", "msgpack"]

NonNegInt = Annotated[int, msgspec.Meta(ge=0)]
NonNegFloat = Annotated[float, msgspec.Meta(ge=0.0)]
PosFloat = Annotated[float, msgspec.Meta(gt=0.0)]
UnitFloat = Annotated[float, msgspec.Meta(ge=0.0, le=1.0)]
Vec3 = tuple[float, float, float]
QuatXYZW = tuple[float, float, float, float]
Cov3 = Annotated[tuple[float, ...], msgspec.Meta(min_length=9, max_length=9)]
Cov6 = Annotated[tuple[float, ...], msgspec.Meta(min_length=36, max_length=36)]

_QUAT_NORM_TOLERANCE = 1e-3


def _check_finite(obj: msgspec.Struct) -> None:
    """Reject NaN and infinities in float fields and float tuples (msgpack can carry them)."""
    for name in obj.__struct_fields__:
        value = getattr(obj, name)
        if type(value) is float:
            finite = math.isfinite(value)
        elif type(value) is tuple and value and type(value[0]) is float:
            finite = all(map(math.isfinite, value))
        else:
            continue
        if not finite:
            raise ValueError(f"field '{name}' must be finite (NaN and infinity are not allowed)")


def _check_quaternion(name: str, q: QuatXYZW) -> None:
    norm = math.sqrt(sum(c * c for c in q))
    if abs(norm - 1.0) > _QUAT_NORM_TOLERANCE:
        raise ValueError(
            f"field '{name}' must be a unit quaternion (x, y, z, w), norm is {norm:.6f}"
        )


def _check_covariance(name: str, cov: tuple[float, ...] | None) -> None:
    if cov is None:
        return
    n = math.isqrt(len(cov))
    for i in range(n):
        if cov[i * n + i] < 0.0:
            raise ValueError(f"field '{name}' has a negative variance at index {i}")
        for j in range(i + 1, n):
            a, b = cov[i * n + j], cov[j * n + i]
            if abs(a - b) > 1e-9 * max(1.0, abs(a), abs(b)):
                raise ValueError(f"field '{name}' is not symmetric at ({i}, {j})")


class Payload(msgspec.Struct, frozen=True, kw_only=True):
    """Base of every bus payload: measurement stamp, publisher sequence and schema version."""

    WIRE: ClassVar[WireFormat] = "json"

    stamp_ns: NonNegInt
    seq: NonNegInt
    schema_version: int = 1

    def __post_init__(self) -> None:
        _check_finite(self)


# ---------------------------------------------------------------- service plumbing


HealthState = Literal["starting", "ok", "degraded", "error", "stopping"]


class StreamStats(msgspec.Struct, frozen=True, kw_only=True):
    """Counters for one input or output stream of a service."""

    key: str
    count: NonNegInt = 0
    rate_hz: NonNegFloat = 0.0
    errors: NonNegInt = 0
    dropped: NonNegInt = 0
    # seq went backwards: a publisher restarted, or two publishers share the key (a fault).
    seq_regressions: NonNegInt = 0
    last_stamp_ns: NonNegInt | None = None
    # Inputs that arrived in Zenoh shared memory (same host, large payloads), not copied in.
    shared_memory: NonNegInt = 0
    # Median over the last 32 of arrival (this computer's clock) minus stamp_ns: negative
    # means stamped in this clock's future; large means old on arrival (skew or a slow link).
    age_ms: float | None = None


class LatencyStats(msgspec.Struct, frozen=True, kw_only=True):
    """Cumulative latency histogram of one stage of a service (capsd.latency reads it).

    `bins` maps bin k to its count; bin k holds [1.05**k, 1.05**(k+1)) microseconds.
    """

    name: str
    count: NonNegInt = 0
    negative: NonNegInt = 0  # latencies below zero: the two ends' clocks disagree
    max_ms: NonNegFloat = 0.0
    bins: dict[NonNegInt, NonNegInt] = msgspec.field(default_factory=dict)


class Health(Payload, frozen=True, kw_only=True):
    """A service's state and counters, published at 1 Hz; `stamp_ns` is the sender's clock."""

    service: str
    state: HealthState
    # Why the state is not "ok" (what is missing or wrong), as the service says it.
    state_reason: str | None = None
    pid: NonNegInt
    host: str
    software_version: str
    uptime_s: NonNegFloat
    inputs: tuple[StreamStats, ...] = ()
    outputs: tuple[StreamStats, ...] = ()
    decode_errors: NonNegInt = 0
    dropped: NonNegInt = 0
    last_error: str | None = None
    last_error_stamp_ns: NonNegInt | None = None
    # Service-specific decision counts, e.g. the bridge's {"sent": 812, "stale": 3}.
    counters: dict[str, NonNegInt] = msgspec.field(default_factory=dict)
    # Per stage (transport of each input, the service's own work): see capsd.latency.
    latencies: tuple[LatencyStats, ...] = ()


class FoxgloveTime(msgspec.Struct, frozen=True, kw_only=True):
    """foxglove.Time: seconds and nanoseconds since the Unix epoch."""

    sec: NonNegInt
    nsec: Annotated[int, msgspec.Meta(ge=0, lt=1_000_000_000)]


class Log(Payload, frozen=True, kw_only=True):
    """One log line in the foxglove.Log JSON shape (as BlueOS services publish), plus stamp/seq."""

    SCHEMA_NAME: ClassVar[str] = "foxglove.Log"

    timestamp: FoxgloveTime
    # foxglove.LogLevel: 0 unknown, 1 debug, 2 info, 3 warning, 4 error, 5 fatal
    level: Annotated[int, msgspec.Meta(ge=0, le=5)]
    message: str
    name: str
    file: str = ""
    line: NonNegInt = 0


# ---------------------------------------------------------------- ASV


AsvPoseStatus = Literal["ok", "degraded", "lost"]
AsvPoseSource = Literal["scan_match", "external", "sim"]


class AsvPose(Payload, frozen=True, kw_only=True):
    """The ASV body frame B in the world frame W at `stamp_ns` (H_W_B).

    `covariance` is 6 x 6 over (x, y, z, roll, pitch, yaw): metres, and radians of small
    rotations about the world axes.
    """

    position_m: Vec3
    orientation_xyzw: QuatXYZW
    covariance: Cov6
    status: AsvPoseStatus = "ok"
    source: AsvPoseSource = "scan_match"

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_quaternion("orientation_xyzw", self.orientation_xyzw)
        _check_covariance("covariance", self.covariance)


class ImuSample(Payload, frozen=True, kw_only=True):
    """One IMU sample in the IMU's own frame (the consumer applies the mounting rotation)."""

    angular_velocity_rad_s: Vec3
    linear_acceleration_m_s2: Vec3


class LidarScan(Payload, frozen=True, kw_only=True):
    """A 2D LiDAR scan in the scanner frame; `stamp_ns` is the first beam's time.

    A range of 0.0 means no return for that beam.
    """

    angle_min_rad: float
    angle_increment_rad: PosFloat
    time_increment_s: NonNegFloat = 0.0
    range_min_m: NonNegFloat
    range_max_m: PosFloat
    ranges_m: tuple[float, ...]
    intensities: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        super().__post_init__()
        if any(r < 0.0 for r in self.ranges_m):
            raise ValueError("field 'ranges_m' has a negative range")
        if self.intensities and len(self.intensities) != len(self.ranges_m):
            raise ValueError("field 'intensities' must be empty or as long as 'ranges_m'")


# ---------------------------------------------------------------- sonar


class SonarFrame(Payload, frozen=True, kw_only=True):
    """One polar sonar image (range bins x beams) as the sonar formed it; msgpack on the wire.

    `image` is row-major: n_ranges rows of n_beams samples, beam index fastest, little-endian
    for 16-bit samples. `azimuths_rad` is theta per beam in the sonar frame S (port positive),
    taken from the sonar's own bearing table and already corrected for the mount.
    """

    WIRE: ClassVar[WireFormat] = "msgpack"

    ping_id: NonNegInt
    n_ranges: Annotated[int, msgspec.Meta(ge=1)]
    n_beams: Annotated[int, msgspec.Meta(ge=1)]
    sample_bits: Literal[8, 16]
    # A memoryview: decoding makes it a view into the received buffer, not a second copy.
    image: memoryview
    azimuths_rad: tuple[float, ...]
    range_start_m: NonNegFloat
    range_resolution_m: PosFloat
    # The speed of sound the sonar turned echo time into range with; None: it did not say.
    sound_speed_m_s: Annotated[float, msgspec.Meta(ge=1300.0, le=1800.0)] | None
    gain_percent: Annotated[float, msgspec.Meta(ge=0.0, le=100.0)]
    frequency_hz: PosFloat
    vertical_aperture_rad: PosFloat

    def __post_init__(self) -> None:
        super().__post_init__()
        expected = self.n_ranges * self.n_beams * (self.sample_bits // 8)
        if len(self.image) != expected:
            raise ValueError(
                f"field 'image' holds {len(self.image)} bytes, expected {expected} "
                f"({self.n_ranges} x {self.n_beams} x {self.sample_bits} bit)"
            )
        if len(self.azimuths_rad) != self.n_beams:
            raise ValueError(
                f"field 'azimuths_rad' has {len(self.azimuths_rad)} entries, "
                f"expected {self.n_beams}"
            )


class Detection(msgspec.Struct, frozen=True, kw_only=True):
    """One ROV candidate in a sonar frame: centre range/azimuth (sonar frame S) and footprint."""

    range_m: PosFloat
    azimuth_rad: Annotated[float, msgspec.Meta(ge=-math.pi, le=math.pi)]
    range_sigma_m: NonNegFloat
    azimuth_sigma_rad: NonNegFloat
    # The CNN's: the probability that this candidate is the ROV, the frame's other candidates
    # considered (sonar_detect's cnn.confidence); the classical detector's: its blob's score.
    confidence: UnitFloat
    range_extent_m: NonNegFloat = 0.0
    azimuth_extent_rad: NonNegFloat = 0.0

    def __post_init__(self) -> None:
        _check_finite(self)


class SonarDetections(Payload, frozen=True, kw_only=True):
    """The detector's candidates for one ping; `stamp_ns` is the ping's stamp.

    `sound_speed_m_s` is the speed the sonar assumed for these ranges (the frame's), so a
    consumer that knows the water's can rescale them; None: not known.
    """

    ping_id: NonNegInt
    detector: str
    detections: tuple[Detection, ...] = ()
    sound_speed_m_s: Annotated[float, msgspec.Meta(ge=1300.0, le=1800.0)] | None = None


# ---------------------------------------------------------------- ROV


class SonarTilt(Payload, frozen=True, kw_only=True):
    """The angles of the servos under the sonar at `stamp_ns` (the ASV's clock).

    `tilt_rad` is added to the sonar mount's pitch (down +), `pan_rad` (a mount with a pan
    servo; else 0) to its yaw (left +): H_B_S of a ping is the mount's with these added
    (docs/CONVENTIONS.md). Published by the ASV's bridge from its autopilot's mount
    (GIMBAL_DEVICE_ATTITUDE_STATUS), which reports the angles it drives the servos to.
    """

    tilt_rad: Annotated[float, msgspec.Meta(ge=-math.pi / 2, le=math.pi / 2)]
    pan_rad: Annotated[float, msgspec.Meta(ge=-math.pi, le=math.pi)] = 0.0


class RovDepth(Payload, frozen=True, kw_only=True):
    """Depth of the ROV's pressure sensor (positive down, metres below the still surface)."""

    depth_m: float
    pressure_pa: PosFloat | None = None
    temperature_c: float | None = None
    sigma_m: NonNegFloat = 0.01


class RovAttitude(Payload, frozen=True, kw_only=True):
    """The ROV body frame R's orientation in the world frame W, and its body rates."""

    orientation_xyzw: QuatXYZW
    angular_velocity_rad_s: Vec3 = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_quaternion("orientation_xyzw", self.orientation_xyzw)


class RovVelocity(Payload, frozen=True, kw_only=True):
    """The ROV's own velocity in the world frame W (e.g. from a DVL), with its covariance."""

    velocity_m_s: Vec3
    covariance_m2_s2: Cov3

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_covariance("covariance_m2_s2", self.covariance_m2_s2)


class AutopilotStatus(Payload, frozen=True, kw_only=True):
    """The autopilot's state as the bridge sees it."""

    armed: bool
    mode: str
    ekf_flags: NonNegInt = 0
    vehicle_boot_ms: NonNegInt = 0
    # lost: the bridge has no link to the autopilot; armed and mode are then unknown.
    link: Literal["ok", "lost"] = "ok"


# ---------------------------------------------------------------- locator


FixQuality = Literal["good", "unsure", "invalid"]
TrackState = Literal["none", "tentative", "tracking", "coasting", "lost"]
LocatorMethod = Literal["capsd", "paper", "ablation"]


class RovFix(Payload, frozen=True, kw_only=True):
    """The locator's output for one sonar ping (`stamp_ns` is the ping's stamp).

    `raw_*` is the single-ping geometric fix; `position_m`/`velocity_m_s`/`covariance_m2` are
    the tracked estimate. `quality` is the one field a consumer must honour: only "good" may
    reach an autopilot. The input stamps say which measurements produced the fix.
    """

    method: LocatorMethod
    quality: FixQuality
    no_fix_reason: str | None = None
    raw_position_m: Vec3 | None = None
    raw_covariance_m2: Cov3 | None = None
    conditioning: NonNegFloat | None = None
    track_state: TrackState = "none"
    # Bumped on every relocalisation jump of the track (the bridge's reset_counter follows it).
    track_resets: NonNegInt = 0
    candidates: NonNegInt = 0
    position_m: Vec3 | None = None
    velocity_m_s: Vec3 | None = None
    covariance_m2: Cov3 | None = None
    asv_pose_stamp_ns: NonNegInt | None = None
    depth_stamp_ns: NonNegInt | None = None
    attitude_stamp_ns: NonNegInt | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_covariance("raw_covariance_m2", self.raw_covariance_m2)
        _check_covariance("covariance_m2", self.covariance_m2)
        if self.quality == "good" and self.position_m is None and self.raw_position_m is None:
            raise ValueError("a 'good' fix must carry a position")


# ---------------------------------------------------------------- missions


CommandKind = Literal["engage", "goto", "hold"]
DriveDirection = Literal["forward", "reverse"]


class VehicleCommand(Payload, frozen=True, kw_only=True):
    """A command to a vehicle's autopilot, signed like fixes; its bridge turns it into MAVLink.

    From a ROV mission (`mission/command`) or the ASV's follower (`follow/command`). engage:
    switch to GUIDED and go to `position_m` (ROV missions only: the ASV's pilot engages);
    goto: move the GUIDED target (only acted on while the vehicle is in GUIDED); hold: switch
    to the autopilot's position hold (only from GUIDED: a mode the pilot chose is never
    overridden). `position_m` is in the tank frame W, `heading_rad` the body x axis's heading
    in W (counter-clockwise from W's x; None: the autopilot keeps its own).
    """

    mission: Annotated[str, msgspec.Meta(min_length=1, max_length=64)]
    kind: CommandKind
    waypoint: NonNegInt = 0
    position_m: Vec3 | None = None
    heading_rad: Annotated[float, msgspec.Meta(ge=-7.0, le=7.0)] | None = None
    reason: Annotated[str, msgspec.Meta(max_length=200)] = ""
    # A ROV mission's engage and goto: the waypoint the leg ends at, also while the ROV waits
    # for the ASV at `position_m` (the follower re-stations for the leg, not for the wait).
    leg_end_m: Vec3 | None = None
    # ... and the waypoint after it (None: the last one): the follower's stations are also to
    # see the start of the next leg as the ROV nears the end of this one.
    next_leg_end_m: Vec3 | None = None
    # The ASV's goto: which way its hull drives to `position_m` (ArduRover's GUIDED steers the
    # hull to its way, or its stern with MAV_CMD_DO_SET_REVERSE: backing off a ROV keeps the
    # sonar on it). The ROV's bridge ignores it.
    direction: DriveDirection = "forward"
    # The ASV's goto, where its sonar sits on a tilt servo: the angle to tilt it to, added to
    # the mount's pitch (down +; the mount's `tilt`). None: leave the servo where it is.
    sonar_tilt_rad: Annotated[float, msgspec.Meta(ge=-math.pi / 2, le=math.pi / 2)] | None = None
    # ... and, where the tilt servo sits on a pan servo, the pan (added to the mount's yaw, left
    # +; the mount's `pan`). None: ahead.
    sonar_pan_rad: Annotated[float, msgspec.Meta(ge=-math.pi, le=math.pi)] | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.kind in ("engage", "goto") and self.position_m is None:
            raise ValueError(f"a '{self.kind}' command must carry position_m")


# ---------------------------------------------------------------- reference


class ReferencePose(Payload, frozen=True, kw_only=True):
    """A reference system's pose of a vehicle (motion capture, a survey): for evaluation only.

    In the reference system's own frame (`frame_id`) and on its own clock: `capsd evaluate`
    estimates both. `orientation_xyzw` is None where the system gives a position only.
    """

    position_m: Vec3
    orientation_xyzw: QuatXYZW | None = None
    frame_id: str = ""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.orientation_xyzw is not None:
            _check_quaternion("orientation_xyzw", self.orientation_xyzw)


# ---------------------------------------------------------------- simulator


class GroundTruth(Payload, frozen=True, kw_only=True):
    """The simulator's true poses (its own key, never mixed with sensor keys)."""

    asv_position_m: Vec3
    asv_orientation_xyzw: QuatXYZW
    rov_position_m: Vec3
    rov_orientation_xyzw: QuatXYZW
    rov_velocity_m_s: Vec3 = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_quaternion("asv_orientation_xyzw", self.asv_orientation_xyzw)
        _check_quaternion("rov_orientation_xyzw", self.rov_orientation_xyzw)


class GhostEcho(msgspec.Struct, frozen=True, kw_only=True):
    """Where a multipath image of the ROV appears in the polar image."""

    range_m: NonNegFloat
    azimuth_rad: float


class SonarLabel(Payload, frozen=True, kw_only=True):
    """The simulator's truth for one sonar ping (`stamp_ns` and `ping_id` as the frame's).

    `range_m`/`azimuth_rad`/`elevation_rad` locate the ROV centre in the sonar frame (the beam
    model of the simulated sonar), ranges in the sonar's own units as the frame shows them
    (with a sound-speed error, not the true ones; `rov_position_m` is the truth); the
    footprint is the extent of the rays that hit the ROV (None when it is not visible);
    `overlap` says other echoes share its footprint.
    """

    ping_id: NonNegInt
    visible: bool
    range_m: NonNegFloat
    azimuth_rad: float
    elevation_rad: float
    range_min_m: NonNegFloat | None = None
    range_max_m: NonNegFloat | None = None
    azimuth_min_rad: float | None = None
    azimuth_max_rad: float | None = None
    overlap: bool = False
    ghosts: tuple[GhostEcho, ...] = ()
    rov_position_m: Vec3

    def footprint(self) -> tuple[float, float, float, float] | None:
        """(range min, range max, azimuth min, azimuth max) of a ROV in view, else None."""
        if (
            not self.visible
            or self.range_min_m is None
            or self.range_max_m is None
            or self.azimuth_min_rad is None
            or self.azimuth_max_rad is None
        ):
            return None
        return (self.range_min_m, self.range_max_m, self.azimuth_min_rad, self.azimuth_max_rad)


class SimControl(Payload, frozen=True, kw_only=True):
    """Fault injection: the simulator stops publishing these streams for `for_s` seconds.

    A stream is named as in the simulator's Health counters, e.g. "asv/scan@asv".
    """

    mute: tuple[str, ...]
    for_s: Annotated[float, msgspec.Meta(ge=0.0, le=600.0)]


ALL_PAYLOADS: tuple[type[Payload], ...] = (
    Health,
    Log,
    AsvPose,
    ImuSample,
    LidarScan,
    SonarFrame,
    SonarDetections,
    SonarTilt,
    RovDepth,
    RovAttitude,
    RovVelocity,
    AutopilotStatus,
    RovFix,
    VehicleCommand,
    ReferencePose,
    GroundTruth,
    SonarLabel,
    SimControl,
)
