"""The sonar's tilt servo on the simulated ASV, as ArduRover's servo mount drives it.

The autopilot is told a mount pitch (MAVLink's degrees, up +; MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW),
clamps it to the mount's range and reports that angle back (GIMBAL_DEVICE_ATTITUDE_STATUS): a
servo mount has no feedback, so what it reports is where it drives the servo, not where the
servo is. The servo itself slews there at its rate, so while it moves the report runs ahead of
the sonar, as on a real ASV. ArduPilot's mount holds its pitch against the horizon: the servo
takes the hull's own pitch out (`tilt_rad`'s `hull_pitch_rad`). Angles here are the servo's
tilt, down + from its zero (the sonar at the mount's pitch), the autopilot's pitch being
`zero_pitch_deg` less the tilt.

With a pan servo (`pan`, the mount's second axis) the autopilot is also told a yaw (MAVLink's
degrees in the vehicle's frame, right +), reported back alike: the pan is its negative (left
+, about the mount's yaw), slewing at its own rate. The horizon hold takes the hull's pitch
out of the tilt whatever the pan (a panned sonar on a rolling hull keeps part of the roll).
"""

from __future__ import annotations

import math
import threading

from capsd.mounts import SonarPanConfig, SonarTiltConfig
from capsd.servo_motion import toward


class TiltServo:
    """`command(t, pitch_deg)` from the autopilot's thread; read `tilt_rad(t)` and the report."""

    def __init__(
        self,
        servo: SonarTiltConfig,
        *,
        zero_pitch_deg: float,
        start_rad: float = 0.0,
        pan: SonarPanConfig | None = None,
    ):
        self.servo = servo
        self.pan = pan
        self.zero_pitch_deg = zero_pitch_deg
        self._lock = threading.Lock()
        self._t0 = 0.0  # when the servo last took a new target (sim seconds)
        self._from = self._to = servo.clamp_rad(start_rad)  # its tilt then, and its target
        self._pan_t0 = 0.0  # ... and the pan's
        self._pan_from = self._pan_to = 0.0
        self.commands = 0

    def _at(self, t_s: float) -> float:
        rate = math.radians(self.servo.rate_deg_s)
        return toward(self._from, self._to, rate, t_s - self._t0)

    def _pan_at(self, t_s: float) -> float:
        if self.pan is None:
            return 0.0
        rate = math.radians(self.pan.rate_deg_s)
        return toward(self._pan_from, self._pan_to, rate, t_s - self._pan_t0)

    def pan_rad(self, t_s: float) -> float:
        """Where the pan servo truly is at sim time `t_s` (left +; 0 without one)."""
        with self._lock:
            return self._pan_at(t_s)

    def tilt_rad(self, t_s: float, *, hull_pitch_rad: float = 0.0) -> float:
        """Where the servo truly is on the hull at sim time `t_s` (what the sonar looks along).

        `hull_pitch_rad`: the hull's pitch then (nose down +, W's Z-Y-X), which the servo takes
        out to hold its angle against the horizon.
        """
        with self._lock:
            return self._at(t_s) - hull_pitch_rad

    def command(self, t_s: float, pitch_deg: float, yaw_deg: float = math.nan) -> None:
        """The autopilot told the mount `pitch_deg` and `yaw_deg` at sim time `t_s`.

        NaN: that axis is left as it is; a yaw without a pan servo: ignored.
        """
        if math.isfinite(pitch_deg):
            self.aim(t_s, math.radians(self.zero_pitch_deg - pitch_deg))
        if math.isfinite(yaw_deg) and self.pan is not None:
            self.aim_pan(t_s, -math.radians(yaw_deg))

    def aim_pan(self, t_s: float, pan_rad: float) -> None:
        """Drive the pan servo to `pan_rad` (left +, within its range) from sim time `t_s`."""
        if self.pan is None:
            return
        with self._lock:
            self._pan_from = self._pan_at(t_s)
            self._pan_t0 = t_s
            self._pan_to = self.pan.clamp_rad(pan_rad)

    def aim(self, t_s: float, tilt_rad: float) -> None:
        """Drive the servo to `tilt_rad` (within its range) from sim time `t_s`."""
        with self._lock:
            self._from = self._at(t_s)
            self._t0 = t_s
            self._to = self.servo.clamp_rad(tilt_rad)
            self.commands += 1

    def reported_pitch_rad(self) -> float:
        """What the autopilot reports: the (clamped) pitch it drives the servo to (up +).

        Against the horizon, as ArduPilot's mount library reports it.
        """
        with self._lock:
            return math.radians(self.zero_pitch_deg) - self._to

    def reported_yaw_rad(self) -> float:
        """The yaw the autopilot reports: where it drives the pan (the vehicle's frame, right +)."""
        with self._lock:
            return -self._pan_to
