"""The ROV under the stand-in autopilot: holds, flies GUIDED targets, steers on its estimates."""

from __future__ import annotations

import math

import numpy as np
import pytest

from capsd.simulator.guided import GuidedLimits, GuidedRov

START = np.array([10.0, 8.0, -4.0])


def _speeds(rov: GuidedRov, t0: float, t1: float) -> np.ndarray:
    return np.array([np.linalg.norm(rov.state(t).velocity_m_s) for t in np.arange(t0, t1, 0.1)])


def test_holds_until_guided_then_flies_to_the_target_within_its_limits() -> None:
    rov = GuidedRov(START, limits=GuidedLimits(max_speed_m_s=0.3))
    assert np.allclose(rov.state(5.0).position_m, START)
    rov.set_target(START + np.array([2.0, 0.0, 0.0]))  # not in GUIDED: ignored, as ArduSub does
    assert np.allclose(rov.state(6.0).position_m, START)
    rov.set_mode("GUIDED")
    rov.set_target(START + np.array([3.0, 1.0, 0.5]))
    end = rov.state(40.0)
    assert end.position_m == pytest.approx(START + np.array([3.0, 1.0, 0.5]), abs=0.01)
    assert _speeds(rov, 6.0, 40.0).max() <= 0.3 + 1e-9
    # It faces where it went.
    heading = np.arctan2(1.0, 3.0)
    forward = rov.state(12.0).rotation[:, 0]
    assert np.arctan2(forward[1], forward[0]) == pytest.approx(heading, abs=0.05)


def test_poshold_stops_where_it_is() -> None:
    rov = GuidedRov(START)
    rov.set_mode("GUIDED")
    rov.set_target(START + np.array([5.0, 0.0, 0.0]))
    moving = rov.state(8.0).position_m.copy()
    rov.set_mode("POSHOLD")
    held = rov.state(30.0).position_m
    assert 0.5 < held[0] - START[0] < 5.0
    assert float(np.linalg.norm(held - moving)) < 0.5  # it brakes, then stays
    assert float(np.linalg.norm(rov.state(30.0).velocity_m_s)) < 1e-3


@pytest.mark.parametrize("error", [(0.1, 0.0, 0.0), (0.0, -0.05, 0.02)])
def test_it_steers_on_its_estimates_so_their_error_becomes_its_error(
    error: tuple[float, float, float],
) -> None:
    rov = GuidedRov(START)
    rov.set_mode("GUIDED")
    target = START + np.array([2.0, 0.0, 0.0])
    rov.set_target(target)
    for k in range(1, 600):  # estimates at 20 Hz that are `error` off the truth
        t = k * 0.05
        rov.on_estimate(t, rov.state(t).position_m + np.array(error))
    assert rov.state(30.0).position_m == pytest.approx(target - np.array(error), abs=0.005)


def test_without_estimates_its_belief_drifts_and_so_does_the_vehicle() -> None:
    limits = GuidedLimits(dead_reckoning_s=1.0, drift_m_s=0.01)
    rov = GuidedRov(START, limits=limits)
    rov.set_mode("POSHOLD")
    for k in range(1, 40):  # good estimates for 2 s, then none
        rov.on_estimate(k * 0.05, rov.state(k * 0.05).position_m)
    still = rov.state(3.0).position_m.copy()
    assert still == pytest.approx(START, abs=0.005)
    # 30 s later its belief has drifted about 0.3 m along +x: it holds 0.3 m short along -x.
    moved = rov.state(33.0).position_m - still
    assert moved[0] == pytest.approx(-0.30, abs=0.05)
    assert abs(moved[1]) < 1e-6


