"""The mission's logic, without a bus: fixes and the vehicle's mode in, commands out.

States: `waiting` (no good fix yet) -> `running` (a GUIDED target per waypoint; a waypoint is
reached when the fix is within the plan's radius, then hovered `dwell_s`) -> `done`. No good
fix for the plan's `fix_timeout_s` (lost, or only unsure ones) pauses the mission: one `hold`
(the bridge puts ArduSub in POSHOLD) and nothing else until fixes have been good for
`resume_after_s` (no gap longer than `fix_timeout_s` between them), then `engage` again at
the same waypoint. One unsure fix among good ones does not pause: the autopilot rides through
a short gap on its own estimate. While running, the ROV waits for the ASV (the plan's
`view_guard`, capsd.mission.view_guard): when the ROV, now or a moment ahead, comes within
`edge_margin_deg` of the sonar's vertical aperture's edge, the target becomes where the ROV
is until it is `resume_margin_deg` inside again (the follower re-stations meanwhile) or
`max_wait_s` passed; after a wait that timed out, the guard waits again only once the view
was good. No view heard for `VIEW_VALID_S`: no waiting. The pilot always wins: if the vehicle
leaves the mode the mission asked for (after a grace for the switch itself), the mission is
`aborted` and sends nothing more; an engage the autopilot refuses (the vehicle still in the
hold the mission left it in) pauses again instead. `stop()` (Ctrl-C) sends a last `hold`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from capsd.mission.plan import Plan, Waypoint, cross_track_m

State = Literal["waiting", "running", "paused", "done", "aborted", "stopped"]
CommandKind = Literal["engage", "goto", "hold"]
# ArduSub's mode names as the bridge reports them (AutopilotStatus.mode).
GUIDED = "GUIDED"
POSHOLD = "POSHOLD"
# What the vehicle may answer a hold with: the bridge puts it in ALT_HOLD where ArduSub refuses
# POSHOLD for want of a position (the fixes stopped before the hold came).
HOLDS = (POSHOLD, "ALT_HOLD")
ANSWERS: dict[str, tuple[str, ...]] = {POSHOLD: HOLDS}
# The vehicle gets this long to take a mode the mission asked for before a different one is
# read as the pilot's choice.
MODE_GRACE_S = 3.0
# A target is repeated at this interval (a lost command is replaced).
REPEAT_S = 0.5
# On a leg the GUIDED target runs this many seconds of the plan's speed ahead of where the ROV
# is along the leg (`_target`): ArduSub flies straight at its target, so a target on the line
# ahead brings it back onto the line after anything that took it off (a wait for the ASV,
# a pause, the corner), where the leg's end would have it cut across (ArduSub SITL: a 16 m
# lane flown 0.2-0.5 m off after its corner, 231 mm RMS).
CARROT_LEAD_S = 2.0
# A view margin older than this is not acted on (no ASV pose: the guard does not wait).
VIEW_VALID_S = 1.0


@dataclass(frozen=True)
class Command:
    """What the mission asks of the ROV: engage GUIDED at a target, move the target, or hold."""

    kind: CommandKind
    waypoint: int
    position_m: tuple[float, float, float] | None
    reason: str


@dataclass
class Progress:
    """What a person watches, and the report's figures."""

    state: State = "waiting"
    waypoint: int = 0
    pauses: int = 0
    paused_s: float = 0.0
    cross_track_m: list[float] = field(default_factory=list)
    flown_m: list[tuple[float, float, float]] = field(default_factory=list)
    pause_latency_s: list[float] = field(default_factory=list)  # last good fix -> hold sent
    why: str = ""
    waits: int = 0  # times a leg waited for the ASV (the ROV near the view's edge)
    waited_s: float = 0.0
    waits_timed_out: int = 0
    engages_refused: int = 0  # GUIDED refused by the autopilot, the vehicle still holding


