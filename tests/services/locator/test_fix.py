"""The CAP-SD fix: forward model then solve recovers the point, for any sonar attitude."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from capsd.geometry import Array, Transform, euler_zyx_to_matrix, rotvec_to_matrix
from capsd.services.locator.fix import (
    FixUncertainty,
    InstallationSigmas,
    installation_covariance,
    rov_centre_z,
    solve_fix,
)
from capsd.sonar_geometry import BeamModel, beam_direction, beam_directions, to_polar
from tests.services.locator.nees import mean_nees_bounds

APERTURE = math.radians(20.0)
IDENTITY = Transform.identity()

tilt = st.floats(min_value=-math.pi / 2, max_value=math.pi / 2)
yaw = st.floats(min_value=-math.pi, max_value=math.pi)
position = st.tuples(*[st.floats(min_value=-20.0, max_value=20.0)] * 3)
azimuth = st.floats(min_value=-math.radians(65), max_value=math.radians(65))
elevation = st.floats(min_value=-APERTURE / 2, max_value=APERTURE / 2)
slant = st.floats(min_value=0.3, max_value=40.0)
model = st.sampled_from(["planar", "conical"])


def _sonar(t: tuple[float, float, float], y: float, p: float, r: float) -> Transform:
    return Transform(euler_zyx_to_matrix(y, p, r), np.array(t))


@settings(max_examples=400, deadline=None)
@given(position, yaw, tilt, tilt, azimuth, elevation, slant, model)
# Rolled 90 deg, on the boresight: the depth plane touches the beam's arc, a hair past it by
# rounding (once reported as no_intersection).
@example((0.0, 0.0, 16.0), 0.0, 0.0, 1.5707963267948963, 1e-05, 0.0, 1.5, "planar")
def test_forward_then_solve_recovers_the_point(
    t: tuple[float, float, float],
    y: float,
    p: float,
    r: float,
    theta: float,
    phi: float,
    rng: float,
    beam: BeamModel,
) -> None:
    sonar = _sonar(t, y, p, r)
    truth = sonar.apply(rng * beam_direction(beam, theta, phi))
    result = solve_fix(
        asv_pose=sonar,
        sonar_mount=IDENTITY,
        range_m=rng,
        azimuth_rad=theta,
        rov_z_m=float(truth[2]),
        vertical_aperture_rad=APERTURE,
        beam_model=beam,
    )
    if result.position_m is None:
        # Allowed only where the geometry really is undecidable, never silently wrong.
        assert result.reason in {"ambiguous", "ill_conditioned"}
        if result.reason == "ambiguous":
            assert sum(c.in_aperture and c.in_front for c in result.candidates) == 2
            assert any(np.linalg.norm(c.position_m - truth) < 1e-6 for c in result.candidates)
        return
    assert np.linalg.norm(result.position_m - truth) < 1e-9
    assert any(np.linalg.norm(c.position_m - truth) < 1e-9 for c in result.candidates)


@settings(max_examples=200, deadline=None)
@given(position, yaw, st.floats(min_value=-0.2, max_value=0.2), azimuth, elevation, slant, model)
def test_level_sonar_pitched_down_always_fixes(
    t: tuple[float, float, float],
    y: float,
    roll: float,
    theta: float,
    phi: float,
    rng: float,
    beam: BeamModel,
) -> None:
    """The deployed geometry (boresight 30 deg down, small waves) is never ambiguous."""
    sonar = _sonar(t, y, math.radians(30.0), roll)
    truth = sonar.apply(rng * beam_direction(beam, theta, phi))
    result = solve_fix(
        asv_pose=sonar,
        sonar_mount=IDENTITY,
        range_m=rng,
        azimuth_rad=theta,
        rov_z_m=float(truth[2]),
        vertical_aperture_rad=APERTURE,
        beam_model=beam,
        max_conditioning=math.inf,
    )
    assert result.reason is None
    assert result.position_m is not None
    assert np.linalg.norm(result.position_m - truth) < 1e-9


@pytest.mark.parametrize(
    ("truth_model", "solver_model"), [("conical", "planar"), ("planar", "conical")]
)
def test_wrong_beam_model_shows_the_expected_bias(
    truth_model: BeamModel, solver_model: BeamModel
) -> None:
    """The models agree on the centre beam and differ by up to ~1.5 deg off it (CONVENTIONS)."""
    sonar = _sonar((0.0, 0.0, 0.0), 0.0, math.radians(30.0), 0.0)
    rng_m = 10.0
    for theta_deg, expect_bias in ((0.0, False), (30.0, True), (45.0, True)):
        truth = sonar.apply(rng_m * beam_direction(truth_model, math.radians(theta_deg), 0.08))
        result = solve_fix(
            asv_pose=sonar,
            sonar_mount=IDENTITY,
            range_m=rng_m,
            azimuth_rad=math.radians(theta_deg),
            rov_z_m=float(truth[2]),
            vertical_aperture_rad=APERTURE,
            beam_model=solver_model,
        )
        assert result.position_m is not None
        error = float(np.linalg.norm(result.position_m - truth))
        if expect_bias:
            assert 0.01 < error < rng_m * math.radians(1.6)
        else:
            assert error < 1e-9


def test_no_intersection_when_depth_is_beyond_range() -> None:
    sonar = _sonar((0.0, 0.0, 0.0), 0.0, math.radians(30.0), 0.0)
    result = solve_fix(
        asv_pose=sonar,
        sonar_mount=IDENTITY,
        range_m=2.0,
        azimuth_rad=0.0,
        rov_z_m=-5.0,
        vertical_aperture_rad=APERTURE,
        beam_model="planar",
    )
    assert result.reason == "no_intersection"
    assert result.position_m is None


def test_outside_aperture() -> None:
    sonar = _sonar((0.0, 0.0, 0.0), 0.0, math.radians(30.0), 0.0)
    # Straight below at 5 m: 90 deg from the surface, 60 deg below the boresight.
    result = solve_fix(
        asv_pose=sonar,
        sonar_mount=IDENTITY,
        range_m=5.0,
        azimuth_rad=0.0,
        rov_z_m=-4.99,
        vertical_aperture_rad=APERTURE,
        beam_model="planar",
    )
    assert result.reason == "outside_aperture"
    assert len(result.candidates) == 2


def test_grazing_geometry_is_ill_conditioned() -> None:
    # Boresight 0.16 rad off vertical; the target 0.02 rad from straight down, toward the
    # boresight. Its mirror candidate (0.18 rad) is outside the 20 deg aperture, so the fix is
    # unique, but the depth plane grazes the bottom of the range circle: 1 m of depth error
    # moves it about 1 / tan(0.02) = 50 m sideways.
    sonar = _sonar((0.0, 0.0, 0.0), 0.0, math.pi / 2 - 0.16, 0.0)
    _, _, down = to_polar("planar", sonar.rotation.T @ np.array([0.0, 0.0, -1.0]))
    assert abs(down) == pytest.approx(0.16)
    target = down - math.copysign(0.02, down)
    truth = sonar.apply(5.0 * beam_direction("planar", 0.0, target))
    result = solve_fix(
        asv_pose=sonar,
        sonar_mount=IDENTITY,
        range_m=5.0,
        azimuth_rad=0.0,
        rov_z_m=float(truth[2]),
        vertical_aperture_rad=APERTURE,
        beam_model="planar",
    )
    assert result.reason == "ill_conditioned"
    assert result.conditioning == pytest.approx(1.0 / math.tan(0.02), rel=1e-3)


def test_level_sonar_target_at_its_own_depth_is_well_conditioned() -> None:
    sonar = _sonar((0.0, 0.0, -1.0), 0.0, 0.0, 0.0)
    result = solve_fix(
        asv_pose=sonar,
        sonar_mount=IDENTITY,
        range_m=10.0,
        azimuth_rad=0.2,
        rov_z_m=-1.0,
        vertical_aperture_rad=APERTURE,
        beam_model="planar",
    )
    assert result.reason is None
    assert result.conditioning == pytest.approx(0.0, abs=1e-6)


def test_beam_parallel_to_depth_plane_is_degenerate() -> None:
    # Rolled 90 deg: the planar beam surface is horizontal, depth cannot pick the elevation.
    sonar = _sonar((0.0, 0.0, 0.0), 0.0, 0.0, math.pi / 2)
    result = solve_fix(
        asv_pose=sonar,
        sonar_mount=IDENTITY,
        range_m=5.0,
        azimuth_rad=math.pi / 2,
        rov_z_m=-1.0,
        vertical_aperture_rad=APERTURE,
        beam_model="planar",
    )
    assert result.reason in {"ill_conditioned", "no_intersection", "behind_sonar"}
    assert result.position_m is None


def test_fix_nees_within_95_percent_chi_square_bounds() -> None:
    """Each noisy fix's own covariance explains its error: mean NEES ~ chi2(3 N) / N."""
    rng = np.random.default_rng(7)
    asv = _sonar((5.0, 3.0, 0.0), 0.4, 0.01, -0.02)
    mount = Transform.from_euler_zyx(
        (0.3, 0.0, -0.2), yaw_rad=0.0, pitch_rad=math.radians(30), roll_rad=0.0
    )
    truth = asv.compose(mount).apply(8.0 * beam_direction("conical", 0.3, 0.05))
    pose_cov = np.diag([1e-4, 1e-4, 4e-4, 3e-6, 3e-6, 1e-5])
    unc = FixUncertainty(
        range_sigma_m=0.02,
        azimuth_sigma_rad=0.005,
        rov_z_sigma_m=0.01,
        asv_pose_covariance=pose_cov,
    )
    chol = np.linalg.cholesky(pose_cov)
    runs = 1000
    nees = 0.0
    for _ in range(runs):
        d = chol @ rng.standard_normal(6)
        pose = Transform(rotvec_to_matrix(d[3:]) @ asv.rotation, asv.translation + d[:3])
        res = solve_fix(
            asv_pose=pose,
            sonar_mount=mount,
            range_m=8.0 + rng.normal(0, 0.02),
            azimuth_rad=0.3 + rng.normal(0, 0.005),
            rov_z_m=float(truth[2]) + rng.normal(0, 0.01),
            vertical_aperture_rad=APERTURE,
            beam_model="conical",
            uncertainty=unc,
        )
        assert res.position_m is not None
        assert res.covariance_m2 is not None
        err = res.position_m - truth
        nees += float(err @ np.linalg.solve(res.covariance_m2, err))
    lo, hi = mean_nees_bounds(dim=3, count=runs)
    assert lo <= nees / runs <= hi