def _asv_flight(drive: str):  # type: ignore[no-untyped-def]
    """A calm-water ASV in GUIDED at (5, 5) facing +x, and a way to fly it with exact estimates."""
    from capsd.simulator.guided import AsvLimits, GuidedAsv
    from capsd.simulator.world import Waves

    calm = Waves(heave_m=0.0, roll_deg=0.0, pitch_deg=0.0)
    asv = GuidedAsv(
        (5.0, 5.0),
        0.0,
        waves=calm,
        mode="GUIDED",
        limits=AsvLimits(drive=drive),  # type: ignore[arg-type]
    )

    def fly(t0: float, t1: float) -> tuple[np.ndarray, np.ndarray]:
        """Exact position estimates every 0.2 s (no dead reckoning) until `t1`."""
        for t in np.arange(t0, t1, 0.2):
            _, xyz = asv.pose(float(t))
            asv.on_estimate(float(t), xyz[:2])
        return asv.pose(t1)

    return asv, fly


def test_a_lateral_asv_keeps_its_heading_to_a_position_and_turns_on_a_heading_alone() -> None:
    """An omni frame on its own controller: any way, heading kept; a heading alone turns it."""
    from capsd.geometry import matrix_to_euler_zyx

    asv, fly = _asv_flight("lateral")
    asv.set_target(np.array([5.0, 7.0]))  # abeam: it crabs there
    rotation, position = fly(0.0, 20.0)
    assert position[:2] == pytest.approx([5.0, 7.0], abs=0.05)
    assert matrix_to_euler_zyx(rotation)[0] == pytest.approx(0.0, abs=1e-6)
    asv.set_heading(1.0)
    rotation, position = fly(20.0, 40.0)
    assert matrix_to_euler_zyx(rotation)[0] == pytest.approx(1.0, abs=0.02)
    assert position[:2] == pytest.approx([5.0, 7.0], abs=0.05)  # turned in place


def test_a_steered_asv_turns_to_its_way_before_it_drives_as_ardurover_guided() -> None:
    """ArduRover's GUIDED: forward speed and turn rate only, so the hull faces the way.

    A target abeam: it first turns on the spot (no lateral thrust), then drives there facing
    it, the target's yaw ignored; a heading-only target then turns it where it is.
    """
    from capsd.geometry import matrix_to_euler_zyx

    asv, fly = _asv_flight("steered")
    asv.set_target(np.array([5.0, 7.0]))  # 90 deg to the left of the hull
    rotation, position = fly(0.0, 1.2)
    yaw = matrix_to_euler_zyx(rotation)[0]
    assert 0.3 < yaw < math.radians(30.0)  # turning left (20 deg/s) ...
    assert float(np.linalg.norm(position[:2] - [5.0, 5.0])) < 0.01  # ... on the spot (pivot)
    rotation, position = fly(1.2, 30.0)
    assert position[:2] == pytest.approx([5.0, 7.0], abs=0.06)
    # It faces about the way it came (it steers while it drives: where it ends depends on the
    # arc), not the heading it started with.
    assert matrix_to_euler_zyx(rotation)[0] == pytest.approx(math.pi / 2, abs=0.6)
    asv.set_heading(0.0)
    rotation, position = fly(30.0, 50.0)
    assert matrix_to_euler_zyx(rotation)[0] == pytest.approx(0.0, abs=0.02)
    assert position[:2] == pytest.approx([5.0, 7.0], abs=0.06)  # turned in place


def test_a_steered_asv_told_to_reverse_backs_to_a_target_astern_without_turning() -> None:
    """MAV_CMD_DO_SET_REVERSE: the stern to the way; a new mode drives ahead again."""
    from capsd.geometry import matrix_to_euler_zyx

    asv, fly = _asv_flight("steered")
    asv.set_direction("reverse")
    asv.set_target(np.array([3.0, 5.0]))  # 2 m astern
    rotation, position = fly(0.0, 20.0)
    assert position[:2] == pytest.approx([3.0, 5.0], abs=0.06)
    assert matrix_to_euler_zyx(rotation)[0] == pytest.approx(0.0, abs=0.05)  # still facing +x
    asv.set_mode("HOLD")
    asv.set_mode("GUIDED")
    asv.set_target(np.array([1.0, 5.0]))  # astern again, but ahead now: it turns round
    rotation, _ = fly(20.0, 30.0)
    assert abs(matrix_to_euler_zyx(rotation)[0]) > 2.5
