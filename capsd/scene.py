"""The operator's 3D scene, derived from the bus: one derivation for the live view and recordings.

From the payloads a site already publishes, and the tank and sonar mount the locator is
configured with (no second description of the tank), `SceneView` makes Foxglove messages
(capsd.foxglove_messages) on fixed topics:

- `/capsd/tf` (FrameTransforms): tank -> asv (the ASV pose), asv -> sonar and asv -> lidar
  (the mounts), tank -> rov (the newest good or unsure fix, the ROV's attitude);
- SceneUpdates, one topic per kind of entity (a viewer that seeks shows the last message of
  each topic, so every kind is there at once): `/capsd/tank` the tank's walls, floor and
  fixtures and the ASV and the ROV as boxes, re-sent every `static_every_s`; `/capsd/fix` the
  latest fix with its 2-sigma covariance ellipsoid coloured by quality (green good, amber
  unsure); `/capsd/sonar_fov` the sonar's field of view from the frames' geometry;
- `/capsd/asv_trail`, `/capsd/rov_trail` (PosesInFrame): the last minute, 2 per second;
- `/capsd/lidar` (LaserScan) in the LiDAR's frame; `/capsd/log` (Log) from the services' logs;
- `/capsd/sonar_fan` (CompressedImage, JPEG or PNG): the newest frame as a fan with its
  detections, at most `fan_hz`;
- `/capsd/tank_map` (CompressedImage, PNG): the tank from above with its fixtures and both
  trails, at most `map_hz` (drawn when a sonar frame comes, as the fan is).
Rates are limited on the payloads' own stamps, so a recording replays the same scene.
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import msgspec
import numpy as np

from capsd import foxglove_messages as fm
from capsd.accuracy import fix_estimate
from capsd.geometry import matrix_to_quat
from capsd.keys import Subject, subject_of
from capsd.mounts import SonarMountConfig
from capsd.payloads import (
    AsvPose,
    LidarScan,
    Log,
    RovAttitude,
    RovFix,
    SonarDetections,
    SonarFrame,
)
from capsd.tank import TankBounds

TF = "/capsd/tf"
TANK = "/capsd/tank"
FIX = "/capsd/fix"
SONAR_FOV = "/capsd/sonar_fov"
ASV_TRAIL = "/capsd/asv_trail"
ROV_TRAIL = "/capsd/rov_trail"
LIDAR = "/capsd/lidar"
LOG = "/capsd/log"
SONAR_FAN = "/capsd/sonar_fan"
TANK_MAP = "/capsd/tank_map"
# Each topic and the one message type it carries.
TOPIC_TYPES: dict[str, type[msgspec.Struct]] = {
    TF: fm.FrameTransforms,
    TANK: fm.SceneUpdate,
    FIX: fm.SceneUpdate,
    SONAR_FOV: fm.SceneUpdate,
    ASV_TRAIL: fm.PosesInFrame,
    ROV_TRAIL: fm.PosesInFrame,
    LIDAR: fm.LaserScan,
    LOG: fm.Log,
    SONAR_FAN: fm.CompressedImage,
    TANK_MAP: fm.CompressedImage,
}
TOPICS = tuple(TOPIC_TYPES)

ImageFormat = Literal["jpeg", "png", "off"]
Out = list[tuple[str, Any]]

_GREY = fm.Color(r=0.55, g=0.6, b=0.65, a=1.0)
_FLOOR = fm.Color(r=0.3, g=0.35, b=0.4, a=0.35)
_FIXTURE = fm.Color(r=0.75, g=0.55, b=0.3, a=0.8)
_ASV = fm.Color(r=0.85, g=0.2, b=0.2, a=0.9)
_ROV = fm.Color(r=0.2, g=0.5, b=0.9, a=0.9)
_FAN = fm.Color(r=0.2, g=0.9, b=0.9, a=0.6)
_QUALITY = {
    "good": fm.Color(r=0.1, g=0.8, b=0.2, a=0.5),
    "unsure": fm.Color(r=1.0, g=0.7, b=0.0, a=0.5),
}
BLUEROV2_SIZE_M = (0.457, 0.338, 0.254)
ASV_SIZE_M = (1.2, 0.8, 0.4)


@dataclass(frozen=True)
class ViewSettings:
    """What the view draws, and how often."""

    tank: TankBounds
    sonar: SonarMountConfig
    lidar_xy_m: tuple[float, float] = (0.0, 0.0)
    images: ImageFormat = "jpeg"
    jpeg_quality: int = 75
    fan_hz: float = 2.0
    map_hz: float = 1.0
    tf_hz: float = 20.0
    trail_s: float = 60.0
    trail_hz: float = 2.0
    # The tank and bodies again this often: a viewer that joins or seeks late still has them.
    static_every_s: float = 5.0


def _vec(v: Any) -> fm.Vector3:
    return fm.Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def _quat(q: Any) -> fm.Quaternion:
    return fm.Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))


def _pose(position: Any = (0.0, 0.0, 0.0), orientation: Any = (0.0, 0.0, 0.0, 1.0)) -> fm.Pose:
    return fm.Pose(position=_vec(position), orientation=_quat(orientation))


def _segments(points: list[fm.Vector3], *, thickness: float, color: fm.Color) -> fm.LinePrimitive:
    """Line segments (a line list: points in pairs), thickness in pixels."""
    return fm.LinePrimitive(type=2, pose=_pose(), thickness=thickness, scale_invariant=True,
                            points=tuple(points), color=color)  # fmt: skip


class _Every:
    """True at most once per period of the payloads' own stamps."""

    def __init__(self, hz: float):
        self.period_ns = int(1e9 / hz) if hz > 0 else 0
        self.last_ns: int | None = None

    def due(self, stamp_ns: int) -> bool:
        if self.last_ns is not None and 0 <= stamp_ns - self.last_ns < self.period_ns:
            return False
        self.last_ns = stamp_ns
        return True


