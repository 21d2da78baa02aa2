"""The CAP-SD fix for one ping: range sphere, beam surface and depth plane, exact for any attitude.

With the sonar pose H_W_S = (R, t), a point seen at range r, azimuth theta and unknown elevation
e is p_W = t + R r u(theta, e). The depth plane z_W = z_R gives one scalar equation in e:

    r g . u(theta, e) = z_R - t_z,      g = R^T e_z (world "up" in sonar coordinates)

For both beam models it takes the form A cos e + B sin e = c:
  planar : A = g_x cos(theta) + g_y sin(theta), B = g_z, c = (z_R - t_z) / r
  conical: A = g_x, B = g_z, c = ((z_R - t_z) / r - g_y sin(theta)) / cos(theta)
so e = atan2(B, A) +- acos(c / hypot(A, B)): two candidates, no approximation and no
assumption of a level sonar (the paper's plane-normal construction is only right when level).
The candidate in front of the sonar (x_S > 0) and inside the vertical aperture is the fix.

Conditioning is |d p_xy / d z_R| (metres of horizontal motion per metre of depth error): it grows
without bound where the depth plane grazes the beam surface, and such fixes are refused.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np

from capsd.geometry import Array, Transform, euler_zyx_to_matrix, rotvec_to_matrix
from capsd.sonar_geometry import BeamModel, beam_direction

NoFixReason = Literal[
    "no_intersection", "outside_aperture", "behind_sonar", "ambiguous", "ill_conditioned"
]

_APERTURE_TOLERANCE_RAD = 1e-9
# Roots closer than this are one (double) root: the depth plane grazes the range circle.
_DOUBLE_ROOT_RAD = 1e-4


@dataclass(frozen=True)
class FixUncertainty:
    """One-sigma input uncertainties propagated into the fix covariance."""

    range_sigma_m: float
    azimuth_sigma_rad: float
    rov_z_sigma_m: float
    # 6 x 6 over (x, y, z, roll, pitch, yaw) of the ASV pose; rotations about the world axes.
    asv_pose_covariance: Array


@dataclass(frozen=True)
class InstallationSigmas:
    """One-sigma of what the configured installation may still get wrong (held for a dive).

    The range scale (the speed of sound, relative), the sonar's position in the ASV frame
    (x, y, z), small rotations of the sonar in its own frame (yaw, pitch, roll, radians), and
    the offset of the depth readings.
    """

    range_scale: float
    sonar_position_m: tuple[float, float, float]
    sonar_angles_rad: tuple[float, float, float]
    depth_offset_m: float

    @property
    def any(self) -> bool:
        return any(
            v > 0.0
            for v in (
                self.range_scale,
                *self.sonar_position_m,
                *self.sonar_angles_rad,
                self.depth_offset_m,
            )
        )


@dataclass(frozen=True)
class Candidate:
    """One intersection point: world position and the elevation it implies."""

    position_m: Array
    elevation_rad: float
    in_front: bool
    in_aperture: bool


@dataclass(frozen=True)
class FixResult:
    """Both candidates, the chosen position (or why there is none), covariance, conditioning."""

    candidates: tuple[Candidate, ...]
    position_m: Array | None
    elevation_rad: float | None
    reason: NoFixReason | None
    conditioning: float | None
    covariance_m2: Array | None


def rov_centre_z(depth_m: float, rov_orientation: Array, lever_arm_m: Array) -> float:
    """World z of the ROV centre from its pressure sensor's depth, the sensor at t_R_D.

    z_D = z_R + (R_W_R t_R_D)_z and z_D = -depth, so z_R = -depth - (R_W_R t_R_D)_z.
    """
    return -depth_m - float((rov_orientation @ lever_arm_m)[2])


def _solve_elevations(
    sonar_pose: Transform, range_m: float, azimuth_rad: float, rov_z_m: float, model: BeamModel
) -> tuple[float, float, float, float] | None:
    """(A, B, c, dc/dz) of A cos e + B sin e = c, or None if the azimuth is beyond +-90 deg."""
    g = sonar_pose.rotation[2, :]  # row 2 of R_W_S is world up expressed in S
    ct, st = math.cos(azimuth_rad), math.sin(azimuth_rad)
    height = (rov_z_m - float(sonar_pose.translation[2])) / range_m
    if model == "planar":
        return float(g[0] * ct + g[1] * st), float(g[2]), height, 1.0 / range_m
    if ct <= 0.0:
        return None
    return float(g[0]), float(g[2]), (height - float(g[1]) * st) / ct, 1.0 / (range_m * ct)


def _candidates(
    sonar_pose: Transform,
    range_m: float,
    azimuth_rad: float,
    rov_z_m: float,
    model: BeamModel,
    half_aperture_rad: float,
) -> tuple[tuple[Candidate, ...], float | None, NoFixReason | None]:
    """Intersection candidates and the conditioning of each root (None when degenerate)."""
    coeffs = _solve_elevations(sonar_pose, range_m, azimuth_rad, rov_z_m, model)
    if coeffs is None:
        return (), None, "behind_sonar"
    a, b, c, dc_dz = coeffs
    rho = math.hypot(a, b)
    if rho < 1e-6:
        # The beam surface is (nearly) parallel to the depth plane: depth says (almost)
        # nothing about the elevation, and rounding decides whether the roots exist.
        return (), None, "ill_conditioned"
    # c carries the rounding of the heights it is made of (metres of z over the range): a
    # tangent (the depth plane touching the beam's arc) may come out a hair beyond it.
    rounding = 8.0 * sys.float_info.epsilon
    rounding *= (abs(rov_z_m) + abs(float(sonar_pose.translation[2])) + range_m) / range_m
    if abs(c) > rho + rounding * abs(dc_dz) * range_m + 1e-12 * rho:
        return (), None, "no_intersection"
    if abs(c) > rho:
        return (), None, "ill_conditioned"  # tangent within rounding: depth fixes no elevation
    ratio = c / rho
    delta = math.atan2(b, a)
    alpha = math.acos(max(-1.0, min(1.0, ratio)))
    out: list[Candidate] = []
    for elevation in (delta + alpha, delta - alpha):
        elevation = math.atan2(math.sin(elevation), math.cos(elevation))
        direction = beam_direction(model, azimuth_rad, elevation)
        point = sonar_pose.apply(range_m * direction)
        out.append(
            Candidate(
                position_m=point,
                elevation_rad=elevation,
                in_front=bool(direction[0] > 0.0),
                in_aperture=abs(elevation) <= half_aperture_rad + _APERTURE_TOLERANCE_RAD,
            )
        )
        if alpha == 0.0:
            break
    # d e / d z from rho cos(e - delta) = c; infinite when tangent (sin(e - delta) = 0).
    sin_term = rho * math.sin(alpha)
    conditioning = None if sin_term == 0.0 else dc_dz / sin_term
    return tuple(out), conditioning, None


def _horizontal_conditioning(
    sonar_pose: Transform,
    range_m: float,
    azimuth_rad: float,
    elevation: float,
    model: BeamModel,
    de_dz: float | None,
) -> float:
    if de_dz is None:
        return math.inf
    h = 1e-7
    d_dir = (
        beam_direction(model, azimuth_rad, elevation + h)
        - beam_direction(model, azimuth_rad, elevation - h)
    ) / (2 * h)
    dp = sonar_pose.rotation @ (range_m * d_dir) * de_dz
    return float(math.hypot(dp[0], dp[1]))


def solve_fix(
    *,
    asv_pose: Transform,
    sonar_mount: Transform,
    range_m: float,
    azimuth_rad: float,
    rov_z_m: float,
    vertical_aperture_rad: float,
    beam_model: BeamModel,
    max_conditioning: float = 10.0,
    uncertainty: FixUncertainty | None = None,
) -> FixResult:
    """Locate the ROV from one detection; see the module docstring for the geometry.

    `asv_pose` is H_W_B, `sonar_mount` H_B_S, `rov_z_m` the world z of the ROV centre (use
    `rov_centre_z` to correct the pressure sensor's lever arm). With `uncertainty`, the 3 x 3
    covariance of the fix is propagated by a numerical Jacobian of this same solution.
    """
    if range_m <= 0.0 or not math.isfinite(range_m):
        raise ValueError(f"range_m must be positive and finite, got {range_m}")
    half_aperture = vertical_aperture_rad / 2.0
    sonar_pose = asv_pose.compose(sonar_mount)
    candidates, de_dz, reason = _candidates(
        sonar_pose, range_m, azimuth_rad, rov_z_m, beam_model, half_aperture
    )
    if reason is not None:
        return FixResult(candidates, None, None, reason, None, None)
    valid = [c for c in candidates if c.in_front and c.in_aperture]
    if not valid:
        why: NoFixReason = (
            "outside_aperture" if any(c.in_front for c in candidates) else "behind_sonar"
        )
        return FixResult(candidates, None, None, why, None, None)
    if len(valid) > 1:
        # Two roots a hair apart are the tangent case: precision, not choice, is the problem.
        spread = abs(valid[0].elevation_rad - valid[1].elevation_rad)
        why = "ill_conditioned" if spread < _DOUBLE_ROOT_RAD else "ambiguous"
        return FixResult(candidates, None, None, why, None, None)
    chosen = valid[0]
    conditioning = _horizontal_conditioning(
        sonar_pose, range_m, azimuth_rad, chosen.elevation_rad, beam_model, de_dz
    )
    if not conditioning <= max_conditioning:
        return FixResult(candidates, None, None, "ill_conditioned", conditioning, None)
    covariance = None
    if uncertainty is not None:
        try:
            covariance = _propagate(
                asv_pose,
                sonar_mount,
                range_m,
                azimuth_rad,
                rov_z_m,
                beam_model,
                chosen,
                uncertainty,
            )
        except ArithmeticError:  # the root vanishes within numerical reach: grazing geometry
            return FixResult(candidates, None, None, "ill_conditioned", conditioning, None)
    return FixResult(
        candidates, chosen.position_m, chosen.elevation_rad, None, conditioning, covariance
    )


def _same_root(
    sonar_pose: Transform,
    range_m: float,
    azimuth_rad: float,
    rov_z_m: float,
    model: BeamModel,
    elevation_rad: float,
) -> Array:
    """The fix under perturbed inputs, following the root nearest the chosen elevation."""
    cands, _, why = _candidates(sonar_pose, range_m, azimuth_rad, rov_z_m, model, math.pi)
    if why is not None or not cands:
        raise ArithmeticError("fix lost under a small perturbation")
    return min(cands, key=lambda c: abs(c.elevation_rad - elevation_rad)).position_m


def _jacobian(point: Callable[[Array], Array], steps: Array, skip: Array | None = None) -> Array:
    """3 x n central differences of `point` (columns where `skip` is set stay zero)."""
    jac = np.zeros((3, len(steps)))
    for i, h in enumerate(steps):
        if skip is not None and skip[i]:
            continue
        d = np.zeros(len(steps))
        d[i] = h
        jac[:, i] = (point(d) - point(-d)) / (2 * h)
    return jac


def installation_covariance(
    *,
    asv_pose: Transform,
    sonar_mount: Transform,
    range_m: float,
    azimuth_rad: float,
    rov_z_m: float,
    model: BeamModel,
    elevation_rad: float,
    sigmas: InstallationSigmas,
) -> Array:
    """J Sigma J^T of a fix over the installation's errors, by central differences.

    Parameters: range scale, sonar x, y, z (ASV frame), sonar yaw, pitch, roll (its own
    frame), depth offset. Not for the tracking filter: these hold for a whole dive, so
    averaging over pings does not shrink them; they belong in what a fix reports.
    """
    sig = np.array(
        [
            sigmas.range_scale,
            *sigmas.sonar_position_m,
            *sigmas.sonar_angles_rad,
            sigmas.depth_offset_m,
        ]
    )
    steps = np.array([1e-5, 1e-4, 1e-4, 1e-4, 1e-6, 1e-6, 1e-6, 1e-4])

    def point(delta: Array) -> Array:
        turn = euler_zyx_to_matrix(float(delta[4]), float(delta[5]), float(delta[6]))
        mount = Transform(sonar_mount.rotation @ turn, sonar_mount.translation + delta[1:4])
        return _same_root(
            asv_pose.compose(mount),
            range_m * (1.0 + delta[0]),
            azimuth_rad,
            rov_z_m - delta[7],
            model,
            elevation_rad,
        )

    jac = _jacobian(point, steps, skip=sig == 0.0)
    cov = (jac * sig**2) @ jac.T
    return np.asarray(0.5 * (cov + cov.T))


def _propagate(
    asv_pose: Transform,
    sonar_mount: Transform,
    range_m: float,
    azimuth_rad: float,
    rov_z_m: float,
    model: BeamModel,
    chosen: Candidate,
    unc: FixUncertainty,
) -> Array:
    """J Sigma J^T over (r, theta, z_R, asv x, y, z, roll, pitch, yaw) by central differences."""
    steps = np.array([1e-4, 1e-6, 1e-4, 1e-4, 1e-4, 1e-4, 1e-6, 1e-6, 1e-6])

    def point(delta: Array) -> Array:
        pose = Transform(
            rotvec_to_matrix(delta[6:9]) @ asv_pose.rotation, asv_pose.translation + delta[3:6]
        )
        return _same_root(
            pose.compose(sonar_mount),
            range_m + delta[0],
            azimuth_rad + delta[1],
            rov_z_m + delta[2],
            model,
            chosen.elevation_rad,
        )

    jac = _jacobian(point, steps)
    sigma = np.zeros((9, 9))
    sigma[0, 0] = unc.range_sigma_m**2
    sigma[1, 1] = unc.azimuth_sigma_rad**2
    sigma[2, 2] = unc.rov_z_sigma_m**2
    sigma[3:, 3:] = unc.asv_pose_covariance
    cov = jac @ sigma @ jac.T
    return np.asarray(0.5 * (cov + cov.T))
