"""The mission logic: engage, advance, dwell, pause on a lost fix, resume, the pilot wins."""

from __future__ import annotations

import math

import msgspec
import pytest

from capsd.mission.controller import CARROT_LEAD_S, GUIDED, POSHOLD, Command, MissionController
from capsd.mission.plan import Plan, Waypoint

POINTS = [Waypoint((5.0, 4.0, -3.0)), Waypoint((9.0, 4.0, -3.0), dwell_s=2.0)]


def _plan(**overrides: float) -> Plan:
    # Engaging at the first good fix keeps these timelines short; start_after_s has its test.
    settings = {"start_after_s": 0.0, **overrides}
    return msgspec.convert(
        {"points": [{"position_m": [5.0, 4.0], "depth_m": 3.0}], **settings}, Plan
    )


def _fly(
    ctl: MissionController,
    path: list[tuple[float, float, float] | None],
    *,
    dt: float = 0.05,
    mode: str = GUIDED,
    t0: float = 0.0,
) -> list[tuple[float, str, int]]:
    """Feed a fix per step (None: no fix that step) and the mode; what was commanded when."""
    out: list[tuple[float, str, int]] = []
    t = t0
    for position in path:
        if position is not None:
            ctl.on_fix(good=True, position_m=position, now=t)
        ctl.on_mode(mode, now=t)
        out += [(t, c.kind, c.waypoint) for c in ctl.step(t)]
        t += dt
    return out


def test_waits_for_a_good_fix_then_engages_and_flies_every_waypoint() -> None:
    ctl = MissionController(_plan(), POINTS)
    assert ctl.step(0.0) == []
    ctl.on_fix(good=False, position_m=None, now=0.0)
    assert ctl.step(0.0) == []
    path: list[tuple[float, float, float] | None] = [(4.0, 4.0, -3.0)] * 5
    path += [(5.05, 4.0, -3.0)] * 5  # at the first point
    path += [(7.0, 4.1, -3.0)] * 5
    path += [(9.0, 4.0, -3.0)] * 60  # at the last: 2 s dwell, then done
    commands = _fly(ctl, path)
    kinds = [(k, w) for _, k, w in commands if k != "goto" or w != 0]
    assert kinds[0] == ("engage", 0)
    assert ("goto", 1) in kinds
    assert kinds[-1] == ("hold", 1)
    assert ctl.progress.state == "done"
    done_at = next(t for t, k, _ in commands if k == "hold")
    arrived_at = 15 * 0.05
    assert done_at - arrived_at >= 2.0 - 1e-9
    # Cross-track measured on the leg between the two points: 0.1 m off at x = 7.
    assert abs(max(ctl.progress.cross_track_m) - 0.1) < 1e-9


def test_the_first_engage_waits_for_fixes_good_for_start_after_s() -> None:
    ctl = MissionController(_plan(start_after_s=1.0, fix_timeout_s=0.5), POINTS)
    path: list[tuple[float, float, float] | None] = [(4.0, 4.0, -3.0)] * 10  # 0.45 s
    path += [None] * 20  # a 1 s gap, longer than fix_timeout_s: the good run restarts
    path += [(4.0, 4.0, -3.0)] * 30
    commands = _fly(ctl, path)
    engages = [t for t, k, _ in commands if k == "engage"]
    assert len(engages) == 1
    assert engages[0] - 30 * 0.05 >= 1.0 - 1e-9


def test_a_lost_fix_pauses_within_the_timeout_and_resumes_after_good_fixes() -> None:
    plan = _plan(fix_timeout_s=0.5, resume_after_s=1.0)
    ctl = MissionController(plan, POINTS)
    path: list[tuple[float, float, float] | None] = [(4.0, 4.0, -3.0)] * 10
    path += [None] * 40  # 2 s without fixes
    path += [(4.2, 4.0, -3.0)] * 40
    commands = _fly(ctl, path)
    holds = [t for t, k, _ in commands if k == "hold"]
    engages = [t for t, k, _ in commands if k == "engage"]
    last_fix_at = 9 * 0.05
    assert len(holds) == 1
    assert holds[0] - last_fix_at <= 0.5 + 0.05 + 1e-9  # within the timeout and one step
    assert len(engages) == 2
    fixes_back_at = 50 * 0.05
    assert engages[1] - fixes_back_at >= 1.0 - 1e-9
    # Nothing but the hold while paused.
    assert not [c for c in commands if holds[0] < c[0] < engages[1]]
    assert ctl.progress.pauses == 1
    assert ctl.progress.pause_latency_s[0] <= 0.55 + 1e-9