def test_lever_arm_correction() -> None:
    # Sensor 0.2 m behind the centre; nose pitched down 10 deg raises the tail by 0.2 sin 10.
    rotation = euler_zyx_to_matrix(0.0, math.radians(10.0), 0.0)
    z = rov_centre_z(2.0, rotation, np.array([-0.2, 0.0, 0.0]))
    assert z == pytest.approx(-2.0 - 0.2 * math.sin(math.radians(10.0)))
    level = rov_centre_z(2.0, np.eye(3), np.array([-0.2, 0.0, 0.0]))
    assert level == pytest.approx(-2.0)


@given(azimuth, elevation, slant, model)
def test_to_polar_inverts_beam_direction(
    theta: float, phi: float, rng: float, beam: BeamModel
) -> None:
    assume(rng > 0.1)
    r, t, e = to_polar(beam, rng * beam_direction(beam, theta, phi))
    assert (r, t, e) == pytest.approx((rng, theta, phi), abs=1e-9)


@given(azimuth, st.lists(elevation, min_size=1, max_size=5), model)
def test_beam_directions_are_beam_direction_for_every_elevation(
    theta: float, phis: list[float], beam: BeamModel
) -> None:
    many = beam_directions(beam, theta, np.array(phis))
    one = np.array([beam_direction(beam, theta, phi) for phi in phis])
    assert many == pytest.approx(one, abs=1e-12)