class SceneView:
    """Payloads in (with their keys), Foxglove messages out; `static()` once per file/client."""

    def __init__(
        self,
        settings: ViewSettings,
        *,
        fan: Callable[..., Any] | None = None,
        tank_map: Callable[..., Any] | None = None,
    ):
        self.settings = settings
        self.fan = fan  # (frame, detections) -> an image array (BGR); None: no fan images
        # (tank, ASV trail, ROV trail) -> an image array (BGR); None: no tank map
        self.tank_map = tank_map
        self._map_due = _Every(settings.map_hz if settings.images != "off" else 0.0)
        self._tf = _Every(settings.tf_hz)
        self._asv_trail_due = _Every(settings.trail_hz)
        self._rov_trail_due = _Every(settings.trail_hz)
        self._fan_due = _Every(settings.fan_hz if settings.images != "off" else 0.0)
        self._fov_due = _Every(1.0)
        self._static_due = _Every(1.0 / settings.static_every_s)
        length = max(1, int(settings.trail_s * settings.trail_hz))
        self._asv_trail: deque[fm.Pose] = deque(maxlen=length)
        self._rov_trail: deque[fm.Pose] = deque(maxlen=length)
        self._attitude: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
        self._detections: dict[int, SonarDetections] = {}
        self._last_asv_ns: int | None = None

    # ------------------------------------------------------------------ static

    def static(self, stamp_ns: int) -> Out:
        """The tank, its fixtures and the vehicles' bodies (entities that do not move)."""
        t = fm.foxglove_time(stamp_ns)
        tank = self.settings.tank
        corners = [(0, 0), (tank.length_m, 0), (tank.length_m, tank.width_m), (0, tank.width_m)]
        edges: list[fm.Vector3] = []
        for z in (0.0, -tank.depth_m):
            for k in range(4):
                a, b = corners[k], corners[(k + 1) % 4]
                edges += [fm.Vector3(x=a[0], y=a[1], z=z), fm.Vector3(x=b[0], y=b[1], z=z)]
        for x, y in corners:
            edges += [fm.Vector3(x=x, y=y, z=0.0), fm.Vector3(x=x, y=y, z=-tank.depth_m)]
        walls = _segments(edges, thickness=2.0, color=_GREY)
        floor = fm.CubePrimitive(
            pose=_pose((tank.length_m / 2, tank.width_m / 2, -tank.depth_m - 0.01)),
            size=fm.Vector3(x=tank.length_m, y=tank.width_m, z=0.02),
            color=_FLOOR,
        )
        fixtures = tuple(
            fm.CubePrimitive(
                pose=_pose(tuple((lo + hi) / 2 for lo, hi in zip(f.lo_m, f.hi_m, strict=True))),
                size=_vec(tuple(hi - lo for lo, hi in zip(f.lo_m, f.hi_m, strict=True))),
                color=_FIXTURE,
            )
            for f in tank.fixtures
        )
        labels = tuple(
            fm.TextPrimitive(
                pose=_pose(((f.lo_m[0] + f.hi_m[0]) / 2, (f.lo_m[1] + f.hi_m[1]) / 2, f.hi_m[2])),
                billboard=True,
                font_size=12.0,
                scale_invariant=True,
                color=_FIXTURE,
                text=f.name,
            )
            for f in tank.fixtures
            if f.name
        )
        entities = (
            fm.SceneEntity(
                timestamp=t,
                frame_id="tank",
                id="tank",
                lines=(walls,),
                cubes=(floor, *fixtures),
                texts=labels,
            ),
            fm.SceneEntity(
                timestamp=t,
                frame_id="asv",
                id="asv_body",
                cubes=(fm.CubePrimitive(pose=_pose(), size=_vec(ASV_SIZE_M), color=_ASV),),
            ),
            fm.SceneEntity(
                timestamp=t,
                frame_id="rov",
                id="rov_body",
                cubes=(fm.CubePrimitive(pose=_pose(), size=_vec(BLUEROV2_SIZE_M), color=_ROV),),
            ),
        )
        return [(TANK, fm.SceneUpdate(entities=entities))]

    # ------------------------------------------------------------------ payloads

    def trails(self) -> tuple[list[fm.Pose], list[fm.Pose]]:
        """The ASV's and the ROV's recent poses, oldest first."""
        return list(self._asv_trail), list(self._rov_trail)

    def on_payload(self, key: str, payload: Any) -> Out:
        """What this payload adds to the scene (often nothing: rates are limited)."""
        stamp = getattr(payload, "stamp_ns", None)
        static = self.static(stamp) if stamp and self._static_due.due(stamp) else []
        return static + self._derive(key, payload)

    def _derive(self, key: str, payload: Any) -> Out:
        subject = subject_of(key)
        if isinstance(payload, AsvPose) and subject == Subject.ASV_POSE.value:
            return self._asv(payload)
        if isinstance(payload, RovAttitude):
            self._attitude = payload.orientation_xyzw
            return []
        if isinstance(payload, RovFix):
            return self._fix(payload)
        if isinstance(payload, LidarScan):
            return self._scan(payload)
        if isinstance(payload, SonarDetections):
            self._detections[payload.ping_id] = payload
            while len(self._detections) > 50:
                del self._detections[min(self._detections)]
            return []
        if isinstance(payload, SonarFrame):
            return self._frame(payload)
        if isinstance(payload, Log):
            return [
                (
                    LOG,
                    fm.Log(
                        timestamp=payload.timestamp,
                        level=payload.level,
                        message=payload.message,
                        name=payload.name,
                        file=payload.file,
                        line=payload.line,
                    ),
                )
            ]
        return []

    def _mounts(self, stamp_ns: int) -> list[fm.FrameTransform]:
        t = fm.foxglove_time(stamp_ns)
        sonar = self.settings.sonar.transform()
        lidar = self.settings.lidar_xy_m
        return [
            fm.FrameTransform(
                timestamp=t,
                parent_frame_id="asv",
                child_frame_id="sonar",
                translation=_vec(sonar.translation),
                rotation=_quat(matrix_to_quat(sonar.rotation)),
            ),
            fm.FrameTransform(
                timestamp=t,
                parent_frame_id="asv",
                child_frame_id="lidar",
                translation=fm.Vector3(x=lidar[0], y=lidar[1], z=0.0),
                rotation=fm.Quaternion(),
            ),
        ]

    def _asv(self, pose: AsvPose) -> Out:
        out: Out = []
        stamp = pose.stamp_ns
        if self._tf.due(stamp):
            asv = fm.FrameTransform(
                timestamp=fm.foxglove_time(stamp),
                parent_frame_id="tank",
                child_frame_id="asv",
                translation=_vec(pose.position_m),
                rotation=_quat(pose.orientation_xyzw),
            )
            out.append((TF, fm.FrameTransforms(transforms=(asv, *self._mounts(stamp)))))
        if self._asv_trail_due.due(stamp):
            self._asv_trail.append(_pose(pose.position_m, pose.orientation_xyzw))
            out.append(
                (
                    ASV_TRAIL,
                    fm.PosesInFrame(
                        timestamp=fm.foxglove_time(stamp),
                        frame_id="tank",
                        poses=tuple(self._asv_trail),
                    ),
                )
            )
        return out

    def _fix(self, fix: RovFix) -> Out:
        position, covariance = fix_estimate(fix)
        color = _QUALITY.get(fix.quality)
        if position is None or color is None:
            return []
        stamp = fix.stamp_ns
        t = fm.foxglove_time(stamp)
        out: Out = [
            (
                TF,
                fm.FrameTransforms(
                    transforms=(
                        fm.FrameTransform(
                            timestamp=t,
                            parent_frame_id="tank",
                            child_frame_id="rov",
                            translation=_vec(position),
                            rotation=_quat(self._attitude),
                        ),
                    )
                ),
            ),
        ]
        spheres: tuple[fm.SpherePrimitive, ...] = ()
        if covariance is not None:
            values, vectors = np.linalg.eigh(np.array(covariance).reshape(3, 3))
            if np.linalg.det(vectors) < 0:
                vectors[:, 2] = -vectors[:, 2]
            size = 2 * 2 * np.sqrt(np.maximum(values, 0.0))  # the 2-sigma ellipsoid's diameters
            spheres = (
                fm.SpherePrimitive(
                    pose=_pose(position, matrix_to_quat(vectors)), size=_vec(size), color=color
                ),
            )
        text = fm.TextPrimitive(
            pose=_pose((position[0], position[1], position[2] + 0.4)),
            billboard=True,
            font_size=12.0,
            scale_invariant=True,
            color=color,
            text=f"fix {fix.quality}" + (f" ({fix.no_fix_reason})" if fix.no_fix_reason else ""),
        )
        entity = fm.SceneEntity(
            timestamp=t,
            frame_id="tank",
            id="fix",
            spheres=spheres,
            texts=(text,),
            metadata=(fm.KeyValuePair(key="quality", value=fix.quality),),
        )
        out.append((FIX, fm.SceneUpdate(entities=(entity,))))
        if fix.quality == "good" and self._rov_trail_due.due(stamp):
            self._rov_trail.append(_pose(position, self._attitude))
            out.append(
                (
                    ROV_TRAIL,
                    fm.PosesInFrame(timestamp=t, frame_id="tank", poses=tuple(self._rov_trail)),
                )
            )
        return out

    def _scan(self, scan: LidarScan) -> Out:
        n = len(scan.ranges_m)
        end = scan.angle_min_rad + scan.angle_increment_rad * max(n - 1, 0)
        message = fm.LaserScan(
            timestamp=fm.foxglove_time(scan.stamp_ns),
            frame_id="lidar",
            pose=_pose(),
            start_angle=scan.angle_min_rad,
            end_angle=end,
            # No return is 0 (a dot at the scanner): JSON has no NaN to leave a ray empty.
            ranges=scan.ranges_m,
            intensities=scan.intensities,
        )
        return [(LIDAR, message)]

    def _frame(self, frame: SonarFrame) -> Out:
        out: Out = []
        stamp = frame.stamp_ns
        if self._fov_due.due(stamp):
            out.append((SONAR_FOV, fm.SceneUpdate(entities=(self._fov(frame),))))
        if self.fan is not None and self.settings.images != "off" and self._fan_due.due(stamp):
            image = self.fan(frame, self._detections.get(frame.ping_id))
            out.append(
                (
                    SONAR_FAN,
                    fm.CompressedImage(
                        timestamp=fm.foxglove_time(stamp),
                        frame_id="sonar",
                        data=encode_image(image, self.settings.images, self.settings.jpeg_quality),
                        format=self.settings.images,
                    ),
                )
            )
        if self.tank_map is not None and self.settings.images != "off" and self._map_due.due(stamp):
            image = self.tank_map(self.settings.tank, *self.trails())
            out.append(
                (
                    TANK_MAP,
                    fm.CompressedImage(
                        timestamp=fm.foxglove_time(stamp),
                        frame_id="tank",
                        data=encode_image(image, "png", 0),
                        format="png",
                    ),
                )
            )
        return out

    def _fov(self, frame: SonarFrame) -> fm.SceneEntity:
        """The fan's volume in the sonar frame (x forward, y left, z up): its edges."""
        near = frame.range_start_m
        far = near + frame.range_resolution_m * frame.n_ranges
        az0, az1 = min(frame.azimuths_rad), max(frame.azimuths_rad)
        half = frame.vertical_aperture_rad / 2

        def ray(r: float, azimuth: float, elevation: float) -> fm.Vector3:
            return fm.Vector3(
                x=r * math.cos(elevation) * math.cos(azimuth),
                y=r * math.cos(elevation) * math.sin(azimuth),
                z=r * math.sin(elevation),
            )

        points: list[fm.Vector3] = []
        arcs = [az0 + (az1 - az0) * k / 16 for k in range(17)]
        for elevation in (-half, half):
            for r in (near, far):
                strip = [ray(r, a, elevation) for a in arcs]
                points += [p for pair in itertools.pairwise(strip) for p in pair]
            for azimuth in (az0, az1):
                points += [ray(near, azimuth, elevation), ray(far, azimuth, elevation)]
        for azimuth in (az0, az1):
            for r in (near, far):
                points += [ray(r, azimuth, -half), ray(r, azimuth, half)]
        lines = _segments(points, thickness=1.5, color=_FAN)
        return fm.SceneEntity(
            timestamp=fm.foxglove_time(frame.stamp_ns),
            frame_id="sonar",
            id="sonar_fov",
            lines=(lines,),
        )


def encode_image(image: Any, fmt: ImageFormat, quality: int) -> bytes:
    """A BGR image as JPEG (at `quality`) or PNG bytes."""
    import cv2

    if fmt == "jpeg":
        ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    else:
        ok, data = cv2.imencode(".png", image)
    if not ok:
        raise ValueError(f"{fmt} encoding failed")
    return bytes(data.tobytes())


__all__ = ["TOPICS", "TOPIC_TYPES", "SceneView", "ViewSettings", "encode_image"]
