"""When the ASV moves, and how: a station held until the ROV leaves its comfort zone.

No chasing of noise: the station is kept while the ROV, seen from the station, stays within
`elevation_tolerance` of the elevation the station was chosen for, `azimuth_tolerance` of the
boresight and the range band, and no mapped fixture shares its range cell (capsd.echo_cell,
also just beyond the aperture's edge); only then (and at most every `replan_after_s`) is a new
one chosen, from good fixes only, for where the ROV will be `lead_s` later at its tracked
velocity (a ROV flying a survey leg would otherwise leave every station as soon as it is
reached), but not past the waypoint its mission sent it to; of the stations, those that also see the
next `path_ahead_m` of the ROV's leg are preferred (the planner's path cost). A new station
that looks at the ROV from the other side (its bearing turned more than `side_switch_rad`)
keeps the choices to that side for `side_commit_s`, where another side has a station.
Without a good fix for `fix_timeout_s` the ROV is looked for where it will hold: a ROV on a
mission stops within a second of losing its fix, so the last good fix carried on at the
tracked velocity for up to `stop_within_s`. If that point lies outside the station's view (the
ROV left the aperture faster than the ASV moved), a station for it is chosen at once; else the
ASV holds its station, and still without a fix after `reacquire_after_s` it searches, a new look
every `reacquire_after_s`. A ROV holding without positions wanders (dead reckoning, at up to
`lost_drift_m_s` in a direction nobody knows), so it may be anywhere on a disc round where it
stopped that grows with the time lost (clipped to the tank: the ROV is in it). Each look is the
station, of those the planner chooses for points spread over the disc, whose view (aperture,
range band, 45 deg either side of the boresight) covers most of the disc; points a look of
this loss already covered from about the same bearing count a third (the ROV was not there, or
clutter or its own shadow hid it from that side: the station that lost it counts so too), so
the looks go round. A look is held until its station has been reached and watched 2 s.
The target sent to the autopilot is a carrot that walks from where the ASV was told to be
towards the station, speed and acceleration limited, turning at a bounded rate; it starts where
the ASV is when the pilot hands over (GUIDED) and nothing is sent in any other mode. On the
way the hull is to face the ROV (or where it is looked for), at the station the ROV itself
(without a fresh fix, the station's heading, unless the ROV is held beyond the sonar's
reach from it); ArduRover turns a hull only at its target, so
while the hull faces more than `turn_first_rad` off that heading the carrot turns where the
hull is, and only then walks;
a way that would pass over the ROV (to a station on its other side) goes round it, no nearer
than where the ROV sits at the target elevation, on the side it first took (straight where
the walls stop it).

That is the lateral drive (the planner's `drive`: an omni frame that moves any way with its
heading kept). ArduRover's GUIDED drives a boat and an omni frame alike: a forward speed and a
turn rate, the hull turned to its way, the target's yaw ignored (the steered drive). There the
sonar looks along the way whenever the ASV moves, so the ASV watches the ROV by turning where
it is: the dead band has no azimuth (the station is seen facing the ROV), the planner prefers
staying, or a way at the ROV, and charges each second a move would turn the sonar off it; on
the way the hull is asked for the way's heading, its bow's or (backing away from the ROV,
MAV_CMD_DO_SET_REVERSE) its stern's, chosen as the way to a station starts (turning first is
turning to the way; again only for a station `DIRECTION_KEEP_M` from it; with the ROV nearer the
sonar than `min_range_m`, the end the hull turns to least, kept until the ROV is NEAR_LEAVE_M
further off) and, once the carrot is at the
station, to face the ROV; the carrot is not
pushed off a near ROV (each push a new way to steer for: it re-stations instead).

A sonar on a tilt servo is told the tilt for where the ROV will be `tilt_lead_s` on; without
a fresh fix the tilt nods about where the ROV is looked for (`nod_*`), first the way the
fixes' tilt last went. On a pan servo too, the pan faces the ROV (held while the ROV stays
within `pan_dead_band_rad` of it), and the hull at its station may turn `pan_abeam_rad` off it
(60 deg by default): the sonar ahead of the origin then stays off a near ROV. With
`pan_abeam_rad` 0 it faces the ROV, but where that would put the sonar nearer than
`min_range_m` it turns as far off as the pan lets it (NEAR_ABEAM_RAD).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from capsd.geometry import Array, wrap_angle
from capsd.payloads import DriveDirection
from capsd.services.asv_follow.station import (
    ABEAM_PAN_MARGIN_RAD,
    AROUND_STEP_RAD,
    STAY_M,
    Station,
    StationPlanner,
    View,
    drive_heading,
    round_turn,
)
from capsd.services.asv_follow.station import AROUND_WITHIN as STATION_AROUND_WITHIN

FollowState = Literal["standby", "holding", "following", "no_station"]
# This near its station a hull has settled there (an autopilot stops short by its arrival
# radius): a holding ROV's view is judged from the hull then.
SETTLED_M = 0.5
ARRIVED_M = 1.0  # this near its station the hull faces the ROV itself, not where it will be
# At its station the hull turns to face the ROV once it is this far off the boresight.
FACE_WITHIN_RAD = math.radians(3.0)
# A way that passes nearer the ROV than this share of the carrot's or the station's distance
# from it goes round instead (station.round_turn).
AROUND_WITHIN = STATION_AROUND_WITHIN
# A lost ROV is looked for over a disc round where it stopped (points on rings at these shares
# of its radius), its centre at least this far from a wall (half a BlueROV2's length); the
# disc is at least SEARCH_MIN_RADIUS_M across (where it stopped is not known better).
SEARCH_RINGS = ((0.5, 6), (1.0, 12))
SEARCH_MIN_RADIUS_M = 0.3
SEARCH_WALL_MARGIN_M = 0.3
# A look covers the points its sonar sees in the aperture, the range band and this far
# either side of its boresight (the fan is wider; its edges are weak).
SEARCH_HALF_FAN_RAD = math.radians(45.0)
# A point an earlier look of the same loss covered (within SEARCH_SEEN_M, from a bearing
# within SEARCH_SAME_SIDE_RAD) counts this much.
SEARCH_SEEN_WEIGHT = 1.0 / 3.0
SEARCH_SEEN_M = 0.15
SEARCH_SAME_SIDE_RAD = math.radians(40.0)
# The next look waits until the carrot has been at this one's station this long (or this long
# since it was chosen: a station never quite reached).
SEARCH_DWELL_S = 2.0
SEARCH_STUCK_S = 30.0
# A mission repeats its waypoint twice a second: one not heard for this long is forgotten
# (the mission ended, or a pilot flies by hand).
LEG_END_VALID_S = 5.0
# The lead is at most this share of the ideal horizontal distance to the ROV.
LEAD_SHARE = 0.25
PATH_STEP_M = 0.25  # the spacing of the points of the ROV's leg a station is to see
# Steered: a way at most this far across the ROV's line of sight goes along it only.
ACROSS_SLACK_M = 0.5
# A ROV holding on its leg is expected to go on at this (a plan's default speed_m_s).
LEG_SPEED_M_S = 0.25
ALONG_SIGHT_COS = math.cos(math.radians(45.0))  # ... where its leg runs along the sight
# The way a fresh fix's tilt went: judged over this long, a change under this is none.
NOD_TREND_S = 0.5
NOD_TREND_MIN_RAD = math.radians(0.5)
PAN_SETTLED_RAD = math.radians(1.0)  # a pan turning onto the bearing stops this near it
# A way round the ROV keeps the side it took while its station stays this near where it was
# (and the other way round turns at most ROUND_KEEP_MAX_RAD of bearing).
ROUND_KEEP_M = 1.0
ROUND_KEEP_MAX_RAD = math.radians(240.0)
# A steered hull's way (ahead or astern) is chosen again for a station this far from the one it
# was chosen for: the stations re-chosen each second as the ROV goes on moved 0.2 m, and each
# time the way's end was chosen again; past the ROV the stern faced it better, and the hull
# stopped for a half turn next to it (`capsd bench follow`, mockup pan-tilt, 20 seeds: in view
# 96.9 -> 97.8 % a run).
DIRECTION_KEEP_M = 0.5
# How far off facing the ROV a pan-tilt hull at its station turns where facing it would put
# the sonar too near (`Follower._near_facing`): as far as the pan's margin lets it.
NEAR_ABEAM_RAD = math.radians(90.0)
NEAR_ABEAM_LEAVE_M = 0.15
NEAR_LEAVE_M = 0.15  # ... and the end chosen for a ROV too near (`Follower._too_near`)
# A pan-tilt hull's way is driven by its other end where the one chosen would put the ROV
# further than this past the pan's reach (the fan is 130 deg wide, but its edges are weak)
# and the other end keeps it this much nearer (`Follower._kept_in_reach`).
PAST_PAN_SEEN_RAD = math.radians(45.0)
PAST_PAN_BETTER_RAD = math.radians(10.0)


@dataclass(frozen=True)
class FollowSettings:
    """Dead band, timing and motion limits of the follower."""

    elevation_tolerance_rad: float = math.radians(4.0)
    azimuth_tolerance_rad: float = math.radians(15.0)
    replan_after_s: float = 2.0
    fix_timeout_s: float = 1.0
    lead_s: float = 3.0
    reacquire_after_s: float = 6.0
    min_lead_speed_m_s: float = 0.05  # slower than this is hovering (or noise): no lead
    # Stations are chosen to see the ROV's mission leg this far ahead of it, too (the
    # planner's path cost): at the plan's 0.25 m/s, the next 6 s.
    path_ahead_m: float = 1.5
    # A ROV that lost its fix holds within this: its mission pauses 0.5 s after the last good
    # fix (the plan's fix_timeout_s) and ArduSub brakes in about 0.5 s more (0.25 m/s at
    # 0.25 m/s^2). Longer, the look for it aims past where it stopped and can turn the sonar
    # off a ROV still in view (a recorded mockup run: 0.46 m past, the ROV 0.05 m past).
    stop_within_s: float = 1.0
    lost_drift_m_s: float = 0.02  # how fast a ROV holding without positions may wander
    max_speed_m_s: float = 0.3
    max_accel_m_s2: float = 0.1
    max_yaw_rate_rad_s: float = math.radians(15.0)
    # A station whose heading is further than this from the hull's is turned to before the
    # ASV goes: ArduRover's GUIDED turns a hull only at its target (the bridge's heading-only
    # targets), so a carrot that walks while the hull faces the old way keeps the sonar looking
    # away from the ROV for the whole trip.
    turn_first_rad: float = math.radians(30.0)
    # A tilt servo is aimed where the ROV will be this far ahead, at its tracked velocity: the
    # fix's age, the command's way through the ASV's bridge and autopilot, the servo's slew.
    tilt_lead_s: float = 0.5
    # Without a fresh fix a tilt servo nods about where the ROV is looked for: this far either
    # side (None: the vertical aperture's half, so the sweep covers twice the aperture), at
    # this rate (half a 30 deg/s servo's), first the way the fixes last went. Where the ROV
    # was lost it is not in the aperture, and its elevation is what a small tank's fixes lose
    # first (a mockup pan-tilt demo, seed 0: the ROV 8-11 deg below the boresight for 10 s,
    # the last fixes biased 0.2 m past it, the servo aimed there).
    nod_amplitude_rad: float | None = None
    nod_rate_rad_s: float = math.radians(15.0)
    # With a pan servo the hull at its station is turned this far off facing the ROV (the pan
    # faces it), kept within the slack (`Follower._abeam`); 0: it faces the ROV.
    pan_abeam_rad: float = math.radians(60.0)
    pan_abeam_slack_rad: float = math.radians(20.0)
    # The pan is held while the ROV's bearing stays this near it, then turned onto the bearing:
    # the fan is 130 deg wide, and every turn of the servo moves the fixes (its slew is
    # modelled from reports up to a report period late: a mockup demo's fixes scattered 8-11 mm
    # across the line of sight with the pan still, 27-57 mm with it turning 2-15 deg in 0.5 s).
    pan_dead_band_rad: float = math.radians(15.0)
    # A station that looks at the ROV from the other side (its bearing turned more than
    # `side_switch_rad`) is kept to that side for `side_commit_s`: where the ROV sits between
    # two sides that both barely see it, each new choice otherwise went back to the side the
    # hull had just left (a mockup pan-tilt demo, seed 2: 13 switches, 11 of them back within
    # 6 s, the hull left midway 0.9 m off the ROV, which the detector then lost for 15 s).
    side_commit_s: float = 10.0
    side_switch_rad: float = math.radians(90.0)


@dataclass(frozen=True)
class Target:
    """What the autopilot is told: a position (W, the ASV origin) and a heading."""

    position_xy: Array
    heading_rad: float
    state: FollowState
    replanned: bool  # a new station was chosen on this step
    direction: DriveDirection = "forward"  # steered: the hull ahead or astern to the position
    # A sonar on a tilt servo: the angle it is to take (added to the mount's pitch, down +),
    # for the ROV where it is (or is looked for) from where the ASV is now; None: no servo.
    sonar_tilt_rad: float | None = None
    # ... on a pan servo too: the pan that faces it (added to the mount's yaw, left +).
    sonar_pan_rad: float | None = None


def _along(start_m: Array, end_m: Array, reach_m: float) -> Array | None:
    """Points every PATH_STEP_M from `start_m` (excluded) towards `end_m`, at most `reach_m` on."""
    way = end_m - start_m
    length = float(np.linalg.norm(way[:2]))
    reach = min(length, reach_m)
    if reach < PATH_STEP_M:
        return None
    steps = np.arange(1, int(reach / PATH_STEP_M) + 1) * PATH_STEP_M
    out: Array = start_m + np.outer(steps / length, way)
    return out


def _closing_direction(
    hull_xy: Array, hull_heading_rad: float, target_xy: Array, *, current: DriveDirection
) -> DriveDirection:
    """The way done, how a steered hull closes what is left to its target: the end facing it.

    The autopilot steers the driving end at a target beyond its arrival radius; the way's
    direction kept there turned a hull that had overshot a station (chosen where it was, while
    it backed off the ROV at speed) half round to back the last 0.6 m, its sonar off the ROV
    for 20 s (nfp demo, session 38, at the first lane's start). On its target (within STAY_M)
    the `current` direction is kept.
    """
    rest = target_xy - hull_xy
    if float(np.linalg.norm(rest)) <= STAY_M:
        return current
    bearing = math.atan2(float(rest[1]), float(rest[0]))
    return "forward" if math.cos(bearing - hull_heading_rad) >= 0.0 else "reverse"


class Follower:
    """Feed `on_pose`, `on_fix` and `on_mode`; `step(now_s)` gives the target (or None)."""

    def __init__(self, planner: StationPlanner, settings: FollowSettings):
        self.planner = planner
        self.settings = settings
        self.mode: str | None = None
        self.asv_xy: Array | None = None
        self.asv_heading = 0.0
        self.rov_m: Array | None = None
        self.rov_velocity = np.zeros(3)
        self.fix_s = -math.inf
        self.station: Station | None = None
        self.replans = 0
        self._carrot: Array | None = None
        self._carrot_v = np.zeros(2)
        self._carrot_heading = 0.0
        self._last_plan_s = -math.inf
        # The bearing a station last looked from before the side was switched, and when.
        self._left_side: tuple[float, float] | None = None
        self.looks = 0  # stations chosen to look again at a lost ROV
        # Where this loss's looks saw no ROV, and from which bearing (W: x, y, bearing).
        self._seen: list[tuple[float, float, float]] = []
        self._searched = False  # this loss has had a search look
        self._arrived_s: float | None = None  # when the carrot reached the look's station
        self._aim: Array | None = None  # where the station was chosen to look
        self._held: Array | None = None  # without a fresh fix: where the ROV holds
        self._pan_told: float | None = None  # the pan servo's angle last asked for
        self._panning = False  # ... and it is on its way to the ROV's bearing (out of the band)
        # The tilt a fresh fix last asked for, when, and which way it went (down +1, up -1):
        # a nod starts that way.
        self._tilt_wanted: tuple[float, float] | None = None
        self._tilt_trend = 1.0
        self._abeam_heading: float | None = None  # the hull's heading off the ROV (`_abeam`)
        self._near = False  # `_near_facing` last said so
        self._last_step_s: float | None = None
        self.leg_end: Array | None = None  # where the ROV's mission sends it now (W)
        self._direction: DriveDirection = "forward"  # steered: how the hull drives its way
        self._direction_for: Array | None = None  # ... to this station
        # The end `_kept_in_reach` chose for the way to this station (kept while it stays).
        self._reach_for: tuple[Array, DriveDirection] | None = None
        self._too_near_now = False  # `_too_near` last said so
        self._sight_only = False  # steered: this station's way goes along the sight only
        self._sight_for: Array | None = None  # ... decided for this station
        # The way round the ROV: which side (+1 left, -1 right) and to which station.
        self._round: tuple[float, Array] | None = None
        self._leg_end_s = -math.inf
        self.next_leg_end: Array | None = None  # the waypoint after `leg_end`, where told

    def on_leg_end(
        self, now_s: float, position_m: Array | None, next_m: Array | None = None
    ) -> None:
        """The waypoint the ROV's mission sent it to (None: it holds, the leg kept).

        `next_m`: the waypoint after it (None: the last, or not told). Where the rest of the
        leg is shorter than `path_ahead_m`, stations are also to see the start of the next leg:
        a station that sees a lane to its end but not the turn after it is driven into a wall
        there (`capsd bench follow`, docs/JOURNAL.md session 38).

        A hold pauses the leg, it does not end it: the mission resumes the same waypoint. (The
        leg dropped at each hold made the stations alternate between one chosen for the leg
        and one for a ROV going nowhere, 7 m apart: an nfp run, 60 s.) A mission that stopped
        sends nothing more, and its leg is forgotten after LEG_END_VALID_S.
        """
        if position_m is not None:
            self.leg_end = np.asarray(position_m, dtype=np.float64)
            self.next_leg_end = None if next_m is None else np.asarray(next_m, dtype=np.float64)
        self._leg_end_s = now_s

    def on_pose(self, xy: Array, heading_rad: float) -> None:
        self.asv_xy = np.asarray(xy[:2], dtype=np.float64)
        self.asv_heading = heading_rad

    def on_fix(self, now_s: float, rov_m: Array, velocity_m_s: Array | None = None) -> None:
        """A good fix of the ROV (the caller passes only those), with its tracked velocity."""
        self._seen, self._searched = [], False  # found: a new loss searches afresh
        self.rov_m = np.asarray(rov_m, dtype=np.float64)
        self.rov_velocity = np.zeros(3) if velocity_m_s is None else np.asarray(velocity_m_s)
        self.fix_s = now_s

    def on_mode(self, mode: str | None) -> None:
        if mode != "GUIDED":
            self._carrot = None  # a new hand-over starts where the ASV then is
            self.station = None
        self.mode = mode

    def step(self, now_s: float) -> Target | None:
        dt = 0.0 if self._last_step_s is None else max(0.0, now_s - self._last_step_s)
        self._last_step_s = now_s
        if now_s - self._leg_end_s > LEG_END_VALID_S:
            self.leg_end = None
            self.next_leg_end = None
        if self.mode != "GUIDED" or self.asv_xy is None:
            return None
        if self._carrot is None:
            self._carrot = self.asv_xy.copy()
            self._carrot_v = np.zeros(2)
            self._carrot_heading = self.asv_heading
        fresh = self.rov_m is not None and now_s - self.fix_s <= self.settings.fix_timeout_s
        self._note_arrival(now_s)
        replanned = False
        if (
            fresh
            and now_s - self._last_plan_s >= self.settings.replan_after_s
            and self._needs_station()  # last: it looks at the map
        ):
            assert self.rov_m is not None
            self._last_plan_s = now_s
            chosen = self._choose_committed(now_s)
            if chosen is not None:
                self.station = chosen
                self._aim = self._ahead()
                self.replans += 1
                replanned = True
        lost_for = now_s - self.fix_s
        self._held = None if fresh or self.rov_m is None else self._held_at(lost_for)
        if (
            not fresh
            and self.rov_m is not None
            and self.station is not None
            and not self._searched  # once searching, the search's looks decide
            # Not for longer: where no station sees that point (a last fix off by the wall),
            # this would take every turn and the search below never start (a mockup run:
            # the ASV held 280 s).
            and lost_for < self.settings.reacquire_after_s
            and now_s - self._last_plan_s >= self.settings.replan_after_s
            and not self._in_view_of_station(held := self._held_at(lost_for))
        ):
            # Lost where the station cannot see it (it left the aperture faster than the ASV
            # re-stationed): a ROV on a mission holds near where it was lost, so look there now.
            self._last_plan_s = now_s
            chosen = self.planner.choose(held, self._carrot, self._carrot_heading)
            if chosen is not None:
                self.station = chosen
                self._aim = held
                self.looks += 1
                replanned = True
        elif (
            not fresh
            and self.rov_m is not None
            and self.station is not None
            and lost_for >= self.settings.reacquire_after_s
            and now_s - self._last_plan_s >= self.settings.reacquire_after_s
            # The first look too waits for the station in hand: a ROV lost on a blind way to
            # a station chosen to see it is seen once the hull is there and faces it (a bench
            # run: a search 6 s into the loss sent the ASV 5 m off, blind, as it arrived).
            and self._looked_long_enough(now_s)
        ):
            self._last_plan_s = now_s
            self._arrived_s = None
            look = self._search_look(lost_for)
            if look is not None:
                self.station, self._aim = look
                self.looks += 1
                replanned = True
        state: FollowState
        if self.station is None:
            state = "no_station" if fresh else "holding"
        else:
            state = "following" if fresh else "holding"
        self._walk(dt, fresh=fresh)
        tilt, pan = self._sonar_angles(now_s, fresh=fresh, dt=dt)
        return Target(
            self._carrot.copy(),
            self._carrot_heading,
            state,
            replanned,
            self._direction,
            tilt,
            pan,
        )

    def _choose_committed(self, now_s: float) -> Station | None:
        """A station for the ROV ahead, kept off the side left within `side_commit_s`.

        Off it only while another side has a station; a choice that switches sides starts
        the commitment again.
        """
        assert self.rov_m is not None
        current = None if self.station is None else self.planner.bearing(self.station)

        def choose(avoid_rad: float | None) -> Station | None:
            assert self._carrot is not None
            return self.planner.choose(
                self._ahead(),
                self._carrot,
                self._carrot_heading,
                avoid_bearing_rad=avoid_rad,
                avoid_within_rad=self.settings.side_switch_rad,
                rov_velocity_m_s=self._horizontal_velocity(),
                current_bearing_rad=current,
                path_m=self._leg_path(),
            )

        left = self._left_side
        chosen = None
        if left is not None and now_s - left[0] < self.settings.side_commit_s:
            chosen = choose(left[1])
        if chosen is None:
            chosen = choose(None)
        if chosen is not None and current is not None:
            turned = abs(wrap_angle(self.planner.bearing(chosen) - current))
            if turned > self.settings.side_switch_rad:
                self._left_side = (now_s, current)
        return chosen

    def _sonar_angles(
        self, now_s: float, *, fresh: bool, dt: float
    ) -> tuple[float | None, float | None]:
        """The servos' angles (tilt, pan) for the ROV now (or where it is looked for).

        Seen from the ASV now. Where the ROV is, not where the station was chosen for (its
        lead): the servos are fast and the fix is what must stay in the aperture. Held (None)
        with nothing to look at; the pan None without a pan servo.

        The pan faces the fix itself (held within `pan_dead_band_rad` of it), without the
        tilt's velocity lead, and is asked to turn no faster than the servo does (`dt` since
        the last step): a pan turns the sonar's azimuth, and a fix whose azimuth is a little
        off (the servo reported where it goes, not where it is) moves the fix, its tracked
        velocity, the lead and so the pan the same way; a mockup pan-tilt demo's pan ran 57
        deg off a ROV 4 deg off the bow so.
        """
        if self.planner.tilt is None or self.asv_xy is None or self.rov_m is None:
            return None, None
        if fresh:
            look = self.rov_m + self.rov_velocity * self.settings.tilt_lead_s
        else:
            lost = self._lost_look()
            look = self.rov_m if lost is None else lost
        if self.planner.pan is None:
            pan = None
            tilt = self.planner.tilt_rad(self.asv_xy, self.asv_heading, look)
        else:
            facing = self.rov_m if fresh else look
            pan, _ = self.planner.pan_tilt_rad(self.asv_xy, self.asv_heading, facing)
            if self._pan_told is not None:
                off = pan - self._pan_told
                if not self._panning and abs(off) <= self.settings.pan_dead_band_rad:
                    pan = self._pan_told  # the fan is wide: hold the pan still
                else:
                    self._panning = abs(off) > PAN_SETTLED_RAD
                    most = math.radians(self.planner.pan.rate_deg_s) * dt
                    pan = self._pan_told + max(-most, min(most, off))
            self._pan_told = pan
            _, tilt = self.planner.pan_tilt_rad(
                self.asv_xy, self.asv_heading, look, pan_now_rad=pan
            )
        return self._nodded(now_s, tilt, fresh=fresh), pan

    def _nodded(self, now_s: float, tilt_rad: float, *, fresh: bool) -> float:
        """The tilt, nodding about `tilt_rad` without a fresh fix (FollowSettings.nod_*).

        A triangle wave: from the look's tilt first the way the fresh fixes' tilt last went,
        out to the amplitude, over to the other side and back, for as long as the fix is lost.
        """
        assert self.planner.tilt is not None
        if fresh:
            if self._tilt_wanted is not None:
                was_s, was = self._tilt_wanted
                if now_s - was_s >= NOD_TREND_S:
                    if abs(tilt_rad - was) >= NOD_TREND_MIN_RAD:
                        self._tilt_trend = 1.0 if tilt_rad > was else -1.0
                    self._tilt_wanted = (now_s, tilt_rad)
            else:
                self._tilt_wanted = (now_s, tilt_rad)
            return tilt_rad
        s = self.settings
        amplitude = s.nod_amplitude_rad
        if amplitude is None:
            amplitude = self.planner.half_aperture
        if amplitude <= 0.0:
            return tilt_rad
        # Time since the fix went stale, in quarter periods of the triangle (amplitude each).
        phase = (now_s - self.fix_s - s.fix_timeout_s) * s.nod_rate_rad_s / amplitude
        phase %= 4.0
        offset = phase if phase <= 1.0 else (2.0 - phase if phase <= 3.0 else phase - 4.0)
        return self.planner.tilt.clamp_rad(tilt_rad + self._tilt_trend * amplitude * offset)

    def _look_point(self, *, fresh: bool) -> Array | None:
        """Where the ROV is (ahead, with a fresh fix) or is looked for (`_lost_look`)."""
        return self._ahead() if fresh and self.rov_m is not None else self._lost_look()

    def _lost_look(self) -> Array | None:
        """Without a fresh fix: where the ROV holds, or, once searching, the look's aim.

        Not the station's aim before the search: that is where the ROV was to be `lead_s` on,
        and a ROV that lost its fix stops (a mockup servo run, seed 2: the servo tilted 20
        deg up to a point on the leg ahead, the ROV 35-44 deg below the boresight, 25 s).
        """
        if self._searched or self._held is None:
            return self._aim
        return self._held

    def _around(self, look: Array | None, station_xy: Array) -> Array:
        """Where the carrot heads: the station, or round the ROV when the way passes over it.

        A straight way to a station on the ROV's other side passes over it, where the ROV is
        under the sonar's aperture; instead the carrot goes round on a spiral from its own
        distance to the station's, at most AROUND_STEP_RAD of bearing ahead at a time, kept
        as far from the walls as a station must be.
        """
        assert self._carrot is not None
        if look is None:
            return station_xy
        centre = look[:2]
        turn = self._kept_round(
            round_turn(self._carrot, station_xy, centre, within=AROUND_WITHIN), station_xy
        )
        if turn == 0.0:
            return station_xy
        here = self._carrot - centre
        r_here = float(np.linalg.norm(here))
        r_there = float(np.linalg.norm(station_xy - centre))
        a_here = math.atan2(here[1], here[0])
        step = math.copysign(AROUND_STEP_RAD, turn)
        # On the tangent, not the circle: heading for a point on the circle cuts inside it.
        radius = (r_here + (r_there - r_here) * step / turn) / math.cos(step)
        direction = np.array([math.cos(a_here + step), math.sin(a_here + step)])
        # No nearer than where the ROV sits at the target elevation where the walls leave room:
        # a ROV flying towards the carrot, or a carrot that starts close, would otherwise take
        # the way round under the aperture (the sonar a little ahead of the origin).
        wide = max(radius, self.planner.ideal_distance(look) + float(self.planner.mount_xy[0]))
        point = centre + wide * direction
        if wide > radius and not (
            self.planner.clear(point) and np.allclose(self.planner.within_walls(point), point)
        ):
            point = centre + radius * direction
        # Never nearer a wall than a station may be (closer to the ROV there, if need be); a
        # keep-out box in the way: straight. Nor where the carrot already is: a way round
        # that the walls stop (the spiral's next point outside them, moved back onto the
        # carrot) goes straight too (`capsd bench follow`, mockup pan-tilt, seed 9: the hull
        # held at a corner of its box 28 s, the ROV lost 0.9 m off).
        point = self.planner.within_walls(point)
        if float(np.linalg.norm(np.asarray(point) - self._carrot)) < STAY_M:
            self._round = None
            return station_xy
        return np.asarray(point) if self.planner.clear(point) else station_xy

    def _kept_round(self, turn_rad: float, station_xy: Array) -> float:
        """`turn_rad` round the ROV, the other way where that keeps the side the way took.

        A station on the ROV's far side, nearly behind it, is as near round either side; the
        side then turned with the point looked at (the fix's, then the held ROV's, a few cm
        apart), and a steered hull backing round it was asked to face one way then the other
        and never went (`capsd bench follow`, mockup pan-tilt, seed 3: 60 s at 0.9 m).
        """
        if turn_rad == 0.0:
            self._round = None
            return turn_rad
        side = math.copysign(1.0, turn_rad)
        if self._round is not None:
            kept, to_xy = self._round
            other = turn_rad + kept * 2.0 * math.pi
            if (
                side != kept
                and float(np.linalg.norm(to_xy - station_xy)) <= ROUND_KEEP_M
                and abs(other) <= ROUND_KEEP_MAX_RAD
            ):
                turn_rad, side = other, kept
        self._round = (side, np.asarray(station_xy, dtype=np.float64).copy())
        return turn_rad

    def _wanted_heading(self, *, fresh: bool) -> float:
        """The hull's heading now: the sonar on the ROV on the way and at the station.

        On the way it faces where the ROV will be (or is looked for); at the station, with a
        fresh fix, the ROV itself, within FACE_WITHIN_RAD (else the station's heading). A
        conical beam's elevation drops off its boresight: a ROV 25 deg off it sits 4 deg lower
        than one faced, at 6 m and 30 deg down (session 30's nfp runs: of the pings refused as
        just below the aperture, two thirds had the ROV more than 15 deg off the boresight).
        """
        assert self.station is not None
        look = self._look_point(fresh=fresh)
        if self.asv_xy is None or look is None:
            return self.station.heading_rad
        arrived = float(np.linalg.norm(self.station.position_xy - self.asv_xy)) <= ARRIVED_M
        if arrived:
            if not fresh or self.rov_m is None:
                if self._reaches(look, self.station.heading_rad) and not self._near_facing(look):
                    return self.station.heading_rad
            else:
                look = self.rov_m
        offset = look[:2] - self.asv_xy
        # Under the hull there is no bearing to face. (Not "nearer than ARRIVED_M": in a small
        # tank the ROV is always that near, and the hull turned to a station's heading on the
        # ROV's far side while still on this one, the sonar facing away: a mockup run, 20 s.)
        if float(np.linalg.norm(offset)) < self.planner.settings.hull_radius_m:
            return self.station.heading_rad
        facing = wrap_angle(math.atan2(offset[1], offset[0]) - self.planner.mount_yaw)
        if arrived and self.planner.pan is not None:
            if self.settings.pan_abeam_rad > 0.0:
                return self._abeam(facing, self.settings.pan_abeam_rad)
            if self._near_facing(look):
                return self._abeam(facing, NEAR_ABEAM_RAD)
        if arrived and abs(wrap_angle(facing - self._carrot_heading)) < FACE_WITHIN_RAD:
            return self._carrot_heading  # no chasing of the fixes' jitter
        return facing

    def _reaches(self, look: Array, heading_rad: float) -> bool:
        """Whether the sonar turns onto `look` from a hull on `heading_rad` (pan or fan).

        Without a fresh fix a hull at its station holds the station's heading; where the ROV
        is held beyond the pan's reach from there, it is never looked at until a search (a
        mockup pan-tilt demo, seed 6: the ROV 115-140 deg off the bow, lost for 45 s).
        """
        assert self.asv_xy is not None
        if float(np.linalg.norm(look[:2] - self.asv_xy)) < self.planner.settings.hull_radius_m:
            return True
        off_bow = wrap_angle(self.planner.facing(self.asv_xy, look) - heading_rad)
        if self.planner.pan is None:
            return abs(off_bow) <= SEARCH_HALF_FAN_RAD
        left, right = self.planner.pan_room_rad()
        return -right <= off_bow <= left

    def _near_facing(self, look: Array) -> bool:
        """Whether a pan-tilt hull facing `look` from where it is puts the sonar too near it.

        Nearer than `min_range_m`, where the detector misses it: in a small tank's middle
        the hull cannot get further off (a mockup pan-tilt demo, seed 3: the ROV 0.9 m from
        the sonar of a hull facing it, lost 16 s). Turned NEAR_ABEAM_RAD off (`_abeam`), the
        sonar ahead of the origin goes aside instead of nearer.
        """
        if self.planner.pan is None or self.asv_xy is None:
            return False
        facing = self.planner.facing(self.asv_xy, look)
        # Left only NEAR_ABEAM_LEAVE_M further off: a ROV about that far would swing the hull
        # between the two headings, the ROV at neither (a mockup demo, seed 3: 78.68 %).
        limit = self.planner.settings.min_range_m + (NEAR_ABEAM_LEAVE_M if self._near else 0.0)
        self._near = self.planner.view(self.asv_xy, facing, look).range_m < limit
        return self._near

    def _abeam(self, facing_rad: float, abeam_rad: float) -> float:
        """With a pan servo, at the station: the hull `abeam_rad` off facing the ROV.

        The side nearer the hull's heading; kept while the pan it needs stays within
        `pan_abeam_slack_rad` of that (no chasing); a hull already so keeps its heading. The
        sonar sits ahead of the hull's origin: a hull facing the ROV brings it that much
        nearer, one turned away keeps it at the station's distance, where a near ROV is still
        found (a mockup pan-tilt demo: the detector lost 25-45 % of the pings under 0.95 m,
        1 % over 1.0 m).
        """
        assert self.planner.pan is not None
        s = self.settings
        # Turned right of the ROV (side +1) the pan turns left to face it, and the other way.
        reach = tuple(
            min(abeam_rad, room)
            for room in self.planner.pan_room_rad(margin_rad=ABEAM_PAN_MARGIN_RAD)
        )

        def within_slack(heading_rad: float) -> bool:
            pan = wrap_angle(facing_rad - heading_rad)  # the pan that heading needs
            return any(
                most > 0.0 and abs(side * pan - most) <= s.pan_abeam_slack_rad
                for side, most in zip((1.0, -1.0), reach, strict=True)
            )

        # The heading chosen is kept while it serves; a hull that already serves keeps its own.
        for kept in (self._abeam_heading, self._carrot_heading):
            if kept is not None and within_slack(kept):
                self._abeam_heading = kept
                return kept
        headings = [
            wrap_angle(facing_rad - side * most)
            for side, most in zip((1.0, -1.0), reach, strict=True)
            if most > 0.0
        ]
        if not headings:
            return facing_rad
        self._abeam_heading = min(headings, key=lambda h: abs(wrap_angle(h - self._carrot_heading)))
        return self._abeam_heading

    def _leg_path(self) -> Array | None:
        """Points (every PATH_STEP_M) along the ROV's mission leg, up to `path_ahead_m` on.

        Then, within what is left of `path_ahead_m`, along the next leg (where told). None
        without a leg (no mission, or it ended) or at its end; a hold keeps the leg.
        """
        if self.leg_end is None or self.rov_m is None:
            return None
        rest = _along(self.rov_m, self.leg_end, self.settings.path_ahead_m)
        if self.next_leg_end is not None:
            left = float(np.linalg.norm((self.leg_end - self.rov_m)[:2]))
            after = _along(self.leg_end, self.next_leg_end, self.settings.path_ahead_m - left)
            if after is not None:
                rest = after if rest is None else np.vstack([rest, after])
        return rest

    def _horizontal_velocity(self) -> Array | None:
        """The ROV's tracked horizontal velocity; None while it hovers (or it is noise)."""
        v = self.rov_velocity.copy()
        v[2] = 0.0
        return None if float(np.linalg.norm(v)) < self.settings.min_lead_speed_m_s else v

    def _expected_velocity(self) -> Array | None:
        """The ROV's velocity as a station should expect it: on its leg, at least the plan's.

        Where its leg runs along the line of sight (at the ASV or away), a ROV that waits for
        the ASV (the mission's view guard) or creeps goes on at the plan's speed as soon as
        the view lets it: a station for it as it is puts it at the view's edge as it goes
        (ArduSub and ArduRover SITL: a 16 m lane at the ASV flown in 0.2 m steps, 110 waits,
        499 s waited in 900 s). Across the sight, and off a leg, the tracked velocity.
        """
        v = self._horizontal_velocity()
        if self.leg_end is None or self.rov_m is None:
            return v
        way = self.leg_end - self.rov_m
        way[2] = 0.0
        left = float(np.linalg.norm(way))
        if left < PATH_STEP_M:
            return v
        if self.asv_xy is not None:
            sight = self.rov_m[:2] - self.asv_xy
            distance = float(np.linalg.norm(sight))
            # Across the line of sight the ROV's elevation hardly changes as it goes on.
            if distance > 0.0 and abs(float(way[:2] @ sight)) < ALONG_SIGHT_COS * left * distance:
                return v
        along = 0.0 if v is None else float(v @ way) / left
        out: Array = way / left * max(along, LEG_SPEED_M_S)
        return out

    def _held_at(self, lost_for_s: float) -> Array:
        """Where a ROV that lost its fix `lost_for_s` ago holds: carried on, then stopped."""
        assert self.rov_m is not None
        v = self._horizontal_velocity()
        if v is None:
            return self.rov_m
        return self.rov_m + v * min(max(lost_for_s, 0.0), self.settings.stop_within_s)

    def _search_disc(self, lost_for_s: float) -> tuple[Array, float]:
        """Where a lost ROV may be: a disc round its stop point, grown since it stopped."""
        s = self.settings
        radius = max(SEARCH_MIN_RADIUS_M, s.lost_drift_m_s * max(0.0, lost_for_s - s.stop_within_s))
        return self._held_at(lost_for_s), radius

    def _search_points(self, centre: Array, radius: float) -> Array:
        """Points spread over the disc (rings), moved inside the walls (the ROV is in the tank)."""
        points = [centre]
        for ring, count in SEARCH_RINGS:
            for k in range(count):
                angle = math.tau * (k + 0.5 * (ring < 1.0)) / count
                offset = ring * radius * np.array([math.cos(angle), math.sin(angle), 0.0])
                points.append(centre + offset)
        out = np.array(points)
        for point in out:
            point[:2] = self.planner.tank.within_walls_xy(point, SEARCH_WALL_MARGIN_M)
        return out

    def _covered(self, station: Station, points: Array) -> Array:
        """Which points the station's sonar sees well (aperture, range, bearing)."""
        views = [self.planner.view(station.position_xy, station.heading_rad, p) for p in points]
        return np.array(
            [
                self.planner.view_is_good(v) and abs(v.azimuth_rad) <= SEARCH_HALF_FAN_RAD
                for v in views
            ]
        )

    def _search_look(self, lost_for_s: float) -> tuple[Station, Array] | None:
        """The station that sees most of where the lost ROV may be, and where it aims.

        Stations are those the planner chooses for points over the disc (the cheapest, and the
        cheapest from another side than the current station's); each is scored by the points
        its view covers, those an earlier look of this loss covered from about the same side
        counting a third; nearer wins a tie.
        """
        assert self._carrot is not None
        centre, radius = self._search_disc(lost_for_s)
        points = self._search_points(centre, radius)
        if not self._searched and self.station is not None:
            self._remember(self.station, points)  # the station that lost it saw no ROV there
        self._searched = True
        best: tuple[float, float, Station, Array] | None = None
        current = None if self.station is None else self.planner.bearing(self.station)
        candidates: list[tuple[Array, Station | None]] = []
        for point in points:
            # The cheapest station for each point, and the cheapest from another side.
            candidates.append(
                (point, self.planner.choose(point, self._carrot, self._carrot_heading))
            )
            if current is not None:
                other = self.planner.choose(
                    point, self._carrot, self._carrot_heading, avoid_bearing_rad=current
                )
                candidates.append((point, other))
        for aim, station in candidates:
            if station is None:
                continue
            covered = self._covered(station, points)
            score = sum(self._weight(station, p) for p in points[covered])
            move = float(np.linalg.norm(station.position_xy - self._carrot))
            if best is None or (score, -move) > (best[0], -best[1]):
                best = (score, move, station, aim)
        if best is None:
            return None
        _, _, station, aim = best
        self._remember(station, points)
        return station, aim

    def _bearings(self, station: Station, points: Array) -> Array:
        """The bearing (W) along which the station's sonar looks at each point."""
        sonar = self.planner.sonar_xy(station.position_xy, station.heading_rad)
        bearings: Array = np.arctan2(points[:, 1] - sonar[1], points[:, 0] - sonar[0])
        return bearings

    def _remember(self, station: Station, points: Array) -> None:
        """The points the station covers, and from which bearing: no ROV seen there so."""
        covered = self._covered(station, points)
        bearings = self._bearings(station, points[covered])
        self._seen.extend(
            (float(p[0]), float(p[1]), float(b))
            for p, b in zip(points[covered], bearings, strict=True)
        )

    def _weight(self, station: Station, point: Array) -> float:
        """A point's worth to a look: less where one covered it from about the same bearing.

        (Clutter or the ROV's own shadow hide it from one side only.)
        """
        bearing = float(self._bearings(station, point[None, :])[0])
        for x, y, seen_from in self._seen:
            if (
                math.hypot(point[0] - x, point[1] - y) <= SEARCH_SEEN_M
                and abs(wrap_angle(bearing - seen_from)) < SEARCH_SAME_SIDE_RAD
            ):
                return SEARCH_SEEN_WEIGHT
        return 1.0

    def _note_arrival(self, now_s: float) -> None:
        """Keep `_arrived_s`: when the carrot reached the station and its heading (or None)."""
        if self._carrot is None or self.station is None:
            self._arrived_s = None
            return
        there = float(np.linalg.norm(self._carrot - self.station.position_xy)) < 0.05 and abs(
            wrap_angle(self._carrot_heading - self.station.heading_rad)
        ) < math.radians(5.0)
        if not there:
            self._arrived_s = None
        elif self._arrived_s is None:
            self._arrived_s = now_s

    def _looked_long_enough(self, now_s: float) -> bool:
        """Whether the station in hand was reached and watched for SEARCH_DWELL_S.

        (A turn round a small tank's ROV takes longer than a look's period.) Or SEARCH_STUCK_S
        passed since it was chosen.
        """
        dwelt = self._arrived_s is not None and now_s - self._arrived_s >= SEARCH_DWELL_S
        return dwelt or now_s - self._last_plan_s >= SEARCH_STUCK_S

    def _ahead(self) -> Array:
        """Where the ROV will be `lead_s` from now, at its horizontal tracked velocity.

        No further than LEAD_SHARE of the distance it is watched from, and not past the
        waypoint its mission sent it to: there it stops (a short survey leg would otherwise be
        watched from a station for a point beyond its end).
        """
        assert self.rov_m is not None
        v = self._expected_velocity()
        if v is None:
            return self.rov_m
        lead = v * self.settings.lead_s
        # Near (a small tank), `lead_s` at survey speed is as far as the ROV is watched from,
        # and no station sees both the ROV now and where it will be: the station chosen for
        # the one has the other out of its dead band at once, and is chosen again every
        # `replan_after_s` (a mockup run: 142 stations in 240 s).
        reach = LEAD_SHARE * self.planner.ideal_distance(self.rov_m)
        length = float(np.linalg.norm(lead))
        if length > reach:
            lead = lead * (reach / length)
        if self.leg_end is not None:
            speed = float(np.linalg.norm(v))
            left = float((self.leg_end[:2] - self.rov_m[:2]) @ v[:2]) / speed  # along its way
            length = float(np.linalg.norm(lead))
            if left < length:
                lead = lead * (max(left, 0.0) / length)
        out: Array = self.rov_m + lead
        return out

    def _station_view(self, rov_m: Array) -> View:
        """The ROV seen from the station: with its heading, or (steered) the hull facing it."""
        assert self.station is not None
        return self._view_from(self.station.position_xy, self.station.heading_rad, rov_m)

    def _view_from(self, xy: Array, heading_rad: float, rov_m: Array) -> View:
        """The ROV seen from `xy`: with `heading_rad`, or (steered) the hull facing it."""
        if self.planner.settings.drive == "steered":
            heading_rad = self.planner.facing(xy, rov_m)
        return self.planner.view(xy, heading_rad, rov_m)

    def _in_view_of_station(self, rov_m: Array) -> bool:
        return self.planner.view_is_good(self._station_view(rov_m))

    def _needs_station(self) -> bool:
        """No station yet, or the ROV seen from it is outside the dead band.

        Or a ROV holding still (it waits for the ASV: the mission's view guard) is outside the
        aperture's margin seen from where the hull settled: an autopilot stops short of its
        target (ArduRover's WP_RADIUS, 0.2 m), and from there the guard waits for a view the
        station promised and the hull never reaches (ArduRover SITL, docs/JOURNAL.md session 38:
        130 s).
        """
        if self.station is None:
            return True
        assert self.rov_m is not None
        s = self.settings
        if (
            self.asv_xy is not None
            and self._horizontal_velocity() is None
            and not self.planner.view_is_good(
                self._view_from(self.asv_xy, self.asv_heading, self.rov_m)
            )
            and float(np.linalg.norm(self.station.position_xy - self.asv_xy)) <= SETTLED_M
        ):
            return True
        view = self._station_view(self.rov_m)
        # The dead band is round the elevation the station was chosen for, not the target: a
        # station chosen steeper than the target (the target's view masked by a rack) would
        # otherwise be re-chosen every `replan_after_s`, and a ROV drifting back to the target
        # elevation, into the masked view, would be kept there.
        return (
            abs(view.elevation_rad - self.station.view.elevation_rad) > s.elevation_tolerance_rad
            or abs(view.azimuth_rad) > s.azimuth_tolerance_rad
            or not self.planner.view_is_good(view)
            # The ROV moved into a cell a fixture shares: look from elsewhere if one is free.
            or self.planner.masked(
                self.station.position_xy,
                self.station.heading_rad
                if self.planner.settings.drive == "lateral"
                else self.planner.facing(self.station.position_xy, self.rov_m),
                self.rov_m,
            )
        )

    def _walk(self, dt: float, *, fresh: bool) -> None:
        """Turn the carrot, then move it towards the station (speed, acceleration, turn rate).

        On the way the hull is to face the ROV (`_wanted_heading`; a steered hull: its way,
        ahead or astern, see the module's docstring); while it faces more than
        `turn_first_rad` off that, the carrot only turns, where the hull is.
        """
        assert self._carrot is not None
        if self.station is None or dt <= 0.0:
            return
        s = self.settings
        look = self._look_point(fresh=fresh)
        goal = self._around(look, self.station.position_xy)
        # Not on a way round the ROV: its first step is a little across the sight too, and
        # along the sight the hull only backed into the wall's clearance, facing the ROV, then
        # (the fix lost, 0.9 m off) turned to the way round, and back (`capsd bench follow`,
        # mockup pan-tilt, seed 3: 40 s).
        if (
            self.planner.settings.drive == "steered"
            and fresh
            and look is not None
            and self._round is None
        ):
            # Decided as the way to a station starts: a way that starts far across goes all
            # the way (else it would stop ACROSS_SLACK_M short of its station).
            station_xy = self.station.position_xy
            if self._sight_for is None or (
                float(np.linalg.norm(self._sight_for - station_xy)) > STAY_M
            ):
                self._sight_for = station_xy.copy()
                self._sight_only = self._across(goal, look) <= ACROSS_SLACK_M
            if self._sight_only:
                along = self._along_sight(goal, look)
                # Never nearer a wall than a station may be (a mockup run: the hull 0.97 m).
                along = self.planner.within_walls(along)
                goal = along if self.planner.clear(along) else goal
        way = goal - self._carrot
        walking = float(np.linalg.norm(way)) > STAY_M
        if self.planner.settings.drive == "steered" and walking:
            # The autopilot turns the hull to its way whatever it is told (ArduRover's GUIDED):
            # ask for that, so that turning first is turning to the way; its stern to the way
            # where that faces the ROV better (backing off it).
            way_heading = math.atan2(float(way[1]), float(way[0]))
            station_xy = self.station.position_xy
            starting = self._direction_for is None or (
                float(np.linalg.norm(self._direction_for - station_xy)) > DIRECTION_KEEP_M
            )
            if look is None:
                heading, self._direction = wrap_angle(way_heading), "forward"
            elif starting:
                # Chosen as the way to a station starts and kept: on a way across the ROV's
                # bearing the better end swaps half way, and each swap is a half turn.
                # Judged from where the hull is, which the autopilot drives (the carrot may be
                # past a station just behind it: "ahead" there turns the hull half round).
                hull_xy = self._carrot if self.asv_xy is None else self.asv_xy
                from_hull = goal - hull_xy
                if float(np.linalg.norm(from_hull)) > STAY_M:
                    way_from_hull = math.atan2(float(from_hull[1]), float(from_hull[0]))
                    if self._too_near(hull_xy, look):
                        # Too near for the sonar to see it whichever end faces it: the end
                        # the hull turns to least leaves soonest (backing off a ROV 0.66 m
                        # away took a 170 deg turn first, 12 s lost: a mockup demo, seed 3).
                        ahead = abs(wrap_angle(way_from_hull - self.asv_heading)) <= math.pi / 2
                        self._direction = "forward" if ahead else "reverse"
                    else:
                        _, self._direction = drive_heading(
                            way_from_hull,
                            self.planner.facing(hull_xy, look),
                            current=self._direction,
                        )
                    if self.planner.pan is not None:
                        self._direction = self._kept_in_reach(
                            hull_xy, goal, look, station_xy, fresh=fresh
                        )
                heading = wrap_angle(way_heading + (math.pi if self._direction == "reverse" else 0))
                self._direction_for = station_xy.copy()
            else:
                heading = wrap_angle(way_heading + (math.pi if self._direction == "reverse" else 0))
        else:
            heading = self._wanted_heading(fresh=fresh)
            if self.planner.settings.drive == "steered" and self.asv_xy is not None:
                self._direction = _closing_direction(
                    self.asv_xy, self.asv_heading, goal, current=self._direction
                )
        turn = wrap_angle(heading - self._carrot_heading)
        if look is not None and self.asv_xy is not None:
            turn = self.planner.turn_keeping_view(self.asv_xy, self._carrot_heading, turn, look)
        max_turn = s.max_yaw_rate_rad_s * dt
        # Wrapped: turn after turn it would wind up past what a command may carry (+-7 rad;
        # a mockup run's bridge refused every command after 108 s).
        self._carrot_heading = wrap_angle(
            self._carrot_heading + max(-max_turn, min(max_turn, turn))
        )
        if (
            self.asv_xy is not None
            and abs(wrap_angle(heading - self.asv_heading)) > s.turn_first_rad
            # Steered, at the station: the autopilot turns the hull where it stopped.
            and (self.planner.settings.drive == "lateral" or walking)
        ):
            # Turn first: the carrot waits where the hull is, so the target is a heading.
            self._carrot = self.asv_xy.copy()
            self._carrot_v = np.zeros(2)
            # Steered: the way now starts where the hull is, not where the carrot was (a new
            # station just behind the hull, chosen while the carrot was past it: "ahead" there
            # turned the hull half round, off the ROV: `capsd bench follow`, nfp, 30 s lost).
            self._direction_for = None
            return
        to_go = goal - self._carrot
        distance = float(np.linalg.norm(to_go))
        # Slow down to stop at the station: v^2 = 2 a d.
        speed = min(s.max_speed_m_s, math.sqrt(2.0 * s.max_accel_m_s2 * distance))
        wanted = to_go / distance * speed if distance > 1e-6 else np.zeros(2)
        change = wanted - self._carrot_v
        limit = s.max_accel_m_s2 * dt
        norm = float(np.linalg.norm(change))
        if norm > limit:
            change = change * (limit / norm)
        self._carrot_v = self._carrot_v + change
        step = self._carrot_v * dt
        if float(np.linalg.norm(step)) >= distance:
            self._carrot = goal.copy()
            self._carrot_v = np.zeros(2)
        else:
            self._carrot = self._carrot + step
        if fresh and self.planner.settings.drive == "lateral":
            # (A steered hull would turn its back on the ROV to back off: it re-stations.)
            self._keep_off()

    def _kept_in_reach(
        self, hull_xy: Array, goal: Array, look: Array, station_xy: Array, *, fresh: bool
    ) -> DriveDirection:
        """The end chosen, or the other where the chosen leaves the ROV far past the pan's reach.

        Further than PAST_PAN_SEEN_RAD past it at worst (`StationPlanner.way_past_pan_rad`,
        the turns included), where the other end keeps it PAST_PAN_BETTER_RAD nearer: the
        rules above judge the ends where the hull starts, and a way past a ROV abeam (out of
        a lane the ROV waits to fly down) driven ahead left it astern 60-70 deg past the pan's
        reach, where the fixes turned unsure (mockup demos, seeds 4-6: 25-69 pings lost); the
        way astern, after a half turn towards it, kept it within 30 deg. Judged with a fresh
        fix only, on a way longer than DIRECTION_KEEP_M (a step to a station re-chosen nearby
        does not pass the ROV), and only where the turn to the other end's way is no more than
        a half turn (the long way round a ROV too near, 250 deg, lost it for most of 17 s:
        `capsd bench follow`, mockup pan-tilt, seed 0). The end so chosen is kept while the
        station stays within DIRECTION_KEEP_M and the way left is longer than that, fresh fix
        or not: judged again at each step of the turn, the rules above took the other end back
        whenever the fix went stale, and the hull turned to and fro.
        """
        way = goal - hull_xy
        if self._reach_for is not None:
            kept_xy, kept = self._reach_for
            if (
                float(np.linalg.norm(kept_xy - station_xy)) <= DIRECTION_KEEP_M
                and float(np.linalg.norm(way)) > DIRECTION_KEEP_M
            ):
                return kept
            self._reach_for = None
        chosen = self._direction
        if not fresh or float(np.linalg.norm(way)) <= DIRECTION_KEEP_M:
            return chosen
        other: DriveDirection = "reverse" if chosen == "forward" else "forward"
        hull = math.atan2(float(way[1]), float(way[0])) + (math.pi if other == "reverse" else 0.0)
        turn = self.planner.turn_keeping_view(
            hull_xy, self.asv_heading, wrap_angle(hull - self.asv_heading), look
        )
        if abs(turn) > math.pi:
            return chosen
        past = {
            end: self.planner.way_past_pan_rad(hull_xy, self.asv_heading, goal, look, direction=end)
            for end in (chosen, other)
        }
        if past[chosen] > PAST_PAN_SEEN_RAD and past[other] + PAST_PAN_BETTER_RAD < past[chosen]:
            self._reach_for = (station_xy.copy(), other)
            return other
        return chosen

    def _too_near(self, hull_xy: Array, look: Array) -> bool:
        """Whether the ROV at `look` is nearer the sonar, as the hull is now, than stations keep it.

        (`min_range_m`: nearer, the detector misses it. The sonar where it is, not where a hull
        facing the ROV would put it: that also sent hulls off ahead with a ROV still seen
        astern, out of the pan's reach, and a detector that finds the ROV only within 35 deg of
        the boresight lost more (`capsd bench follow`, the mockup's pan-tilt, 20 seeds,
        `--detect-within 35`: 96.14 against 95.34 %; 100.0 % both with the default 60 deg).)
        """
        # Left only NEAR_LEAVE_M further off: each station chosen a second apart chose the
        # end again, and with the ROV's range about `min_range_m` the end swapped, each swap a
        # half turn first, and the hull never went (a mockup pan-tilt demo, seed 2: 150 s 0.5 m
        # off the ROV, 63 % good fixes).
        limit = self.planner.settings.min_range_m + (NEAR_LEAVE_M if self._too_near_now else 0.0)
        self._too_near_now = self.planner.view(hull_xy, self.asv_heading, look).range_m < limit
        return self._too_near_now

    def _sight(self, look: Array) -> Array | None:
        """The unit vector from the carrot along the line of sight to `look` (None: on it)."""
        assert self._carrot is not None
        sight = np.asarray(look[:2], dtype=np.float64) - self._carrot
        length = float(np.linalg.norm(sight))
        return None if length < 1e-6 else sight / length

    def _across(self, goal: Array, look: Array) -> float:
        """How far the way to `goal` goes across the line of sight to `look`."""
        assert self._carrot is not None
        unit = self._sight(look)
        if unit is None:
            return 0.0
        return abs(float((goal - self._carrot) @ np.array([-unit[1], unit[0]])))

    def _along_sight(self, goal: Array, look: Array) -> Array:
        """A steered hull's goal less the part of its way across the line of sight.

        ArduRover turns the hull to its way: a way a little across the ROV's bearing (the ASV
        a few centimetres off its carrot, a station a ring's step round) turns the sonar off
        the ROV (an nfp run: a 0.2 m move turned it 68 deg away), where only the distance
        matters for the view (the hull turns to the ROV where it stands). So a way that starts
        at most ACROSS_SLACK_M across goes along the line of sight only, ahead or astern.
        """
        assert self._carrot is not None
        unit = self._sight(look)
        if unit is None:
            return goal
        out: Array = self._carrot + float((goal - self._carrot) @ unit) * unit
        return out

    def _keep_off(self) -> None:
        """The carrot no nearer the ROV than where it would sink out of the aperture's bottom.

        A station keeps the ROV inside the aperture, but the way to it and a ROV flying at the
        sonar (a survey leg towards a station ahead of it) do not: the ROV, nearer than
        `StationPlanner.nearest_distance`, is below the lower edge and lost (session 30's nfp
        lawnmower: 320 of its 541 lost pings so, on one lane). So the carrot is pushed out to
        that distance from the ROV's fix (the sonar's from the ROV, the hull facing it), where
        the hull's clearance allows: a way that would pass nearer slides round instead.
        """
        assert self._carrot is not None
        assert self.rov_m is not None
        centre = self.rov_m[:2]
        offset = self._carrot - centre
        r = float(np.linalg.norm(offset))
        nearest = self.planner.nearest_distance(self.rov_m) + float(self.planner.mount_xy[0])
        if r >= nearest or r < 1e-6:
            return
        radial = offset / r
        pushed = centre + radial * nearest
        if not self.planner.clear(pushed):
            return
        self._carrot = pushed