def _installation_case(sigmas: InstallationSigmas, *, range_m: float = 8.0) -> tuple[Array, Array]:
    """(covariance, position) of a fix on the boresight of a sonar 30 deg down at 0.2 m."""
    asv = Transform(np.eye(3), np.zeros(3))
    mount = Transform(euler_zyx_to_matrix(0.0, math.radians(30.0), 0.0), np.array([0.3, 0, -0.2]))
    target = asv.compose(mount).apply(range_m * beam_direction("conical", 0.0, 0.0))
    solved = solve_fix(
        asv_pose=asv,
        sonar_mount=mount,
        range_m=range_m,
        azimuth_rad=0.0,
        rov_z_m=float(target[2]),
        vertical_aperture_rad=math.radians(20.0),
        beam_model="conical",
    )
    assert solved.position_m is not None
    assert solved.elevation_rad is not None
    cov = installation_covariance(
        asv_pose=asv,
        sonar_mount=mount,
        range_m=range_m,
        azimuth_rad=0.0,
        rov_z_m=float(target[2]),
        model="conical",
        elevation_rad=solved.elevation_rad,
        sigmas=sigmas,
    )
    return cov, solved.position_m


@settings(max_examples=30, deadline=None)
@given(range_m=st.floats(3.0, 15.0), scale_sigma=st.floats(0.0005, 0.01))
def test_installation_range_scale_moves_the_fix_along_the_ground(
    range_m: float, scale_sigma: float
) -> None:
    sigmas = InstallationSigmas(scale_sigma, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0)
    cov, position = _installation_case(sigmas, range_m=range_m)
    # The depth is held: a range R (1 + d) moves the fix horizontally by R^2 d / rho.
    rho = math.hypot(position[0] - 0.3, position[1])
    assert math.sqrt(cov[0, 0]) == pytest.approx(range_m**2 * scale_sigma / rho, rel=0.02)
    assert cov[2, 2] == pytest.approx(0.0, abs=1e-12)
    assert cov[1, 1] == pytest.approx(0.0, abs=1e-12)


def test_installation_position_and_depth_terms() -> None:
    none = InstallationSigmas(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0)
    assert not none.any
    assert np.allclose(_installation_case(none)[0], 0.0)
    # A sonar 2 cm off sideways puts the fix 2 cm off sideways.
    sideways, _ = _installation_case(InstallationSigmas(0.0, (0.0, 0.02, 0.0), (0, 0, 0), 0.0))
    assert math.sqrt(sideways[1, 1]) == pytest.approx(0.02, rel=1e-3)
    # A depth offset moves the fix's z by itself, and along the ground through the geometry.
    depth, _ = _installation_case(InstallationSigmas(0.0, (0, 0, 0), (0, 0, 0), 0.01))
    assert math.sqrt(depth[2, 2]) == pytest.approx(0.01, rel=1e-3)
    assert depth[0, 0] > 0.0
    # Half a degree of sonar heading at 8 m: about 70 mm across.
    yaw, _ = _installation_case(
        InstallationSigmas(0.0, (0, 0, 0), (math.radians(0.5), 0.0, 0.0), 0.0)
    )
    assert 0.055 < math.sqrt(yaw[1, 1]) < 0.075
