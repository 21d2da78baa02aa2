"""Where the ASV should be for the sonar to see the ROV well, and the ROV as seen from a pose.

The sonar sits at the mount's position on the ASV, looks along the mount's yaw and is tilted
down by its pitch; the ASV floats level (waves are small against the 20 deg aperture). The ROV
is in the middle of the vertical aperture when its depression angle from the sonar equals the
pitch, i.e. at the horizontal distance d = (z_sonar - z_rov) / tan(pitch). Stations are
sampled on rings around the ROV, facing it (azimuth 0): distances whose elevation stays
`elevation_margin` inside the aperture's edge and whose slant range lies in [min, max] range.
A station keeps the ASV's hull `wall_clearance_m` from every wall and out of keep-out boxes
(fixtures reaching the surface, and the site's own), and its depth conditioning (metres of
horizontal fix error per metre of depth error, tan of the depression) stays bounded. Of the
feasible stations the cheapest wins: elevation off the target, distance from where the ASV is
now, turning, masking, drift and switching, each weighted. Drift: how fast the ROV, at its
tracked velocity, would leave the view's elevation (a ROV flying towards or away from the sonar
changes its depression; one flying across it hardly does), so a ROV on a survey leg is watched
from abeam and its station lasts (a steered hull, `drive`, turns after it there). Switching: a
station looking from another bearing than the current one costs by the degree, so two near-
equal stations on either side of the ROV do not take turns. Path: where the ROV's mission leg
is known, the points it flies through next (`path_m`) are looked at from each station moved as
far the same way (the ASV keeps pace with the ROV, but not nearer the walls than a station may
be; a steered hull pursues the ROV from the station along the line of sight only, the one
move it makes in view, `_pursued_beyond_deg`), and each degree one of them would sit beyond
the aperture's margin costs `path_cost_per_deg`: a ROV waiting at a lane's
start has no velocity to tell the drift cost which way it goes, and where the walls stop the
ASV from backing off (a small tank), a station on the lane ahead sees it fly under the sonar
within seconds. A point counts less the further along the path it lies (by exp(-distance /
`path_discount_m`)): stations are chosen again every second, and a loss a lane's length ahead
is not worth a certain blind turn now.
Masking: a 2D sonar image cannot tell echoes apart
that share a range and bearing at any elevation, so a ROV whose range cell (at its bearing,
over the whole vertical aperture) also holds a mapped fixture, the floor or a wall is hidden
in that echo (a ROV passing over a rack, seen along it), also where the fixture lies just
beyond the aperture's nominal edge, in the beam pattern's skirt (`mask_skirt_rad`); such views
cost `mask_cost_per_deg` degrees of elevation error, so another bearing or a steeper view is
taken where one exists.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from capsd.echo_cell import any_inside, cell_points, fixture_boxes
from capsd.geometry import Array, Transform, wrap_angle
from capsd.mounts import AsvDrive, SonarMountConfig
from capsd.payloads import DriveDirection
from capsd.sonar_geometry import to_polar
from capsd.tank import TankBounds, TankFixture

# Steered: a move whose way is further than this off the ROV's bearing turns the sonar off it.
BLIND_OFF_RAD = math.radians(20.0)
# A hull turned off the ROV keeps its pan at least this far inside the servo's range.
ABEAM_PAN_MARGIN_RAD = math.radians(15.0)
# A turn at least this large may go the long way round (`turn_keeping_view`); the extra
# degrees count this much against the blind ones they save (a turn's time is not all lost).
EITHER_WAY_RAD = math.radians(90.0)
LONG_WAY_WEIGHT = 0.25
TURN_STEP_RAD = math.radians(2.0)  # the turn looked at every this often
WAY_POINTS = 11  # a way looked at in this many points, its ends included (`way_past_pan_rad`)
# Steered: astern only where that faces the ROV this much better than ahead.
REVERSE_BETTER_RAD = math.radians(20.0)
# Steered: nearer than this is no move (the autopilot's arrival).
STAY_M = 0.05
# A way that passes nearer the ROV than this share of its start's or its end's distance from
# it goes round instead (the follower), heading at most AROUND_STEP_RAD bearing ahead round
# the ROV at a time.
AROUND_WITHIN = 0.8
AROUND_STEP_RAD = math.radians(30.0)
# Steered path cost: a point leaving the distances that keep the margin is pursued to this
# share inside them (a move to the very edge would be made again at the next point).
PURSUIT_INSIDE = 0.02


def round_turn(
    start_xy: Array, end_xy: Array, centre_xy: Array, *, within: float = AROUND_WITHIN
) -> float:
    """The bearing a way from `start_xy` to `end_xy` goes round `centre_xy` (0: straight).

    A straight way that passes nearer the centre (the ROV) than `within` of the nearer end's
    distance from it, and turns more than AROUND_STEP_RAD of bearing round it, passes over the
    ROV, where it is under the sonar's aperture: such a way goes round it. 0.0 where it does
    not, or either end is within 0.5 m of the centre (no bearing to go round by).
    """
    start = np.asarray(start_xy[:2], dtype=np.float64)
    end = np.asarray(end_xy[:2], dtype=np.float64)
    centre = np.asarray(centre_xy[:2], dtype=np.float64)
    here, there = start - centre, end - centre
    r_here, r_there = float(np.linalg.norm(here)), float(np.linalg.norm(there))
    way = end - start
    length2 = float(way @ way)
    if length2 < 1e-12 or min(r_here, r_there) < 0.5:
        return 0.0
    t = min(max(float((centre - start) @ way) / length2, 0.0), 1.0)
    if float(np.linalg.norm(start + t * way - centre)) >= within * min(r_here, r_there):
        return 0.0
    turn = wrap_angle(math.atan2(there[1], there[0]) - math.atan2(here[1], here[0]))
    return 0.0 if abs(turn) <= AROUND_STEP_RAD else turn


def drive_heading(
    way_heading_rad: float, facing_rad: float, *, current: DriveDirection = "forward"
) -> tuple[float, DriveDirection]:
    """A steered hull's heading on a way, and which way it drives: the nearer the facing one.

    Ahead, the bow to the way; astern (MAV_CMD_DO_SET_REVERSE), the stern: backing away from
    the ROV keeps the sonar on it. The `current` direction is kept unless the other faces the
    ROV REVERSE_BETTER_RAD better (a way across the ROV's bearing does not flip it, each flip
    a half turn).
    """
    ahead = wrap_angle(way_heading_rad)
    astern = wrap_angle(way_heading_rad + math.pi)
    off = {
        "forward": abs(wrap_angle(ahead - facing_rad)),
        "reverse": abs(wrap_angle(astern - facing_rad)),
    }
    other: DriveDirection = "reverse" if current == "forward" else "forward"
    chosen = other if off[other] + REVERSE_BETTER_RAD < off[current] else current
    return (astern if chosen == "reverse" else ahead), chosen


@dataclass(frozen=True)
class StationSettings:
    """What a good station is; see the module docstring."""

    target_elevation_rad: float = 0.0
    elevation_margin_rad: float = math.radians(3.0)
    min_range_m: float = 2.0
    max_range_m: float = 15.0
    # Stations keep the ROV at least this far off where any can (None: `min_range_m`), and
    # `min_range_m` off where none can (a lane through the middle of a small tank).
    preferred_min_range_m: float | None = None
    wall_clearance_m: float = 1.0  # hull to wall
    hull_radius_m: float = 0.6  # origin to the hull's furthest point
    # The autopilot overshoots a target it was driven to (the simulated ArduRover by up to
    # 0.2 m at 0.5 m/s): stations keep this much more, so the hull keeps `wall_clearance_m`.
    tracking_margin_m: float = 0.5
    max_conditioning: float = 2.0
    keep_out: tuple[TankFixture, ...] = ()
    # Costs: per degree of elevation off the target, per metre moved, per degree turned.
    elevation_cost_per_deg: float = 1.0
    move_cost_per_m: float = 0.5
    turn_cost_per_deg: float = 0.02
    mask_cost_per_deg: float = 20.0
    mask_margin_m: float = 0.3  # range half-width of the ROV's cell, and fixtures' growth
    # The vertical beam still hears a strong echo beyond its nominal (-3 dB) edge: a Gaussian
    # pattern is -5 dB at 1.3 times the half-aperture. A rack top there, at the ROV's range,
    # buries a ROV seen high in the aperture as surely as one inside it.
    mask_skirt_rad: float = math.radians(3.0)
    # Per degree a second that the ROV's motion moves its elevation in the view, and per
    # degree of bearing away from the current station's.
    drift_cost_per_deg_s: float = 4.0
    switch_cost_per_deg: float = 0.03
    # Per degree a point of the ROV's path would sit beyond the aperture's margin; a point this
    # far along the path counts 1/e as much as its first (0: every point alike).
    path_cost_per_deg: float = 0.5
    path_discount_m: float = 10.0
    # How the ASV's autopilot moves it (AsvDrive) and, for a steered hull, what a second with
    # the sonar turned off the ROV costs, and how fast it drives and turns.
    drive: AsvDrive = "lateral"
    blind_cost_per_s: float = 8.0
    transit_speed_m_s: float = 0.3
    turn_rate_rad_s: float = math.radians(15.0)


@dataclass(frozen=True)
class View:
    """The ROV as the sonar sees it from one ASV pose."""

    range_m: float
    azimuth_rad: float
    elevation_rad: float
    conditioning: float  # tan of the depression: horizontal error per depth error


@dataclass(frozen=True)
class Station:
    """An ASV pose in W (body origin, heading counter-clockwise from W's x) and its view."""

    position_xy: Array
    heading_rad: float
    view: View


class StationPlanner:
    """Stations for one sonar mount in one tank."""

    def __init__(self, sonar: SonarMountConfig, tank: TankBounds, settings: StationSettings):
        self.settings = settings
        self.tank = tank
        self.mount_xy = np.array(sonar.position_m[:2], dtype=np.float64)
        self.sonar_z = float(sonar.position_m[2])
        self.mount_yaw = math.radians(sonar.yaw_deg)
        self.pitch = math.radians(sonar.pitch_deg)
        self.tilt = sonar.tilt  # a tilt servo under the sonar (`tilt_rad`), or None
        self.pan = sonar.pan  # a pan servo under that (`pan_tilt_rad`), or None
        self.half_aperture = math.radians(sonar.vertical_aperture_deg) / 2.0
        surface = [f for f in tank.fixtures if f.hi_m[2] > -0.5]  # what a hull can hit
        self.keep_out = tuple(surface) + settings.keep_out
        self.sonar_mount = sonar.transform()
        self._sonar = sonar
        self.beam_model = sonar.beam_model
        self._echo_boxes = fixture_boxes(tank.fixtures, settings.mask_margin_m)

    # ------------------------------------------------------------------ views

    def sonar_xy(self, asv_xy: Array, heading_rad: float) -> Array:
        c, s = math.cos(heading_rad), math.sin(heading_rad)
        mx, my = self.mount_xy
        return np.array([asv_xy[0] + c * mx - s * my, asv_xy[1] + s * mx + c * my])

    def view(
        self,
        asv_xy: Array,
        heading_rad: float,
        rov_m: Array,
        *,
        tilt_rad: float = 0.0,
        pan_rad: float = 0.0,
    ) -> View:
        """Range, azimuth and elevation of the ROV from the ASV pose (level ASV).

        The azimuth is the horizontal bearing off the boresight; the elevation is the beam
        model's: in a conical beam a ROV off the boresight sits lower than one faced (25 deg
        off, 45 deg down: 2.8 deg lower). `tilt_rad`, `pan_rad`: the servos' angles (added to
        the pitch and the yaw; the sonar stays where the mount puts it on the hull).
        """
        sonar = self.sonar_xy(asv_xy, heading_rad)
        dx, dy = float(rov_m[0] - sonar[0]), float(rov_m[1] - sonar[1])
        horizontal = math.hypot(dx, dy)
        drop = self.sonar_z - float(rov_m[2])
        depression = math.atan2(drop, horizontal)
        azimuth = wrap_angle(math.atan2(dy, dx) - heading_rad - self.mount_yaw - pan_rad)
        slant = math.hypot(horizontal, drop)
        # The ROV in the sonar's frame, less its lateral part: x along the boresight, z down.
        forward = horizontal * math.cos(azimuth)
        pitch = self.pitch + tilt_rad
        x = forward * math.cos(pitch) + drop * math.sin(pitch)
        z = drop * math.cos(pitch) - forward * math.sin(pitch)
        if self.beam_model == "conical":
            elevation = -math.atan2(z, x)
        else:
            elevation = -math.asin(max(-1.0, min(1.0, z / slant))) if slant > 0.0 else 0.0
        return View(
            range_m=slant,
            azimuth_rad=azimuth,
            elevation_rad=elevation,
            conditioning=math.tan(depression) if depression < math.pi / 2 else math.inf,
        )

    def tilt_rad(self, asv_xy: Array, heading_rad: float, rov_m: Array) -> float:
        """A tilt servo's angle that puts the ROV at the target elevation from this ASV pose.

        Within the servo's range; 0.0 without one. In the boresight's vertical plane the
        elevation is the pitch less the depression there (exact in a conical beam, whose
        azimuth leaves a point in that plane). Stations are chosen for the servo at its zero
        (the views above): the servo is the fast loop that keeps the ROV centred while the hull
        turns, lags or overshoots, the stations the slow one that keeps the geometry the fixes
        are good in. (Stations chosen for any angle the servo can take put the ASV nearly over
        the ROV and lost it as it passed under: `capsd bench follow --tank mockup --sonar-tilt
        servo`, 80.6 % in view against 91.3 %, the view guard alike, docs/JOURNAL.md session 42.)
        """
        if self.tilt is None:
            return 0.0
        sonar = self.sonar_xy(asv_xy, heading_rad)
        dx, dy = float(rov_m[0] - sonar[0]), float(rov_m[1] - sonar[1])
        azimuth = wrap_angle(math.atan2(dy, dx) - heading_rad - self.mount_yaw)
        forward = math.hypot(dx, dy) * math.cos(azimuth)
        drop = self.sonar_z - float(rov_m[2])
        wanted = math.atan2(drop, forward) + self.settings.target_elevation_rad - self.pitch
        return self.tilt.clamp_rad(wanted)

    def pan_tilt_rad(
        self, asv_xy: Array, heading_rad: float, rov_m: Array, *, pan_now_rad: float | None = None
    ) -> tuple[float, float]:
        """The pan that faces the ROV and the tilt that puts it at the target elevation.

        From this ASV pose, each within its servo's range. The tilt is for the pan at
        `pan_now_rad` (where the servo is; None: at the angle asked): a pan still turning
        leaves the ROV off its boresight, nearer in the boresight's plane (`tilt_rad`'s
        azimuth). Stations stay chosen at both servos' zero (`tilt_rad`): the pan only keeps
        the sonar on the ROV while a steered hull's way crosses its bearing (`capsd bench
        follow --sonar-tilt pan-tilt`: the mockup's one loss a run).
        """
        if self.pan is None or self.tilt is None:
            return 0.0, self.tilt_rad(asv_xy, heading_rad, rov_m)
        sonar = self.sonar_xy(asv_xy, heading_rad)
        dx, dy = float(rov_m[0] - sonar[0]), float(rov_m[1] - sonar[1])
        off_bow = wrap_angle(math.atan2(dy, dx) - heading_rad - self.mount_yaw)
        pan = self.pan.clamp_rad(off_bow)
        off = wrap_angle(off_bow - (pan if pan_now_rad is None else pan_now_rad))
        forward = math.hypot(dx, dy) * math.cos(off)
        drop = self.sonar_z - float(rov_m[2])
        wanted = math.atan2(drop, forward) + self.settings.target_elevation_rad - self.pitch
        return pan, self.tilt.clamp_rad(wanted)

    def pan_room_rad(self, *, margin_rad: float = 0.0) -> tuple[float, float]:
        """How far the pan turns left and right of its zero, less `margin_rad` (0, 0: none)."""
        if self.pan is None:
            return 0.0, 0.0
        return (
            math.radians(self.pan.max_deg) - margin_rad,
            -math.radians(self.pan.min_deg) - margin_rad,
        )

    def reached_view(
        self, asv_xy: Array, heading_rad: float, rov_m: Array
    ) -> tuple[View, float, float]:
        """The view with the servos where the follower turns them, and their (tilt, pan).

        What a pre-dive check judges: a tilt servo keeps the ROV in the aperture from places
        whose view at its zero misses it, a pan faces it from a hull turned off it
        (`pan_tilt_rad`; without servos: the view, 0.0, 0.0).
        """
        pan, tilt = self.pan_tilt_rad(asv_xy, heading_rad, rov_m)
        view = self.view(asv_xy, heading_rad, rov_m, tilt_rad=tilt, pan_rad=pan)
        return view, tilt, pan

    def view_is_good(self, view: View, *, min_range_m: float | None = None) -> bool:
        """Inside the aperture (with the margin), the range band and the conditioning.

        The band from `min_range_m` (None: the settings') to the settings' `max_range_m`.
        """
        s = self.settings
        nearest = s.min_range_m if min_range_m is None else min_range_m
        return (
            abs(view.elevation_rad) <= self.half_aperture - s.elevation_margin_rad
            and nearest <= view.range_m <= s.max_range_m
            and view.conditioning <= s.max_conditioning
        )

    def _wall_clearance(self) -> float:
        s = self.settings
        return s.wall_clearance_m + s.hull_radius_m + s.tracking_margin_m

    def within_walls(self, asv_xy: Array) -> Array:
        """`asv_xy` moved the least to where the hull keeps its clearance from the walls."""
        return np.array(self.tank.within_walls_xy(asv_xy, self._wall_clearance()))

    def clear(self, asv_xy: Array) -> bool:
        """Whether the hull at `asv_xy` keeps its clearance from walls and keep-out boxes."""
        s = self.settings
        c = self._wall_clearance()
        x, y = float(asv_xy[0]), float(asv_xy[1])
        if not (c <= x <= self.tank.length_m - c and c <= y <= self.tank.width_m - c):
            return False
        r = s.hull_radius_m + s.tracking_margin_m
        return not any(
            f.lo_m[0] - r <= x <= f.hi_m[0] + r and f.lo_m[1] - r <= y <= f.hi_m[1] + r
            for f in self.keep_out
        )

    def masked(
        self,
        asv_xy: Array,
        heading_rad: float,
        rov_m: Array,
        *,
        tilt_rad: float = 0.0,
        pan_rad: float = 0.0,
    ) -> bool:
        """Whether a fixture, the floor or a wall shares the ROV's range cell at its bearing.

        `tilt_rad`, `pan_rad`: the servos' angles (the aperture, and what it takes in, moves).
        """
        body = Transform.from_euler_zyx(
            (float(asv_xy[0]), float(asv_xy[1]), 0.0),
            yaw_rad=heading_rad,
            pitch_rad=0.0,
            roll_rad=0.0,
        )
        mount = (
            self.sonar_mount
            if tilt_rad == 0.0 and pan_rad == 0.0
            else self._sonar.transform(tilt_rad=tilt_rad, pan_rad=pan_rad)
        )
        sonar = body.compose(mount)
        r, azimuth, elevation = to_polar(self.beam_model, sonar.inverse().apply(rov_m))
        m = self.settings.mask_margin_m
        p = cell_points(
            sonar,
            range_m=r,
            azimuth_rad=azimuth,
            beam_model=self.beam_model,
            vertical_aperture_rad=2.0 * (self.half_aperture + self.settings.mask_skirt_rad),
            half_width_m=m,
            skip_elevation_rad=elevation,
        )
        t = self.tank
        if bool(
            np.any(p[:, 2] <= -t.depth_m + m)
            or np.any((p[:, 0] <= m) | (p[:, 0] >= t.length_m - m))
            or np.any((p[:, 1] <= m) | (p[:, 1] >= t.width_m - m))
        ):
            return True
        return any_inside(p, self._echo_boxes)

    # ------------------------------------------------------------------ choice

    def bearing(self, station: Station) -> float:
        """The bearing (in W) along which `station` looks at its ROV."""
        return wrap_angle(station.heading_rad + self.mount_yaw + station.view.azimuth_rad)

    def choose(
        self,
        rov_m: Array,
        asv_xy: Array,
        heading_rad: float,
        *,
        avoid_bearing_rad: float | None = None,
        avoid_within_rad: float = math.radians(40.0),
        rov_velocity_m_s: Array | None = None,
        current_bearing_rad: float | None = None,
        path_m: Array | None = None,
    ) -> Station | None:
        """The cheapest feasible station for the ROV at `rov_m`, the ASV now at `asv_xy`.

        `avoid_bearing_rad`: no station looking along a bearing within `avoid_within_rad` of
        it (another look at a ROV the sonar lost from there). `rov_velocity_m_s`: the ROV's
        tracked velocity (drift cost); `current_bearing_rad`: the bearing the current station
        looks along (switching cost); `path_m`: points (N x 3, W) the ROV flies through next
        (path cost). Kept `preferred_min_range_m` off the ROV where a station can be, else
        `min_range_m`.
        """
        s = self.settings
        floors = [s.min_range_m]
        if s.preferred_min_range_m is not None:
            floors.insert(0, s.preferred_min_range_m)
        for floor in floors:
            chosen = self._cheapest(
                rov_m,
                asv_xy,
                heading_rad,
                min_range_m=floor,
                avoid_bearing_rad=avoid_bearing_rad,
                avoid_within_rad=avoid_within_rad,
                rov_velocity_m_s=rov_velocity_m_s,
                current_bearing_rad=current_bearing_rad,
                path_m=path_m,
            )
            if chosen is not None:
                return chosen
        return None

    def _cheapest(
        self,
        rov_m: Array,
        asv_xy: Array,
        heading_rad: float,
        *,
        min_range_m: float,
        avoid_bearing_rad: float | None,
        avoid_within_rad: float,
        rov_velocity_m_s: Array | None,
        current_bearing_rad: float | None,
        path_m: Array | None,
    ) -> Station | None:
        """`choose` with the ROV at least `min_range_m` off."""
        s = self.settings
        drop = self.sonar_z - float(rov_m[2])
        if drop <= 0.0:
            return None  # the ROV at or above the sonar: no station sees it from above
        best: tuple[float, Station] | None = None
        for origin, heading, bearing in self._candidates(rov_m, asv_xy, drop):
            if (
                avoid_bearing_rad is not None
                and abs(wrap_angle(float(bearing) - avoid_bearing_rad)) < avoid_within_rad
            ):
                continue
            if not self.clear(origin):
                continue
            view = self.view(origin, heading, rov_m)
            if not self.view_is_good(view, min_range_m=min_range_m):
                continue
            cost = (
                s.elevation_cost_per_deg
                * math.degrees(abs(view.elevation_rad - s.target_elevation_rad))
                + s.move_cost_per_m * float(np.linalg.norm(origin - asv_xy[:2]))
                + s.turn_cost_per_deg * math.degrees(abs(wrap_angle(heading - heading_rad)))
            )
            if s.drive == "steered":
                cost += s.blind_cost_per_s * self.blind_s(
                    asv_xy, heading_rad, origin, heading, rov_m
                )
            if rov_velocity_m_s is not None:
                away = float(
                    rov_velocity_m_s[0] * math.cos(bearing)
                    + rov_velocity_m_s[1] * math.sin(bearing)
                )
                # d(elevation)/dt = drop / range^2 * (the ROV's speed away from the sonar)
                # (the steered drive too: its bearing's rate was tried, docs/JOURNAL.md session 32)
                rate = drop / view.range_m**2 * away
                cost += s.drift_cost_per_deg_s * math.degrees(abs(rate))
            if current_bearing_rad is not None:
                turned = abs(wrap_angle(float(bearing) - current_bearing_rad))
                cost += s.switch_cost_per_deg * math.degrees(turned)
            if best is not None and cost >= best[0]:
                continue  # the path and masking only add: no need to look
            if path_m is not None:
                beyond = self._beyond_margin_deg(origin, heading, rov_m, path_m)
                cost += s.path_cost_per_deg * beyond
            if best is not None and cost >= best[0]:
                continue
            if self.masked(origin, heading, rov_m):
                cost += s.mask_cost_per_deg
            if best is None or cost < best[0]:
                best = (cost, Station(origin, heading, view))
        return None if best is None else best[1]

    def _beyond_margin_deg(
        self, asv_xy: Array, heading_rad: float, rov_m: Array, path_m: Array
    ) -> float:
        """Degrees the path's elevations sit beyond the aperture's margin, summed.

        Lateral drive: each point is seen from the station moved as the ROV moved from
        `rov_m` to it, then into the walls' clearance box (the hull's own; keep-out boxes are
        not looked at). Steered: `_pursued_beyond_deg`.
        """
        if self.settings.drive == "steered":
            return self._pursued_beyond_deg(asv_xy, path_m)
        limit = self.half_aperture - self.settings.elevation_margin_rad
        total = 0.0
        for point, weight in zip(path_m, self._path_weights(path_m), strict=True):
            moved = self.within_walls(asv_xy[:2] + point[:2] - rov_m[:2])
            view = self.view(moved, heading_rad, point)
            total += weight * max(0.0, abs(view.elevation_rad) - limit)
        return math.degrees(total)

    def _path_weights(self, path_m: Array) -> Array:
        """Each path point's weight: exp(-(distance along the path) / `path_discount_m`).

        The follower chooses again every second, as the ROV goes on: a view lost near a leg's
        end 40 s ahead is not yet a blind second, and paying for it now with a certain one (a
        steered hull turned across the line of sight, off the ROV) loses the ROV for nothing
        (session 40's nfp demo, seed 1: 6 s).
        """
        n = len(path_m)
        discount = self.settings.path_discount_m
        if discount <= 0.0 or n == 0:
            return np.ones(n)
        steps = np.linalg.norm(np.diff(np.asarray(path_m)[:, :2], axis=0), axis=1)
        along = np.concatenate(([0.0], np.cumsum(steps)))
        out: Array = np.exp(-along / discount)
        return out

    def _pursued_beyond_deg(self, asv_xy: Array, path_m: Array) -> float:
        """A steered hull after the ROV along its path, from `asv_xy`: degrees unseen, summed.

        The hull watches by turning where it stands; when a point would leave the distances
        whose elevation keeps the margin (`nearest_distance`, `farthest_distance`) it moves
        only along the line of sight (ahead at the ROV or astern away from it, the sonar on
        it), to the nearer of those distances. That is the one move a steered hull makes in
        view, and it carries the bearing round as the ROV goes on: a ROV flying at the ASV
        from slightly off its axis ends up seen from well off it, so that a station on one
        side of a lane's end sees the next leg and one on the other side is driven into a
        wall. Where a wall stops the move, the hull slides along the wall instead: across the
        sight, blind; each such second costs `blind_cost_per_s` (in the path cost's degrees),
        and the point is judged from where the hull got to.
        """
        s = self.settings
        limit = self.half_aperture - s.elevation_margin_rad
        total = 0.0
        blind_s = 0.0
        sliding = False
        here = np.asarray(asv_xy[:2], dtype=np.float64).copy()
        for point, weight in zip(path_m, self._path_weights(path_m), strict=True):
            sonar = self.sonar_xy(here, self.facing(here, point))
            off = sonar - point[:2]
            distance = float(np.linalg.norm(off))
            near, far = self.nearest_distance(point), self.farthest_distance(point)
            slid = False
            if distance > 1e-6 and not near <= distance <= far:
                wanted = min(
                    max(distance, near * (1.0 + PURSUIT_INSIDE)), far * (1.0 - PURSUIT_INSIDE)
                )
                moved = here + off * ((wanted - distance) / distance)
                kept = self.within_walls(moved)
                slide = float(np.linalg.norm(kept - moved))
                if slide > STAY_M:
                    # The turn to the wall's way once per slide, then the way along it.
                    blind_s += weight * slide / s.transit_speed_m_s
                    if not sliding:
                        blind_s += weight * math.pi / s.turn_rate_rad_s
                    slid = True
                here = kept
            sliding = slid
            view = self.view(here, self.facing(here, point), point)
            total += weight * max(0.0, abs(view.elevation_rad) - limit)
        # Blind seconds in the path cost's unit (its weight is applied by `choose`).
        return math.degrees(total) + s.blind_cost_per_s * blind_s / max(s.path_cost_per_deg, 1e-9)

    def facing(self, asv_xy: Array, rov_m: Array) -> float:
        """The hull's heading at `asv_xy` that points the sonar's boresight at the ROV."""
        return wrap_angle(
            math.atan2(float(rov_m[1] - asv_xy[1]), float(rov_m[0] - asv_xy[0])) - self.mount_yaw
        )

    def blind_s(
        self, asv_xy: Array, heading_rad: float, origin: Array, heading: float, rov_m: Array
    ) -> float:
        """Seconds a steered hull's sonar is off the ROV on its way from `asv_xy` to `origin`.

        Its autopilot turns the hull to the way (its bow, or its stern backing away:
        drive_heading), drives, and turns it to the station's heading; a hull more than
        BLIND_OFF_RAD off the ROV's bearing so takes the sonar off it for all that (a way
        nearer STAY_M is no move: the hull turns where it is, facing the ROV).
        """
        way = np.asarray(origin[:2], dtype=np.float64) - np.asarray(asv_xy[:2], dtype=np.float64)
        length = float(np.linalg.norm(way))
        if length < STAY_M:
            return 0.0
        facing = self.facing(asv_xy, rov_m)
        hull, _ = drive_heading(math.atan2(float(way[1]), float(way[0])), facing)
        s = self.settings
        turns = abs(wrap_angle(hull - heading_rad)) + abs(wrap_angle(heading - hull))
        round_rad = round_turn(asv_xy, origin, rov_m)
        if round_rad != 0.0:
            # Not at the ROV but round it (a way to its far side): across the line of sight
            # all the way, on an arc about as long as the turn at the mean distance.
            r_here = float(np.linalg.norm(np.asarray(asv_xy[:2]) - rov_m[:2]))
            r_there = float(np.linalg.norm(np.asarray(origin[:2]) - rov_m[:2]))
            arc = 0.5 * (r_here + r_there) * abs(round_rad) + abs(r_there - r_here)
            return (turns + math.pi) / s.turn_rate_rad_s + arc / s.transit_speed_m_s
        # The hull along its way (or astern): the sonar on the ROV if that is about facing it.
        if abs(wrap_angle(hull - facing)) <= BLIND_OFF_RAD:
            return 0.0  # driving at the ROV, or backing away from it: still in view
        return turns / s.turn_rate_rad_s + length / s.transit_speed_m_s

    def turn_keeping_view(
        self, asv_xy: Array, heading_rad: float, turn_rad: float, rov_m: Array
    ) -> float:
        """`turn_rad` (from `heading_rad`, the shorter way), or the same heading the long way.

        The long way where it keeps the ROV within the sonar's reach (BLIND_OFF_RAD either
        side of the bow, and a pan servo's range) for more of the turn, by more than
        LONG_WAY_WEIGHT of its extra degrees: a hull turning its stern to a new way with the
        ROV on the far side of it swept the sonar away from the ROV for 150 deg, 10 s, where
        the long way swept it across (a mockup pan-tilt demo, seed 1).
        """
        if abs(turn_rad) < EITHER_WAY_RAD:
            return turn_rad
        other = turn_rad - math.copysign(2.0 * math.pi, turn_rad)
        extra = abs(other) - abs(turn_rad)
        if self._turn_blind_rad(asv_xy, heading_rad, other, rov_m) + LONG_WAY_WEIGHT * extra < (
            self._turn_blind_rad(asv_xy, heading_rad, turn_rad, rov_m)
        ):
            return other
        return turn_rad

    def _beyond_reach(self, off_bow_rad: float) -> bool:
        """Whether a ROV `off_bow_rad` off the mount's yaw is beyond the sonar's reach.

        BLIND_OFF_RAD either side of the bow, and a pan servo's range besides.
        """
        return self.past_pan_rad(off_bow_rad) > BLIND_OFF_RAD

    def _turn_blind_rad(
        self, asv_xy: Array, heading_rad: float, turn_rad: float, rov_m: Array
    ) -> float:
        """Of a turn by `turn_rad` where the hull stands, the degrees (rad) beyond reach."""
        bearing = math.atan2(float(rov_m[1] - asv_xy[1]), float(rov_m[0] - asv_xy[0]))
        steps = max(1, math.ceil(abs(turn_rad) / TURN_STEP_RAD))
        blind = 0
        for k in range(steps + 1):
            hull = heading_rad + turn_rad * k / steps
            blind += self._beyond_reach(bearing - self.mount_yaw - hull)
        return abs(turn_rad) * blind / (steps + 1)

    def past_pan_rad(self, off_bow_rad: float) -> float:
        """How far a ROV `off_bow_rad` off the mount's yaw is past the pan's reach (0: within).

        Its angle off the boresight of a pan turned as far towards it as it goes (off the bow
        without a pan).
        """
        left, right = self.pan_room_rad()
        off = wrap_angle(off_bow_rad)
        return max(0.0, off - left, -right - off)

    def way_past_pan_rad(
        self,
        asv_xy: Array,
        heading_rad: float,
        goal_xy: Array,
        rov_m: Array,
        *,
        direction: DriveDirection,
    ) -> float:
        """The most a steered hull's way to `goal_xy` puts the ROV past the pan's reach.

        Driven `direction` (its bow or its stern to the way): the turn to the way where it
        stands, the way, and the turn to face the ROV at its end (each the way
        `turn_keeping_view` takes), the ROV where it is now (`past_pan_rad`). The end that
        faces the ROV better at the start can leave it well past the pan's reach as the hull
        passes it: a hull driven ahead past a ROV abeam ended with it 150-160 deg off the bow,
        60-70 deg off the pan's boresight at its limit, where the fixes turned unsure (mockup
        demos, seeds 4-6: 25-69 pings lost).
        """
        start = np.asarray(asv_xy[:2], dtype=np.float64)
        way = np.asarray(goal_xy[:2], dtype=np.float64) - start
        if float(np.linalg.norm(way)) < STAY_M:
            return 0.0
        hull = math.atan2(float(way[1]), float(way[0])) + (math.pi if direction == "reverse" else 0)
        end = start + way
        worst = 0.0
        for xy, before, after in (
            (start, heading_rad, hull),
            (end, hull, self.facing(end, rov_m)),
        ):
            turn = self.turn_keeping_view(xy, before, wrap_angle(after - before), rov_m)
            facing = self.facing(xy, rov_m)
            steps = max(1, math.ceil(abs(turn) / TURN_STEP_RAD))
            for k in range(steps + 1):
                worst = max(worst, self.past_pan_rad(facing - (before + turn * k / steps)))
        for share in np.linspace(0.0, 1.0, WAY_POINTS):
            worst = max(worst, self.past_pan_rad(self.facing(start + share * way, rov_m) - hull))
        return worst

    def _candidates(
        self, rov_m: Array, asv_xy: Array, drop: float
    ) -> Iterator[tuple[Array, float, float]]:
        """(origin, heading, bearing) of the stations to try: rings round the ROV, facing it.

        A steered hull also tries staying where it is, turned to face the ROV, and each ring's
        point on its line of sight now: the rings' bearings are 5 deg apart, and a move that
        is a little across the line (0.3 m at 7 m) turns the hull to it, off the ROV.
        """
        bearings = [float(b) for b in np.linspace(-math.pi, math.pi, 72, endpoint=False)]
        if self.settings.drive == "steered":
            here = np.asarray(asv_xy[:2], dtype=np.float64).copy()
            heading = self.facing(here, rov_m)
            yield here, heading, wrap_angle(heading + self.mount_yaw)
            bearings.insert(0, wrap_angle(heading + self.mount_yaw))
        for distance in self._distances(drop):
            for bearing in bearings:
                heading = wrap_angle(float(bearing) - self.mount_yaw)
                # The sonar on the ring at `distance` from the ROV, looking along `bearing`.
                sonar = np.array(
                    [
                        rov_m[0] - distance * math.cos(bearing),
                        rov_m[1] - distance * math.sin(bearing),
                    ]
                )
                yield sonar - self.sonar_xy(np.zeros(2), heading), heading, float(bearing)

    def nearest_distance(self, rov_m: Array) -> float:
        """The horizontal sonar-to-ROV distance at the aperture's lower edge, less the margin.

        Nearer, a level sonar facing the ROV sees it less than `elevation_margin` inside the
        lower edge, or below it.
        """
        drop = max(self.sonar_z - float(rov_m[2]), 0.0)
        steepest = self.pitch + self.half_aperture - self.settings.elevation_margin_rad
        if steepest >= math.pi / 2:
            return 0.0
        return drop / math.tan(steepest)

    def farthest_distance(self, rov_m: Array) -> float:
        """The horizontal sonar-to-ROV distance at the aperture's upper edge, less the margin.

        Further, a level sonar facing the ROV sees it less than `elevation_margin` inside the
        upper edge, or above it (inf where the upper edge, less the margin, looks up).
        """
        drop = max(self.sonar_z - float(rov_m[2]), 0.0)
        shallowest = self.pitch - self.half_aperture + self.settings.elevation_margin_rad
        return drop / math.tan(shallowest) if shallowest > 0.0 else math.inf

    def ideal_distance(self, rov_m: Array) -> float:
        """The horizontal sonar-to-ROV distance that puts the ROV at the target elevation."""
        drop = max(self.sonar_z - float(rov_m[2]), 0.0)
        return self._ideal(drop)

    def _ideal(self, drop: float) -> float:
        s = self.settings
        return drop / math.tan(max(self.pitch - s.target_elevation_rad, math.radians(1.0)))

    def _distances(self, drop: float) -> list[float]:
        """Horizontal sonar-to-ROV distances to try: the ideal one first, then either side."""
        ideal = self._ideal(drop)
        return [ideal * f for f in (1.0, 0.9, 1.1, 0.8, 1.25, 0.7, 1.4, 0.6, 1.6)]
