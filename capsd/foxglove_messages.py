"""Foxglove's well-known messages (3D scene, transforms, scans, images, logs) as msgspec Structs.

Only what CAP-SD's view draws; field names and meanings as Foxglove's schemas define them
(docs.foxglove.dev, "Foxglove schemas"), JSON-encoded. A channel carries one of these with the
schema name `foxglove.<Name>` (`SCHEMA_NAMES`), so every viewer's 3D, Image and Log panels
recognise it; the JSON Schema comes from the Struct (capsd.viewer_schema), as for payloads.
Times are foxglove.Time ({sec, nsec}): exact, unlike a 64-bit nanosecond count in JavaScript.
"""

from __future__ import annotations

from typing import Annotated

import msgspec

from capsd.payloads import FoxgloveTime


class Vector3(msgspec.Struct, frozen=True):
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0


class Quaternion(msgspec.Struct, frozen=True):
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    w: float = 1.0


class Pose(msgspec.Struct, frozen=True):
    position: Vector3 = Vector3()
    orientation: Quaternion = Quaternion()


class Color(msgspec.Struct, frozen=True):
    r: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)]
    g: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)]
    b: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)]
    a: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)] = 1.0


class Duration(msgspec.Struct, frozen=True):
    sec: int = 0
    nsec: int = 0


class KeyValuePair(msgspec.Struct, frozen=True):
    key: str
    value: str


class FrameTransform(msgspec.Struct, frozen=True):
    timestamp: FoxgloveTime
    parent_frame_id: str
    child_frame_id: str
    translation: Vector3
    rotation: Quaternion


class FrameTransforms(msgspec.Struct, frozen=True):
    transforms: tuple[FrameTransform, ...]


class PosesInFrame(msgspec.Struct, frozen=True):
    timestamp: FoxgloveTime
    frame_id: str
    poses: tuple[Pose, ...]


class LaserScan(msgspec.Struct, frozen=True):
    timestamp: FoxgloveTime
    frame_id: str
    pose: Pose
    start_angle: float
    end_angle: float
    ranges: tuple[float, ...]
    intensities: tuple[float, ...] = ()


class CubePrimitive(msgspec.Struct, frozen=True):
    pose: Pose
    size: Vector3
    color: Color


class SpherePrimitive(msgspec.Struct, frozen=True):
    pose: Pose
    size: Vector3
    color: Color


class LinePrimitive(msgspec.Struct, frozen=True):
    type: int  # 0 line strip, 1 line loop, 2 line list
    pose: Pose
    thickness: float
    scale_invariant: bool
    points: tuple[Vector3, ...]
    color: Color
    colors: tuple[Color, ...] = ()
    indices: tuple[int, ...] = ()


class ArrowPrimitive(msgspec.Struct, frozen=True):
    pose: Pose
    shaft_length: float
    shaft_diameter: float
    head_length: float
    head_diameter: float
    color: Color


class CylinderPrimitive(msgspec.Struct, frozen=True):
    pose: Pose
    size: Vector3
    bottom_scale: float
    top_scale: float
    color: Color


class TriangleListPrimitive(msgspec.Struct, frozen=True):
    pose: Pose
    points: tuple[Vector3, ...]
    color: Color
    colors: tuple[Color, ...] = ()
    indices: tuple[int, ...] = ()


class ModelPrimitive(msgspec.Struct, frozen=True):
    pose: Pose
    scale: Vector3
    color: Color
    override_color: bool
    url: str
    media_type: str = ""
    data: bytes = b""


class TextPrimitive(msgspec.Struct, frozen=True):
    pose: Pose
    billboard: bool
    font_size: float
    scale_invariant: bool
    color: Color
    text: str


class SceneEntity(msgspec.Struct, frozen=True):
    timestamp: FoxgloveTime
    frame_id: str
    id: str
    lifetime: Duration = Duration()  # zero: until replaced or deleted
    frame_locked: bool = True
    metadata: tuple[KeyValuePair, ...] = ()
    arrows: tuple[ArrowPrimitive, ...] = ()
    cubes: tuple[CubePrimitive, ...] = ()
    spheres: tuple[SpherePrimitive, ...] = ()
    cylinders: tuple[CylinderPrimitive, ...] = ()
    lines: tuple[LinePrimitive, ...] = ()
    triangles: tuple[TriangleListPrimitive, ...] = ()
    texts: tuple[TextPrimitive, ...] = ()
    models: tuple[ModelPrimitive, ...] = ()


class SceneEntityDeletion(msgspec.Struct, frozen=True):
    timestamp: FoxgloveTime
    type: int  # 0 the entity `id`, 1 all
    id: str


class SceneUpdate(msgspec.Struct, frozen=True):
    deletions: tuple[SceneEntityDeletion, ...] = ()
    entities: tuple[SceneEntity, ...] = ()


class CompressedImage(msgspec.Struct, frozen=True):
    timestamp: FoxgloveTime
    frame_id: str
    data: bytes  # base64 in JSON
    format: str  # "jpeg" or "png"


class Log(msgspec.Struct, frozen=True):
    timestamp: FoxgloveTime
    level: int  # 1 debug, 2 info, 3 warning, 4 error, 5 fatal
    message: str
    name: str
    file: str = ""
    line: int = 0


SCHEMA_NAMES: dict[type[msgspec.Struct], str] = {
    cls: f"foxglove.{cls.__name__}"
    for cls in (FrameTransforms, PosesInFrame, LaserScan, SceneUpdate, CompressedImage, Log)
}


def foxglove_time(stamp_ns: int) -> FoxgloveTime:
    return FoxgloveTime(sec=stamp_ns // 1_000_000_000, nsec=stamp_ns % 1_000_000_000)
