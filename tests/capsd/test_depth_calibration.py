"""The depth offset from a float at the surface: recovered, bounded, refused when unsure."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from capsd.depth_calibration import FLOAT_DEPTH_SIGMA_M, MIN_FLOAT_S, fit_depth_offset
from capsd.geometry import euler_zyx_to_matrix, matrix_to_quat
from capsd.mounts import RovConfig
from capsd.payloads import RovAttitude, RovDepth

T0 = 1_800_000_000_000_000_000
ROV = RovConfig(pressure_sensor_m=(-0.2, 0.0, -0.05))


def _dive(
    *, float_s: float, offset_m: float, heave_m: float, pitch_deg: float, dive_s: float = 20.0
) -> tuple[list[RovDepth], list[RovAttitude]]:
    """Floating (pitched, heaving), then a dive to 3 m: readings `offset_m` too shallow."""
    rotation = euler_zyx_to_matrix(0.4, math.radians(pitch_deg), 0.0)
    port_float = ROV.float_depth_m - float((rotation @ np.array(ROV.pressure_sensor_m))[2])
    depths, attitudes = [], []
    for k in range(int((float_s + dive_s) * 10)):
        t = k / 10
        true = port_float + heave_m * math.sin(2 * math.pi * t / 5.1)
        if t > float_s:
            true += min(3.0, 0.3 * (t - float_s))  # down at 0.3 m/s
        stamp = T0 + k * 100_000_000
        depths.append(RovDepth(stamp_ns=stamp, seq=k, depth_m=true - offset_m))
        q = tuple(float(v) for v in matrix_to_quat(rotation))
        attitudes.append(RovAttitude(stamp_ns=stamp, seq=k, orientation_xyzw=q))  # type: ignore[arg-type]
    return depths, attitudes


@settings(max_examples=40, deadline=None)
@given(
    offset_m=st.floats(-0.15, 0.15),
    heave_m=st.floats(0.0, 0.02),
    pitch_deg=st.floats(-10.0, 10.0),
    float_s=st.floats(15.0, 120.0),
)
def test_the_offset_is_recovered_within_its_sigma(
    offset_m: float, heave_m: float, pitch_deg: float, float_s: float
) -> None:
    depths, attitudes = _dive(
        float_s=float_s, offset_m=offset_m, heave_m=heave_m, pitch_deg=pitch_deg
    )
    fit = fit_depth_offset(depths, attitudes, rov=ROV)
    assert fit.determined
    # The synthetic ROV floats exactly at its configured depth: only the heave is left over.
    assert abs(fit.offset_m - offset_m) < max(fit.sigma_m - FLOAT_DEPTH_SIGMA_M, 0.004)
    assert fit.sigma_m >= FLOAT_DEPTH_SIGMA_M
    # The dive that follows is not taken for floating.
    assert fit.floating_s <= float_s + 0.5


def test_a_short_float_or_none_is_not_determined() -> None:
    depths, attitudes = _dive(float_s=MIN_FLOAT_S / 2, offset_m=0.05, heave_m=0.01, pitch_deg=0)
    fit = fit_depth_offset(depths, attitudes, rov=ROV)
    assert not fit.determined
    assert "floated at the surface for" in (fit.why_not or "")
    empty = fit_depth_offset([], [], rov=ROV)
    assert not empty.determined
    assert "no depth readings" in (empty.why_not or "")
    # Always at depth: no float at all.
    deep = [RovDepth(stamp_ns=T0 + k * 10**8, seq=k, depth_m=4.0) for k in range(300)]
    assert not fit_depth_offset(deep, [], rov=ROV).determined


def test_heavy_waves_make_it_unsure() -> None:
    # 5 cm of heave over only 12 s: the mean is not known within 15 mm.
    depths, attitudes = _dive(float_s=12.0, offset_m=0.0, heave_m=0.05, pitch_deg=0)
    fit = fit_depth_offset(depths, attitudes, rov=ROV)
    assert not fit.determined
    assert fit.lines()[0].startswith("depth offset           NOT determined")
