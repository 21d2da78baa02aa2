"""Where the servos are, from reports of where they are driven to (capsd.servo_motion)."""

from __future__ import annotations

import math

import msgspec
import pytest
from hypothesis import given
from hypothesis import strategies as st

from capsd.mounts import SonarMountConfig
from capsd.servo_motion import ServoMotion
from capsd.simulator.tilt_servo import TiltServo

MOUNT = msgspec.convert(
    {"tilt": {"rate_deg_s": 30.0}, "pan": {"rate_deg_s": 60.0}}, SonarMountConfig
)
SECOND = 1_000_000_000


def test_a_reported_step_is_slewed_to_at_the_servos_rate_as_the_simulator_moves_it() -> None:
    """The pan told 30 deg left at 1 s: at 1.25 s it is half way, as the simulated servo is."""
    motion = ServoMotion(MOUNT)
    servo = TiltServo(MOUNT.tilt, zero_pitch_deg=-30.0, pan=MOUNT.pan)  # type: ignore[arg-type]
    first = motion.report(None, 0, 0.0, 0.0)
    servo.aim_pan(1.0, math.radians(30.0))
    second = motion.report(first, SECOND, 0.0, math.radians(30.0))
    assert second.pan_rad == 0.0  # reported at once, not there yet
    for t_s in (1.1, 1.25, 1.5, 2.0):
        modelled = motion.at(second, round(t_s * SECOND)).pan_rad
        assert modelled == pytest.approx(servo.pan_rad(t_s), abs=1e-9)
    # Between two reports, and past the newest (the locator's timeline).
    third = motion.report(second, 2 * SECOND, 0.0, math.radians(30.0))
    assert motion.between(second, third, 0.25).pan_rad == pytest.approx(math.radians(15.0))
    assert motion.between(second, third, 1.5).pan_rad == pytest.approx(math.radians(30.0))
    assert third.pan_rad == pytest.approx(math.radians(30.0))


@given(
    steps=st.lists(
        st.tuples(st.floats(0.01, 2.0), st.floats(-1.5, 1.5), st.floats(-1.5, 1.5)),
        min_size=1,
        max_size=20,
    )
)
def test_the_servos_never_move_faster_than_their_rates_nor_past_their_targets(
    steps: list[tuple[float, float, float]],
) -> None:
    motion = ServoMotion(MOUNT)
    state = motion.report(None, 0, 0.0, 0.0)
    stamp = 0
    for dt_s, tilt, pan in steps:
        stamp += round(dt_s * SECOND)
        new = motion.report(state, stamp, tilt, pan)
        dt = (new.stamp_ns - state.stamp_ns) / SECOND
        assert abs(new.tilt_rad - state.tilt_rad) <= motion.tilt_rate_rad_s * dt + 1e-9
        assert abs(new.pan_rad - state.pan_rad) <= motion.pan_rate_rad_s * dt + 1e-9
        lo, hi = sorted((state.pan_rad, state.pan_to_rad))
        assert lo - 1e-9 <= new.pan_rad <= hi + 1e-9
        state = new