def test_unsure_fixes_pause_within_the_timeout() -> None:
    ctl = MissionController(_plan(fix_timeout_s=0.5), POINTS)
    ctl.on_fix(good=True, position_m=(4.0, 4.0, -3.0), now=0.0)
    assert [c.kind for c in ctl.step(0.0)] == ["engage"]
    kinds = []
    for k in range(1, 30):
        ctl.on_fix(good=False, position_m=None, now=k * 0.05)
        ctl.on_mode(GUIDED, now=k * 0.05)
        kinds += [(k * 0.05, c.kind) for c in ctl.step(k * 0.05)]
    holds = [t for t, kind in kinds if kind == "hold"]
    assert len(holds) == 1
    assert holds[0] <= 0.55 + 1e-9
    assert {kind for t, kind in kinds if t < holds[0]} <= {"goto"}
    assert ctl.progress.state == "paused"


def test_the_pilot_changing_mode_aborts_and_nothing_more_is_sent() -> None:
    ctl = MissionController(_plan(), POINTS)
    commands = _fly(ctl, [(4.0, 4.0, -3.0)] * 20)
    assert commands[0][1] == "engage"
    # The pilot takes over in MANUAL: within the grace it is read as the switch in progress.
    commands = _fly(ctl, [(4.0, 4.0, -3.0)] * 100, mode="MANUAL", t0=1.0)
    assert ctl.progress.state == "aborted"
    assert "MANUAL" in ctl.progress.why
    assert not [c for c in commands if c[0] > 3.1]
    assert ctl.stop(10.0) == []


def test_stop_leaves_the_rov_holding() -> None:
    ctl = MissionController(_plan(), POINTS)
    _fly(ctl, [(4.0, 4.0, -3.0)] * 5)
    (last,) = ctl.stop(1.0)
    assert last.kind == "hold"
    assert ctl.progress.state == "stopped"
    assert ctl.step(2.0) == []


def test_hold_after_pause_expects_poshold_not_guided() -> None:
    ctl = MissionController(_plan(), POINTS)
    _fly(ctl, [(4.0, 4.0, -3.0)] * 5)
    _fly(ctl, [None] * 20, t0=0.25)
    assert ctl.progress.state == "paused"
    # The vehicle in POSHOLD while paused is what was asked: no abort.
    _fly(ctl, [None] * 100, mode=POSHOLD, t0=1.25)
    assert ctl.progress.state == "paused"


def test_a_paused_mission_resumes_through_occasional_unsure_fixes() -> None:
    ctl = MissionController(_plan(fix_timeout_s=0.5, resume_after_s=1.0), POINTS)
    _fly(ctl, [(4.0, 4.0, -3.0)] * 5)
    _fly(ctl, [None] * 20, t0=0.25)
    assert ctl.progress.state == "paused"
    engaged = []
    for k in range(60):  # good fixes at 20 Hz, every fourth one unsure
        t = 1.25 + k * 0.05
        ctl.on_fix(good=k % 4 != 3, position_m=(4.0, 4.0, -3.0), now=t)
        engaged += [t for c in ctl.step(t) if c.kind == "engage"]
    assert engaged
    assert 1.0 - 1e-9 <= engaged[0] - 1.25 <= 1.1


def _guarded(**guard: float) -> MissionController:
    plan = msgspec.convert(
        {
            "points": [{"position_m": [5.0, 4.0], "depth_m": 3.0}],
            "start_after_s": 0.0,
            "view_guard": {"edge_margin_deg": 3.0, "resume_margin_deg": 6.0, **guard},
        },
        Plan,
    )
    return MissionController(plan, POINTS)


def _step_with_view(
    ctl: MissionController, t: float, margin_deg: float | None, at: tuple[float, float, float]
) -> list[tuple[str, tuple[float, float, float] | None, str]]:
    ctl.on_fix(good=True, position_m=at, now=t)
    if margin_deg is not None:
        ctl.on_view(math.radians(margin_deg), now=t)
    ctl.on_mode(GUIDED, now=t)
    return [(c.kind, c.position_m, c.reason) for c in ctl.step(t)]


