"""The vehicles under their autopilots: hold, or go to a GUIDED target, on their own estimate.

The ROV (GuidedRov, ArduSub) and the ASV (GuidedAsv, ArduRover on a boat or an omni frame).

What ArduSub does with a position target, reduced to what the closed loop needs: in GUIDED
with a target the vehicle flies a straight line to it (speed and acceleration limited, slowing
on approach); in POSHOLD it holds where it believed it was when the mode began; in the other
modes (no pilot in the simulation) it coasts to a stop. It steers on what its EKF believes, and
its EKF believes our fixes: the believed position is the truth plus the error of the newest
VISION_POSITION_ESTIMATE (the estimate against where the vehicle truly was at the estimate's
measurement time), so the error of CAP-SD's fixes becomes the vehicle's error, as in a real
tank. Without estimates for `dead_reckoning_s` the belief drifts (the EKF coasts). States are
integrated forward as they are asked for (the simulator asks in time order) and kept for a
while, so a sensor may look a little into the past.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from dataclasses import dataclass

import numpy as np

from capsd.geometry import euler_zyx_to_matrix, wrap_angle
from capsd.mounts import AsvDrive
from capsd.payloads import DriveDirection
from capsd.simulator.world import RovState, Waves, rov_attitude, wave_motion

Array = np.ndarray
DT_S = 0.02
POSITION_MODES = ("GUIDED", "POSHOLD")
HISTORY_S = 120.0


@dataclass(frozen=True)
class GuidedLimits:
    """How the stand-in autopilot flies (ArduSub-like defaults for a BlueROV2 in a tank)."""

    max_speed_m_s: float = 0.3  # WPNAV_SPEED-like
    max_accel_m_s2: float = 0.25
    approach_gain_1_s: float = 0.8  # slows down over the last ~0.4 m
    velocity_tau_s: float = 0.5
    dead_reckoning_s: float = 1.0  # no estimate for longer: the believed position drifts
    drift_m_s: float = 0.01


class GuidedRov:
    """Drive with `set_mode`, `set_target` and `on_estimate`; read with `state(t)`."""

    def __init__(self, start_m: Array, *, limits: GuidedLimits = GuidedLimits(), tilt: float = 0.6):
        self.limits = limits
        self.tilt = tilt
        self._lock = threading.Lock()
        self._mode = "MANUAL"
        self._target: Array | None = None
        self._hold_m = np.array(start_m, dtype=np.float64)  # where it holds (believed frame)
        self._t = 0.0
        self._p = np.array(start_m, dtype=np.float64)
        self._v = np.zeros(3)
        self._a = np.zeros(3)
        self._yaw = 0.0
        self._error = np.zeros(3)  # believed minus true position (the EKF's error)
        self._last_estimate_t = -math.inf
        self._history: deque[tuple[float, Array, Array, Array, float]] = deque(
            maxlen=int(HISTORY_S / DT_S)
        )
        self._history.append((0.0, self._p.copy(), self._v.copy(), self._a.copy(), 0.0))

    # ------------------------------------------------------------------ the autopilot's side

    def set_mode(self, mode: str) -> None:
        with self._lock:
            if mode != self._mode:
                # A new position mode starts from where the vehicle believes it is now.
                self._hold_m = self._p + self._error
                self._target = None
            self._mode = mode

    def set_target(self, target_m: Array) -> None:
        """A GUIDED position target (tank frame W); ignored in other modes, as ArduSub does."""
        with self._lock:
            if self._mode == "GUIDED":
                self._target = np.array(target_m, dtype=np.float64)

    def on_estimate(self, t_s: float, estimate_m: Array) -> None:
        """An external position estimate measured at sim time `t_s` (tank frame W)."""
        true_p = self.state(t_s).position_m
        with self._lock:
            self._error = np.asarray(estimate_m, dtype=np.float64) - true_p
            self._last_estimate_t = max(self._last_estimate_t, self._t)

    @property
    def mode(self) -> str:
        return self._mode

    # ------------------------------------------------------------------ the world's side

    def state(self, t_s: float) -> RovState:
        with self._lock:
            while self._t < t_s:
                self._step()
            return self._lookup(t_s)

    def _step(self) -> None:
        lim = self.limits
        stale = self._t - self._last_estimate_t > lim.dead_reckoning_s
        if stale and math.isfinite(self._last_estimate_t):
            # Coasting: the EKF's belief wanders (a steady drift; no estimate ever: no EKF
            # position at all, and ArduSub refuses the position modes).
            self._error = self._error + np.array([lim.drift_m_s, 0.0, 0.0]) * DT_S
        if self._mode in POSITION_MODES:
            goal = self._target if self._target is not None else self._hold_m
            to_go = goal - (self._p + self._error)
            wanted = _clip(lim.approach_gain_1_s * to_go, lim.max_speed_m_s)
        else:
            wanted = np.zeros(3)  # no pilot in the simulation: it coasts to a stop
        accel = _clip((wanted - self._v) / lim.velocity_tau_s, lim.max_accel_m_s2)
        self._v = self._v + accel * DT_S
        self._p = self._p + self._v * DT_S
        self._a = accel
        speed_xy = math.hypot(float(self._v[0]), float(self._v[1]))
        if speed_xy > 0.05:
            self._yaw = math.atan2(float(self._v[1]), float(self._v[0]))
        self._t += DT_S
        self._history.append((self._t, self._p.copy(), self._v.copy(), self._a.copy(), self._yaw))

    def _lookup(self, t_s: float) -> RovState:
        first_t = self._history[0][0]
        k = round((t_s - first_t) / DT_S)
        k = min(max(k, 0), len(self._history) - 1)
        _, p, v, a, yaw = self._history[k]
        return RovState(p.copy(), v.copy(), a.copy(), rov_attitude(v, a, yaw, self.tilt))


def _clip(v: Array, limit: float) -> Array:
    norm = float(np.linalg.norm(v))
    return v if norm <= limit else v * (limit / norm)


# ArduRover's WP_RADIUS as `capsd mav check --role asv` sets it (at most 0.2 m; its default
# 2 m stops GUIDED that far short of a station, as ArduRover SITL showed).
WP_RADIUS_M = 0.2


@dataclass(frozen=True)
class AsvLimits:
    """How the ArduRover stand-in drives the ASV (an omnidirectional MallARD-like frame)."""

    max_speed_m_s: float = 0.3
    max_accel_m_s2: float = 0.3
    approach_gain_1_s: float = 0.8
    velocity_tau_s: float = 0.8
    max_yaw_rate_rad_s: float = math.radians(20.0)
    yaw_gain_1_s: float = 1.0
    dead_reckoning_s: float = 1.0
    drift_m_s: float = 0.01
    drive: AsvDrive = "steered"
    # Steered: this near its position target it stops steering for it (ArduRover's arrival),
    # else it would spin round a target it sits on.
    arrive_radius_m: float = WP_RADIUS_M
    # Steered: further than this off its way it turns on the spot first (WP_PIVOT_ANGLE).
    pivot_angle_rad: float = math.radians(60.0)


class GuidedAsv:
    """The ASV under ArduRover: drive with `set_mode`, `set_target`, `on_estimate`.

    In GUIDED with a position target it goes straight to it (speed and acceleration limited),
    ignoring the target's yaw as ArduRover does: `steered` (the default, AsvDrive) turns the
    hull towards the way and drives forward at the target velocity's forward part (more than
    `pivot_angle_rad` off the way it turns on the spot first; at its target it holds fore and
    aft only; `set_direction` "reverse": the stern to the way, astern), `lateral` moves any way
    keeping its heading; a heading-only target stops it and
    turns it (rate limited); in GUIDED
    without a target, LOITER and HOLD it keeps where it believed it was when the mode began;
    otherwise (no pilot in the simulation) it drifts to a stop. Like the ROV it steers on what
    its EKF believes: the truth plus the error of the newest estimate (our pose of it). Waves
    are added on top (`pose`). The interface is AsvMotion's: `pose(t)`, `acceleration(t)`.
    """

    def __init__(
        self,
        start_xy: tuple[float, float],
        start_yaw_rad: float,
        *,
        waves: Waves,
        mode: str = "MANUAL",
        limits: AsvLimits = AsvLimits(),
    ):
        self.limits = limits
        self.waves = waves
        self._lock = threading.Lock()
        self._mode = mode
        self._target: tuple[Array, float | None] | None = None
        self._p = np.array([start_xy[0], start_xy[1]], dtype=np.float64)
        self._v = np.zeros(2)
        self._a = np.zeros(2)
        self._yaw = float(start_yaw_rad)
        self._hold = (self._p.copy(), self._yaw)
        self._arrived = False  # steered: reached its position target (it steers no more)
        self._direction: DriveDirection = "forward"  # steered: astern to its targets or not
        self._error = np.zeros(2)
        self._last_estimate_t = -math.inf
        self._t = 0.0
        self._history: deque[tuple[float, Array, Array, float]] = deque(
            maxlen=int(HISTORY_S / DT_S)
        )
        self._history.append((0.0, self._p.copy(), self._a.copy(), self._yaw))

    # ------------------------------------------------------------------ the autopilot's side

    @property
    def mode(self) -> str:
        return self._mode

    def set_mode(self, mode: str) -> None:
        with self._lock:
            if mode != self._mode:
                self._hold = (self._p + self._error, self._yaw)
                self._target = None
                self._direction = "forward"  # as ArduRover's mode entry
            self._mode = mode

    def set_target(self, target_xy: Array) -> None:
        """A GUIDED position target in W; else ignored. As ArduRover, it keeps its heading.

        ArduRover's GUIDED ignores a position target's yaw: so does this one (turn with
        `set_heading`).
        """
        with self._lock:
            if self._mode == "GUIDED":
                xy = np.array(target_xy[:2], dtype=np.float64)
                if self._target is None or float(np.linalg.norm(xy - self._target[0])) > 1e-3:
                    self._arrived = False  # a new target: steer for it again
                self._target = (xy, None)

    def set_direction(self, direction: DriveDirection) -> None:
        """MAV_CMD_DO_SET_REVERSE: a steered hull drives astern to its targets (or not)."""
        with self._lock:
            self._direction = direction

    def set_heading(self, heading_rad: float) -> None:
        """A GUIDED heading alone: stop where it believes it is and turn in place to it."""
        with self._lock:
            if self._mode == "GUIDED":
                believed = self._p + self._error
                goal = self._target[0] if self._target is not None else believed
                # Already stopping at its position target: stay on it.
                here = goal if float(np.linalg.norm(goal - believed)) < 0.5 else believed
                self._target = (np.array(here, dtype=np.float64), heading_rad)

    def on_estimate(self, t_s: float, estimate_xy: Array) -> None:
        """An external position estimate of the ASV measured at sim time `t_s`."""
        true_xy, _, _ = self._at(t_s)
        with self._lock:
            self._error = np.asarray(estimate_xy[:2], dtype=np.float64) - true_xy
            self._last_estimate_t = max(self._last_estimate_t, self._t)

    # ------------------------------------------------------------------ the world's side

    def pose(self, t_s: float) -> tuple[Array, Array]:
        """(R_W_B, t_W_B) at `t_s`, waves included."""
        p, _, yaw = self._at(t_s)
        roll, pitch, heave = wave_motion(self.waves, t_s)
        return euler_zyx_to_matrix(yaw, pitch, roll), np.array([p[0], p[1], heave])

    def acceleration(self, t_s: float) -> Array:
        _, a, _ = self._at(t_s)
        w = self.waves
        omega = 2 * math.pi / w.heave_period_s
        heave_acc = -w.heave_m * omega * omega * math.sin(omega * t_s + 2.0)
        return np.array([a[0], a[1], heave_acc])

    def _at(self, t_s: float) -> tuple[Array, Array, float]:
        with self._lock:
            while self._t < t_s:
                self._step()
            # Interpolated: the IMU differentiates the attitude over a millisecond.
            first_t = self._history[0][0]
            x = min(max((t_s - first_t) / DT_S, 0.0), len(self._history) - 1.000001)
            k = int(x)
            f = x - k
            _, p0, a0, yaw0 = self._history[k]
            _, p1, a1, yaw1 = self._history[min(k + 1, len(self._history) - 1)]
            return p0 + f * (p1 - p0), a0 + f * (a1 - a0), yaw0 + f * (yaw1 - yaw0)

    def _step(self) -> None:
        lim = self.limits
        stale = self._t - self._last_estimate_t > lim.dead_reckoning_s
        if stale and math.isfinite(self._last_estimate_t):
            self._error = self._error + np.array([lim.drift_m_s, 0.0]) * DT_S
        yaw_goal: float | None = None
        if self._mode in ("GUIDED", "LOITER", "HOLD"):
            goal, yaw_goal = self._target if self._target is not None else self._hold
            to_go = goal - (self._p + self._error)
            wanted = _clip(lim.approach_gain_1_s * to_go, lim.max_speed_m_s)
            if lim.drive == "steered":
                # As ArduRover: once at its target it stops steering for it (a small overshoot
                # would otherwise turn the hull round), until a new target comes.
                self._arrived = self._arrived or (
                    float(np.linalg.norm(to_go)) <= lim.arrive_radius_m
                )
                astern = self._direction == "reverse"
                if yaw_goal is None and not self._arrived:
                    yaw_goal = math.atan2(float(to_go[1]), float(to_go[0])) + (
                        math.pi if astern else 0.0
                    )
                hull = np.array([math.cos(self._yaw), math.sin(self._yaw)])
                pivot = yaw_goal is not None and (
                    abs(wrap_angle(yaw_goal - self._yaw)) > lim.pivot_angle_rad
                )
                forward = float(wanted @ hull)
                if pivot:
                    forward = 0.0
                elif not self._arrived:  # on its way: ahead only (astern only, reversed)
                    forward = min(0.0, forward) if astern else max(0.0, forward)
                wanted = forward * hull  # no lateral thrust; at its target it holds fore-aft
        else:
            wanted = np.zeros(2)
        accel = _clip((wanted - self._v) / lim.velocity_tau_s, lim.max_accel_m_s2)
        self._v = self._v + accel * DT_S
        self._p = self._p + self._v * DT_S
        self._a = accel
        if yaw_goal is not None:
            turn = wrap_angle(yaw_goal - self._yaw)
            rate = max(
                -lim.max_yaw_rate_rad_s, min(lim.max_yaw_rate_rad_s, lim.yaw_gain_1_s * turn)
            )
            self._yaw += rate * DT_S
        self._t += DT_S
        self._history.append((self._t, self._p.copy(), self._a.copy(), self._yaw))
