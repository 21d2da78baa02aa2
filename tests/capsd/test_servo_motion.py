"""Where the servos are, from reports of where they are driven to (capsd.servo_motion)."""

from __future__ import annotations

import math

import msgspec
import pytest
from hypothesis import given
from hypothesis import strategies as st

from capsd.mounts import SonarMountConfig
from capsd.servo_motion import MAX_BACKDATE_NS, ServoMotion
from capsd.simulator.tilt_servo import TiltServo

MOUNT = msgspec.convert(
    {"tilt": {"rate_deg_s": 30.0}, "pan": {"rate_deg_s": 60.0}}, SonarMountConfig
)
SECOND = 1_000_000_000


def test_a_reported_step_is_slewed_to_at_the_servos_rate_as_the_simulator_moves_it() -> None:
    """The pan told 30 deg left at 1 s, reported then: at 1.25 s half way, as the servo is.

    (The report before came long before: the new target is taken at most MAX_BACKDATE_NS
    before the report, here exactly when the simulated servo took it.)
    """
    motion = ServoMotion(MOUNT)
    servo = TiltServo(MOUNT.tilt, zero_pitch_deg=-30.0, pan=MOUNT.pan)  # type: ignore[arg-type]
    first = motion.report(None, 0, 0.0, 0.0)
    servo.aim_pan(1.0 - MAX_BACKDATE_NS / SECOND, math.radians(30.0))
    second = motion.report(first, SECOND, 0.0, math.radians(30.0))
    assert second.since_ns == SECOND - MAX_BACKDATE_NS
    assert second.pan_rad == pytest.approx(servo.pan_rad(1.0), abs=1e-9)  # on its way
    for t_s in (1.1, 1.25, 1.5, 2.0):
        modelled = motion.at(second, round(t_s * SECOND)).pan_rad
        assert modelled == pytest.approx(servo.pan_rad(t_s), abs=1e-9)
    # Between two reports, and past the newest (the locator's timeline).
    third = motion.report(second, 2 * SECOND, 0.0, math.radians(30.0))
    assert third.since_ns is None  # nothing new
    assert motion.between(second, third, 0.25).pan_rad == pytest.approx(servo.pan_rad(1.25))
    assert motion.between(second, third, 1.5).pan_rad == pytest.approx(math.radians(30.0))
    assert third.pan_rad == pytest.approx(math.radians(30.0))
    # Between the report before the new target and the one that says it: still until it was
    # taken, then on its way.
    assert motion.between(first, second, 0.5).pan_rad == 0.0
    at = (SECOND - MAX_BACKDATE_NS // 2) / SECOND
    assert motion.between(first, second, at).pan_rad == pytest.approx(servo.pan_rad(at))


@given(
    commanded=st.floats(0.0, 0.0499),
    pan_deg=st.floats(-90.0, 90.0),
    after_s=st.floats(0.0, 2.0),
)
def test_a_target_taken_between_two_reports_is_modelled_within_half_a_period_of_slew(
    commanded: float, pan_deg: float, after_s: float
) -> None:
    """Reports at 20 Hz: the model off by at most half a period of slew, either way.

    (After the report that says the target; taken at the report, up to a whole period behind.)
    """
    period_s = 0.05
    motion = ServoMotion(MOUNT)
    servo = TiltServo(MOUNT.tilt, zero_pitch_deg=-30.0, pan=MOUNT.pan)  # type: ignore[arg-type]
    before = motion.report(None, SECOND, 0.0, 0.0)
    servo.aim_pan(1.0 + commanded, math.radians(pan_deg))
    report = motion.report(before, SECOND + round(period_s * SECOND), 0.0, math.radians(pan_deg))
    t_s = 1.0 + period_s + after_s
    modelled = motion.at(report, round(t_s * SECOND)).pan_rad
    half = motion.pan_rate_rad_s * period_s / 2.0
    assert abs(modelled - servo.pan_rad(t_s)) <= half + 1e-9


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
        # Towards the old target, then (from when it took it) the new one: never past both.
        lo, hi = (
            min(state.pan_rad, state.pan_to_rad, pan),
            max(state.pan_rad, state.pan_to_rad, pan),
        )
        assert lo - 1e-9 <= new.pan_rad <= hi + 1e-9
        state = new