def test_the_rov_waits_where_it_is_near_the_views_edge_until_the_asv_has_it_again() -> None:
    ctl = _guarded()
    here = (4.0, 4.0, -3.0)
    assert _step_with_view(ctl, 0.0, 8.0, here)[0][0] == "engage"
    assert ctl.progress.waits == 0
    # Near the edge: the target becomes where the ROV is.
    commands = _step_with_view(ctl, 0.1, 2.0, here)
    assert commands[0][:2] == ("goto", here)
    assert "waiting for the ASV" in commands[0][2]
    assert ctl.waiting()
    # Repeated while the margin stays under resume (4 deg is inside edge and resume).
    repeats = [c for k in range(2, 30) for c in _step_with_view(ctl, k * 0.05 + 0.05, 4.0, here)]
    assert repeats
    assert all(position == here for _, position, _ in repeats)
    # Well inside again: on to the waypoint.
    commands = _step_with_view(ctl, 2.0, 7.0, here)
    assert commands == [("goto", POINTS[0].position_m, "in view again: on")]
    assert not ctl.waiting()
    assert ctl.progress.waits == 1
    assert abs(ctl.progress.waited_s - 1.9) < 1e-9


def test_every_command_of_a_leg_names_its_end_even_while_the_rov_waits_at_its_place() -> None:
    """The follower re-stations for where the leg goes, not for where the ROV waits.

    And for the waypoint after it: its stations are to see the turn after a lane too
    (docs/JOURNAL.md, session 38); the plan's last leg has none.
    """
    ctl = _guarded()
    here = (4.0, 4.0, -3.0)
    ctl.on_fix(good=True, position_m=here, now=0.0)
    ctl.on_view(math.radians(8.0), now=0.0)
    ctl.on_mode(GUIDED, now=0.0)
    (engage,) = ctl.step(0.0)
    assert ctl.leg_end(engage) == POINTS[0].position_m
    ctl.on_fix(good=True, position_m=here, now=0.1)
    ctl.on_view(math.radians(2.0), now=0.1)
    (wait,) = ctl.step(0.1)
    assert wait.position_m == here
    assert ctl.leg_end(wait) == POINTS[0].position_m
    assert ctl.next_leg_end(engage) == ctl.next_leg_end(wait) == POINTS[1].position_m
    last = Command(kind="goto", waypoint=len(POINTS) - 1, position_m=here, reason="")
    assert ctl.leg_end(last) == POINTS[-1].position_m
    assert ctl.next_leg_end(last) is None
    hold = ctl.stop(0.2)[0]
    assert ctl.leg_end(hold) is None  # a hold ends no leg
    assert ctl.next_leg_end(hold) is None


def test_a_wait_ends_after_max_wait_s_and_is_not_repeated_until_the_view_was_good() -> None:
    ctl = _guarded(max_wait_s=1.0)
    here = (4.0, 4.0, -3.0)
    _step_with_view(ctl, 0.0, 8.0, here)
    assert _step_with_view(ctl, 0.1, 1.0, here)[0][1] == here
    commands = [c for k in range(3, 40) for c in _step_with_view(ctl, k * 0.05, 1.0, here)]
    assert ("goto", POINTS[0].position_m, "waited 1 s for the ASV: on") in commands
    assert not ctl.waiting()
    assert ctl.progress.waits_timed_out == 1
    assert all(c[1] != here for c in _step_with_view(ctl, 2.5, 1.0, here))  # not re-armed
    _step_with_view(ctl, 2.6, 6.5, here)  # the view good again: armed
    assert _step_with_view(ctl, 2.7, 1.0, here)[0][1] == here
    assert ctl.progress.waits == 2


