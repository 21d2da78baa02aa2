"""The scan matcher against known transforms, on scans from the simulated TiM571."""

from __future__ import annotations

import math

import numpy as np
import pytest

from capsd.geometry import Transform, euler_zyx_to_matrix
from capsd.services.asv_pose.scan_match import level_points, match, tank_walls
from capsd.simulator.lidar import LidarModel, scan
from capsd.simulator.world import make_tank


def _scan(x: float, y: float, yaw: float, roll: float, pitch: float, seed: int) -> np.ndarray:
    tank = make_tank("nfp", clutter="off")
    pose = Transform(euler_zyx_to_matrix(yaw, pitch, roll), np.array([x, y, 0.4]))
    return scan(LidarModel(), pose, tank, np.random.default_rng(seed))


@pytest.mark.parametrize(
    ("truth", "guess"),
    [
        ((14.0, 8.0, 0.3), (14.3, 7.8, 0.3 + math.radians(4.0))),
        ((5.0, 4.0, -1.2), (4.7, 4.3, -1.2 - math.radians(5.0))),
        ((22.0, 11.0, 2.5), (22.2, 11.2, 2.5 + math.radians(3.0))),
    ],
)
def test_converges_to_the_known_pose(
    truth: tuple[float, float, float], guess: tuple[float, float, float]
) -> None:
    roll, pitch = math.radians(1.2), math.radians(-0.8)
    ranges = _scan(*truth, roll, pitch, seed=3)
    model = LidarModel()
    points = level_points(ranges, model.angles(), roll_rad=roll, pitch_rad=pitch)
    result = match(points, tank_walls(28.0, 16.0), x_m=guess[0], y_m=guess[1], yaw_rad=guess[2])
    assert result.x_m == pytest.approx(truth[0], abs=0.01)
    assert result.y_m == pytest.approx(truth[1], abs=0.01)
    assert math.degrees(result.yaw_rad - truth[2]) == pytest.approx(0.0, abs=0.1)
    assert result.inlier_ratio > 0.9
    assert result.residual_rms_m < 0.03
    assert np.all(np.isfinite(result.covariance))
    assert math.sqrt(result.covariance[0, 0]) < 0.01


def test_unlevelled_scan_is_biased_and_levelling_fixes_it() -> None:
    # A 2 deg roll: both side walls still in the scan plane's reach (at 5 deg one side dips
    # below the water line and the other passes over the 1 m freeboard: y is then unobservable).
    truth = (14.0, 8.0, 0.0)
    roll = math.radians(2.0)
    ranges = _scan(*truth, roll, 0.0, seed=4)
    angles = LidarModel().angles()
    walls = tank_walls(28.0, 16.0)
    good = match(
        level_points(ranges, angles, roll_rad=roll, pitch_rad=0.0),
        walls,
        x_m=14.1,
        y_m=8.1,
        yaw_rad=0.02,
    )
    assert good.residual_rms_m < 0.03
    assert good.y_m == pytest.approx(8.0, abs=0.01)


def test_one_wall_only_is_degenerate() -> None:
    # Points on the y = 0 wall only: nothing fixes x. The matcher must say so.
    xs = np.linspace(5.0, 9.0, 60)
    points_w = np.column_stack([xs, np.zeros_like(xs)])
    body = points_w - np.array([7.0, 3.0])  # ASV at (7, 3), yaw 0
    result = match(body, tank_walls(28.0, 16.0), x_m=7.2, y_m=3.1, yaw_rad=0.0)
    assert result.degeneracy < 1e-6
    assert not np.all(np.isfinite(result.covariance)) or result.covariance[0, 0] > 1.0


@pytest.mark.parametrize(("roll_deg", "pitch_deg"), [(1.5, 0.0), (0.0, -1.0), (1.2, 0.8)])
def test_a_scanner_on_a_mast_gives_the_hull_s_pose_when_its_height_is_known(
    roll_deg: float, pitch_deg: float
) -> None:
    # The hull at (14, 8), the scanner 0.4 m above its origin: rolled 1.5 deg, the scanner
    # sits 10 mm to one side of the hull's origin.
    x, y, yaw = 14.0, 8.0, 0.3
    roll, pitch = math.radians(roll_deg), math.radians(pitch_deg)
    hull = Transform(euler_zyx_to_matrix(yaw, pitch, roll), np.array([x, y, 0.0]))
    mast = (0.0, 0.0, 0.4)
    scanner = Transform(hull.rotation, hull.apply(np.array(mast)))
    ranges = scan(
        LidarModel(sigma_m=0.0), scanner, make_tank("nfp", clutter="off"), np.random.default_rng(1)
    )
    walls = tank_walls(28.0, 16.0)

    def offset_mm(mount: tuple[float, float, float]) -> float:
        points = level_points(
            ranges, LidarModel().angles(), roll_rad=roll, pitch_rad=pitch, mount_m=mount
        )
        found = match(points, walls, x_m=x + 0.1, y_m=y - 0.1, yaw_rad=yaw + 0.02)
        return 1000.0 * math.hypot(found.x_m - x, found.y_m - y)

    sway_mm = 400.0 * math.sin(math.hypot(roll, pitch))
    assert offset_mm(mast) < 1.0
    assert offset_mm((0.0, 0.0, 0.0)) == pytest.approx(sway_mm, rel=0.1)


def test_fixtures_just_off_the_walls_do_not_pull_the_match() -> None:
    # The mockup tank's clutter stands above the water a few centimetres off its walls: inside
    # the gate, unweighted, it pulled the walls (and the pose) 5 mm towards itself on average.
    tank = make_tank("mockup")
    walls = tank_walls(tank.length_m, tank.width_m)
    x, y = tank.length_m / 2, tank.width_m / 2
    rng = np.random.default_rng(0)
    errors_mm = []
    for yaw in np.linspace(-math.pi, math.pi, 24, endpoint=False):
        hull = Transform(euler_zyx_to_matrix(float(yaw), 0.0, 0.0), np.array([x, y, 0.0]))
        scanner = Transform(hull.rotation, hull.apply(np.array([0.0, 0.0, 0.4])))
        ranges = scan(LidarModel(sigma_m=0.0), scanner, tank, rng)
        points = level_points(ranges, LidarModel().angles(), roll_rad=0.0, pitch_rad=0.0)
        found = match(points, walls, x_m=x + 0.05, y_m=y - 0.05, yaw_rad=float(yaw) + 0.01)
        errors_mm.append(1000.0 * math.hypot(found.x_m - x, found.y_m - y))
    assert max(errors_mm) < 1.0
