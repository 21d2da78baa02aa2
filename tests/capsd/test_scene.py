"""The operator's scene: what each payload adds, in messages every viewer's schema accepts."""

from __future__ import annotations

import dataclasses
import json
import math
from typing import Any

import jsonschema
import msgspec
import numpy as np
import pytest

from capsd import foxglove_messages as fm
from capsd.geometry import quat_to_matrix
from capsd.mounts import SonarMountConfig
from capsd.payloads import AsvPose, LidarScan, RovAttitude, RovFix, SonarFrame
from capsd.scene import (
    ASV_TRAIL,
    FIX,
    LIDAR,
    ROV_TRAIL,
    SONAR_FAN,
    SONAR_FOV,
    TANK,
    TF,
    SceneView,
    ViewSettings,
)
from capsd.tank import TankBounds, TankFixture
from capsd.viewer_schema import viewer_rules, viewer_schema
from tests.capsd.samples import SAMPLES, STAMP

SETTINGS = ViewSettings(
    tank=TankBounds(fixtures=(TankFixture(name="rack", lo_m=(4, 3, -8), hi_m=(8, 7, -5)),)),
    sonar=SonarMountConfig(position_m=(0.3, 0.0, -0.2), pitch_deg=30.0),
    lidar_xy_m=(0.1, 0.0),
)
COV3 = (4e-4, 0.0, 0.0, 0.0, 1e-4, 0.0, 0.0, 0.0, 2.5e-5)


def _fix(stamp: int, quality: str = "good") -> RovFix:
    return RovFix(stamp_ns=stamp, seq=0, method="capsd", quality=quality,  # type: ignore[arg-type]
                  position_m=(5.0, 4.0, -2.0), covariance_m2=COV3)  # fmt: skip


def _valid(topic: str, message: Any) -> None:
    """The message validates against the schema its channel carries (an independent check)."""
    schema = viewer_schema(type(message))
    assert viewer_rules(schema) == [], topic
    jsonschema.Draft202012Validator(schema).validate(json.loads(msgspec.json.encode(message)))


def test_static_scene_draws_the_tank_and_its_fixtures() -> None:
    ((topic, update),) = SceneView(SETTINGS).static(STAMP)
    assert topic == TANK
    _valid(topic, update)
    tank = next(e for e in update.entities if e.id == "tank")
    assert len(tank.lines[0].points) == 24  # 12 edges of the tank's box, as a line list
    rack = tank.cubes[1]
    assert (rack.pose.position.x, rack.pose.position.z) == (6.0, -6.5)
    assert (rack.size.x, rack.size.z) == (4.0, 3.0)
    assert {e.frame_id for e in update.entities} == {"tank", "asv", "rov"}


def test_a_fix_is_a_transform_an_ellipsoid_and_a_trail() -> None:
    view = SceneView(SETTINGS)
    first = view.on_payload(
        "cap/tank/rov/rov/attitude",
        RovAttitude(
            stamp_ns=STAMP, seq=0, orientation_xyzw=(0.0, 0.0, math.sin(0.3), math.cos(0.3))
        ),
    )
    out = view.on_payload("cap/tank/topside/locator/fix", _fix(STAMP))  # fmt: skip
    assert [t for t, _ in first] == [TANK]  # the static scene, due at the first stamp
    topics = [t for t, _ in out]
    assert TF in topics
    assert ROV_TRAIL in topics
    for topic, message in out:
        _valid(topic, message)
    tf = next(m for t, m in out if t == TF).transforms[0]
    assert (tf.parent_frame_id, tf.child_frame_id) == ("tank", "rov")
    assert tf.rotation.z == pytest.approx(math.sin(0.3))  # the ROV's attitude
    fix = next(m for t, m in out if t == FIX and m.entities[0].id == "fix").entities[0]
    sphere = fix.spheres[0]
    # 2-sigma diameters: 4 sigma along each principal axis (sigmas 20, 10, 5 mm).
    assert sorted([sphere.size.x, sphere.size.y, sphere.size.z]) == pytest.approx(
        [0.02, 0.04, 0.08]
    )
    assert sphere.color == fm.Color(r=0.1, g=0.8, b=0.2, a=0.5)
    unsure = view.on_payload("k/locator/fix", _fix(STAMP + 10**6, "unsure"))
    sphere = next(m for t, m in unsure if t == FIX).entities[0].spheres[0]
    assert sphere.color.r == 1.0  # amber
    assert view.on_payload("k/locator/fix", _fix(STAMP + 2 * 10**6, "invalid")) == []


def test_rates_are_limited_on_the_payloads_own_stamps() -> None:
    view = SceneView(SETTINGS)
    trails = 0
    for k in range(100):  # 10 s of fixes at 10 Hz
        out = view.on_payload("k/locator/fix", _fix(STAMP + k * 100_000_000))
        trails += sum(t == ROV_TRAIL for t, _ in out)
    assert trails == 20  # 2 Hz
    assert len(view.trails()[1]) == 20


def test_the_asv_pose_carries_the_mounts() -> None:
    view = SceneView(SETTINGS)
    pose = next(s for s in SAMPLES if isinstance(s, AsvPose))
    out = view.on_payload("cap/tank/asv/asv/pose", pose)
    tf = next(m for t, m in out if t == TF)
    frames = {(t.parent_frame_id, t.child_frame_id): t for t in tf.transforms}
    assert set(frames) == {("tank", "asv"), ("asv", "sonar"), ("asv", "lidar")}
    sonar = frames[("asv", "sonar")]
    rotation = quat_to_matrix(np.array([sonar.rotation.x, sonar.rotation.y, sonar.rotation.z,
                                        sonar.rotation.w]))  # fmt: skip
    # Pitched 30 deg down: the boresight (x) points below the horizon.
    assert rotation[2, 0] == pytest.approx(-0.5)
    assert any(t == ASV_TRAIL for t, _ in out)
    # An external SLAM's pose is not the ASV pose the services use: not drawn.
    assert view.on_payload("cap/tank/asv/asv/pose_external", pose) == []


def test_scans_frames_and_fan_images() -> None:
    drawn = []

    def fan(frame: SonarFrame, detections: Any) -> Any:
        drawn.append(frame.ping_id)
        return np.zeros((40, 60, 3), dtype=np.uint8)

    view = SceneView(SETTINGS, fan=fan)
    scan = next(s for s in SAMPLES if isinstance(s, LidarScan))
    (topic, laser), *_ = [o for o in view.on_payload("k/asv/scan", scan) if o[0] == LIDAR]
    _valid(topic, laser)
    assert laser.end_angle == pytest.approx(-math.radians(135) + 2 * 0.0058)
    frame = next(s for s in SAMPLES if isinstance(s, SonarFrame))
    out = view.on_payload("k/sonar/frame", frame)
    image = next(m for t, m in out if t == SONAR_FAN)
    _valid(SONAR_FAN, image)
    assert image.format == "jpeg"
    assert image.data[:3] == b"\xff\xd8\xff"
    fov = next(m for t, m in out if t == SONAR_FOV and m.entities[0].id == "sonar_fov").entities[0]
    assert fov.frame_id == "sonar"
    # Half a second later: no new image (2 Hz), no new field of view (1 Hz).
    later = msgspec.structs.replace(frame, stamp_ns=frame.stamp_ns + 100_000_000)
    assert [t for t, _ in view.on_payload("k/sonar/frame", later)] == []
    off = SceneView(dataclasses.replace(SETTINGS, images="off"), fan=fan)
    assert all(t != SONAR_FAN for t, _ in off.on_payload("k/sonar/frame", frame))
    assert drawn == [frame.ping_id]