def test_without_a_view_or_with_the_guard_off_the_leg_is_flown() -> None:
    here = (4.0, 4.0, -3.0)
    for ctl, margin in ((_guarded(), None), (MissionController(
        msgspec.convert({"points": [{"position_m": [5.0, 4.0], "depth_m": 3.0}],
                         "start_after_s": 0.0, "view_guard": {"mode": "off"}}, Plan),
        POINTS), -5.0)):  # fmt: skip
        _step_with_view(ctl, 0.0, margin, here)
        for k in range(1, 20):
            _step_with_view(ctl, k * 0.05, margin, here)
        assert not ctl.waiting()
        assert ctl.progress.waits == 0
    # A view that goes stale while waiting ends the wait (no ASV pose: fly on).
    ctl = _guarded()
    _step_with_view(ctl, 0.0, 8.0, here)
    _step_with_view(ctl, 0.1, 1.0, here)
    assert ctl.waiting()
    commands = _step_with_view(ctl, 1.5, None, here)
    assert commands == [("goto", POINTS[0].position_m, "view unknown: on")]


def test_a_resume_margin_below_the_edge_margin_is_refused() -> None:
    with pytest.raises(msgspec.ValidationError, match="resume_margin_deg"):
        msgspec.convert(
            {"points": [{"position_m": [5.0, 4.0], "depth_m": 3.0}],
             "view_guard": {"edge_margin_deg": 5.0, "resume_margin_deg": 2.0}},
            Plan,
        )  # fmt: skip


def test_a_depth_hold_answers_a_hold_the_autopilot_could_not_take() -> None:
    ctl = MissionController(_plan(fix_timeout_s=0.5), POINTS)
    _fly(ctl, [(4.0, 4.0, -3.0)] * 5)
    commands = _fly(ctl, [None] * 20, t0=0.25)
    assert [k for _, k, _ in commands][-1] == "hold"
    for k in range(100):  # 5 s in ALT_HOLD (the bridge's fallback), past the mode grace
        ctl.on_mode("ALT_HOLD", now=1.5 + k * 0.05)
    states = [ctl.progress.state]
    ctl.on_mode("MANUAL", now=7.0)  # the pilot's own choice still ends the mission
    states.append(ctl.progress.state)
    assert states == ["paused", "aborted"]


def test_an_engage_the_autopilot_refuses_pauses_again_and_is_retried() -> None:
    ctl = MissionController(_plan(fix_timeout_s=0.5, resume_after_s=1.0), POINTS)
    here: list[tuple[float, float, float] | None] = [(4.0, 4.0, -3.0)]
    commands = _fly(ctl, here * 5)  # engaged, GUIDED taken
    commands += _fly(ctl, [None] * 20, t0=0.25, mode="POSHOLD")  # lost: hold, taken
    commands += _fly(ctl, here * 30, t0=1.25, mode="POSHOLD")  # good again: engage...
    assert [k for _, k, _ in commands].count("engage") == 2
    # ... which the autopilot refuses: still POSHOLD past the grace. Not the pilot: paused.
    commands = _fly(ctl, here * 100, t0=2.75, mode="POSHOLD")
    assert ctl.progress.engages_refused >= 1
    states = [ctl.progress.state]
    assert [k for _, k, _ in commands].count("engage") >= 1  # retried after resume_after_s
    # The pilot's own mode (MANUAL) still ends it.
    ctl.on_mode("MANUAL", now=20.0)
    states.append(ctl.progress.state)
    assert states[0] != "aborted"
    assert states[1] == "aborted"


def test_on_a_leg_the_target_runs_ahead_of_the_rov_on_the_line() -> None:
    """Off the line mid-leg, the ROV is sent back onto it ahead, not across to the leg's end."""
    ctl = MissionController(_plan(), POINTS)
    _fly(ctl, [(5.0, 4.0, -3.0)] * 3)  # engaged, at the first point: on to the second
    ctl.on_fix(good=True, position_m=(6.0, 4.4, -3.0), now=1.0)  # 0.4 m off the line
    ctl.on_mode(GUIDED, now=1.0)
    (goto,) = ctl.step(1.0)
    assert goto.kind == "goto"
    assert goto.waypoint == 1
    ahead = _plan().speed_m_s * CARROT_LEAD_S
    assert goto.position_m == pytest.approx((6.0 + ahead, 4.0, -3.0))
    assert ctl.leg_end(goto) == POINTS[1].position_m  # the follower still sees the leg's end
    # Within that of the end: the end itself; reached there, not at the target.
    ctl.on_fix(good=True, position_m=(8.7, 4.0, -3.0), now=2.0)
    (goto,) = ctl.step(2.0)
    assert goto.position_m == POINTS[1].position_m
    assert ctl.progress.waypoint == 1
