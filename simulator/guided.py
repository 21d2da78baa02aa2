"""The ROV under its autopilot: it holds, or flies to a GUIDED target, on its own estimate.

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

from capsd.simulator.world import RovState, rov_attitude

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