class MissionController:
    """Feed it fixes and the vehicle's mode; call `step(now)`; send the commands it returns."""

    def __init__(self, plan: Plan, points: list[Waypoint]):
        if not points:
            raise ValueError("a mission needs at least one waypoint")
        self.plan = plan
        self.points = points
        self.progress = Progress()
        self._last_good_s: float | None = None  # when the newest good fix arrived
        self._good_since_s: float | None = None
        self._position: np.ndarray | None = None
        self._asked: str | None = None  # the mode we last asked for
        self._asked_at = -math.inf
        self._mode: str | None = None  # the vehicle's, as last reported
        self._mode_before: str | None = None  # the vehicle's when we last asked
        self._taken = False  # the vehicle has reported the mode we last asked for
        self._last_sent = -math.inf
        self._arrived_at: float | None = None
        self._paused_at: float | None = None
        self._view_margin_rad: float | None = None
        self._view_at = -math.inf
        self._waiting_since: float | None = None
        self._wait_point: tuple[float, float, float] | None = None
        self._guard_armed = True

    # -------------------------------------------------------------------- inputs

    def on_fix(
        self, *, good: bool, position_m: tuple[float, float, float] | None, now: float
    ) -> None:
        """A fix arrived (`now` on the controller's clock)."""
        if not good or position_m is None:
            # Not a reset: "good for resume_after_s" means no gap longer than fix_timeout_s
            # between good fixes (the same measure that pauses), so a locator that is unsure
            # now and then still lets a paused mission resume.
            return
        gap = now - self._last_good_s if self._last_good_s is not None else math.inf
        if gap > self.plan.fix_timeout_s:
            self._good_since_s = now  # a new run of good fixes
        self._last_good_s = now
        self._position = np.array(position_m, dtype=np.float64)
        if self.progress.state in ("running", "paused"):
            self.progress.flown_m.append(position_m)
            k = self.progress.waypoint
            if k >= 1:  # along a leg of the plan (the transit to the first point is not)
                start = np.array(self.points[k - 1].position_m)
                end = np.array(self.points[k].position_m)
                self.progress.cross_track_m.append(cross_track_m(self._position, start, end))

    def on_mode(self, mode: str, *, now: float) -> None:
        """The vehicle's mode as the bridge reports it."""
        self._mode = mode
        state = self.progress.state
        if self._asked is None or state not in ("running", "paused"):
            return
        if mode in ANSWERS.get(self._asked, (self._asked,)):
            self._taken = True
            return
        if now - self._asked_at <= MODE_GRACE_S:
            return
        if self._asked == GUIDED and not self._taken and mode == self._mode_before in HOLDS:
            # The autopilot refused GUIDED (its estimates late: it had no position) and the
            # vehicle holds where the mission left it: no pilot's choice, so paused again, and
            # the engage retried once fixes have been good for `resume_after_s` anew.
            self.progress.engages_refused += 1
            self._repause(now, holding=mode)
            return
        self._finish(
            "aborted",
            f"the vehicle is in {mode}, not the {self._asked} the mission asked for: the "
            "pilot's choice wins (or the autopilot refused the mode, or the bridge refuses "
            "mission commands: its `mission_commands` and Health counters say)",
        )

    def on_view(self, margin_rad: float, *, now: float) -> None:
        """How far inside the vertical aperture the ROV is, now or a moment ahead (view_guard)."""
        self._view_margin_rad = margin_rad
        self._view_at = now

    def waiting(self) -> bool:
        """The leg waits for the ASV."""
        return self._waiting_since is not None

    # -------------------------------------------------------------------- decisions

    def fix_ok(self, now: float) -> bool:
        """A good fix no older than the plan's timeout."""
        return self._last_good_s is not None and now - self._last_good_s <= self.plan.fix_timeout_s

    def step(self, now: float) -> list[Command]:
        """The commands to send now (often none)."""
        p = self.progress
        if p.state in ("done", "aborted", "stopped"):
            return []
        if p.state == "waiting":
            # Fixes good for `start_after_s` first: the autopilot has then had positions long
            # enough to accept GUIDED (it refuses without them).
            good_for = now - self._good_since_s if self._good_since_s is not None else 0.0
            if self.fix_ok(now) and good_for >= self.plan.start_after_s:
                p.state = "running"
                return [self._engage(now, f"fix good for {good_for:.1f} s: start")]
            return []
        if p.state == "running":
            if not self.fix_ok(now):
                self._end_wait(now)
                return [self._pause(now)]
            waited = self._guard(now)
            return waited if waited is not None else self._advance(now)
        # paused
        assert self._paused_at is not None
        good_for = now - self._good_since_s if self._good_since_s is not None else 0.0
        if self.fix_ok(now) and good_for >= self.plan.resume_after_s:
            p.paused_s += now - self._paused_at
            self._paused_at = None
            p.state = "running"
            return [self._engage(now, f"fix good for {good_for:.1f} s: resume")]
        return []

    def stop(self, now: float) -> list[Command]:
        """Ctrl-C: leave the ROV holding position (unless the pilot already took it)."""
        if self.progress.state in ("aborted", "done", "stopped"):
            return []
        self._finish("stopped", "stopped by user")
        return [Command("hold", self.progress.waypoint, None, "stopped by user")]

    # -------------------------------------------------------------------- helpers

    def leg_end(self, command: Command) -> tuple[float, float, float] | None:
        """The waypoint `command`'s leg ends at (a wait's is not where it waits); None: a hold."""
        if command.kind == "hold" or not 0 <= command.waypoint < len(self.points):
            return None
        return self.points[command.waypoint].position_m

    def next_leg_end(self, command: Command) -> tuple[float, float, float] | None:
        """The waypoint after `leg_end(command)`; None: a hold, or the plan's last waypoint."""
        if command.kind == "hold" or not 0 <= command.waypoint + 1 < len(self.points):
            return None
        return self.points[command.waypoint + 1].position_m

    def _target(self) -> tuple[float, float, float]:
        """Where the ROV is sent now: on its leg, CARROT_LEAD_S at the plan's speed ahead.

        The ROV's newest good fix projected onto the leg (from the previous waypoint to
        this one), moved on along it; the waypoint itself within that of its end, on the way
        to the first waypoint (no leg yet) and without a fix.
        """
        k = self.progress.waypoint
        end = self.points[k].position_m
        if k == 0 or self._position is None:
            return end
        start = np.array(self.points[k - 1].position_m)
        leg = np.array(end) - start
        length = float(np.linalg.norm(leg))
        if length < 1e-6:
            return end
        along = min(max(float((self._position - start) @ leg) / length, 0.0), length)
        ahead = along + self.plan.speed_m_s * CARROT_LEAD_S
        if ahead >= length:
            return end
        x, y, z = start + leg * (ahead / length)
        return (float(x), float(y), float(z))

    def _engage(self, now: float, reason: str) -> Command:
        self._ask(GUIDED, now)
        self._last_sent = now
        return Command("engage", self.progress.waypoint, self._target(), reason)

    def _pause(self, now: float) -> Command:
        p = self.progress
        p.state = "paused"
        p.pauses += 1
        self._paused_at = now
        self._arrived_at = None
        if self._last_good_s is not None:
            p.pause_latency_s.append(now - self._last_good_s)
        self._ask(POSHOLD, now)
        return Command("hold", p.waypoint, None, "fix lost or unsure: hold position")

    def _advance(self, now: float) -> list[Command]:
        p = self.progress
        assert self._position is not None
        waypoint = np.array(self.points[p.waypoint].position_m)
        if float(np.linalg.norm(self._position - waypoint)) <= self.plan.accept_radius_m:
            self._arrived_at = self._arrived_at if self._arrived_at is not None else now
            if now - self._arrived_at >= self.points[p.waypoint].dwell_s:
                self._arrived_at = None
                if p.waypoint + 1 >= len(self.points):
                    self._finish("done", "every waypoint reached")
                    return [Command("hold", p.waypoint, None, "mission complete: hold")]
                p.waypoint += 1
                self._last_sent = now
                return [Command("goto", p.waypoint, self._target(), f"waypoint {p.waypoint}")]
        if now - self._last_sent >= REPEAT_S:
            self._last_sent = now
            return [Command("goto", p.waypoint, self._target(), "repeat")]
        return []

    def _guard(self, now: float) -> list[Command] | None:
        """The view guard's commands while it waits (or as it starts or ends); None: fly on."""
        guard = self.plan.view_guard
        p = self.progress
        fresh = now - self._view_at <= VIEW_VALID_S and self._view_margin_rad is not None
        if guard.mode == "off" or not fresh:
            if self._waiting_since is not None:
                self._end_wait(now)
                self._last_sent = now
                return [Command("goto", p.waypoint, self._target(), "view unknown: on")]
            return None
        assert self._view_margin_rad is not None
        margin_deg = math.degrees(self._view_margin_rad)
        if self._waiting_since is None:
            if margin_deg >= guard.resume_margin_deg:
                self._guard_armed = True
            if not self._guard_armed or margin_deg >= guard.edge_margin_deg:
                return None
            assert self._position is not None
            self._waiting_since = now
            self._wait_point = (
                float(self._position[0]), float(self._position[1]), float(self._position[2]),
            )  # fmt: skip
            p.waits += 1
            self._last_sent = now
            why = "waiting for the ASV: the ROV near the edge of the sonar's view"
            return [Command("goto", p.waypoint, self._wait_point, why)]
        if margin_deg >= guard.resume_margin_deg:
            self._end_wait(now)
            self._last_sent = now
            return [Command("goto", p.waypoint, self._target(), "in view again: on")]
        if now - self._waiting_since >= guard.max_wait_s:
            self._end_wait(now)
            self._guard_armed = False  # not again until the view was good
            p.waits_timed_out += 1
            self._last_sent = now
            return [Command("goto", p.waypoint, self._target(),
                            f"waited {guard.max_wait_s:g} s for the ASV: on")]  # fmt: skip
        if now - self._last_sent >= REPEAT_S:
            self._last_sent = now
            assert self._wait_point is not None
            return [Command("goto", p.waypoint, self._wait_point, "repeat")]
        return []

    def _end_wait(self, now: float) -> None:
        if self._waiting_since is not None:
            self.progress.waited_s += now - self._waiting_since
        self._waiting_since = None
        self._wait_point = None

    def _ask(self, mode: str, now: float) -> None:
        self._asked, self._asked_at = mode, now
        self._mode_before, self._taken = self._mode, False

    def _repause(self, now: float, *, holding: str) -> None:
        """Back to paused after a refused engage, the vehicle holding in `holding`."""
        self._end_wait(now)
        self.progress.state = "paused"
        self._paused_at = now
        self._arrived_at = None
        self._good_since_s = now  # a new run of good fixes before the next engage
        self._asked, self._asked_at, self._taken = holding, now, True

    def _finish(self, state: State, why: str) -> None:
        self.progress.state = state
        self.progress.why = why
