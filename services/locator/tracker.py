"""Constant-velocity Kalman tracker of the ROV in the world frame, with gating and coasting.

State x = (p, v) in W. Process model: white acceleration with spectral density q per axis
(m^2/s^3), so over dt the covariance grows by q [[dt^3/3, dt^2/2], [dt^2/2, dt]] per axis.
Measurements are CAP-SD fixes (position, 3 x 3 covariance) and, when available, the ROV's own
velocity. A fix is accepted only inside a Mahalanobis gate (chi-square, 3 dof); among several
candidates the one with the smallest distance wins. Without accepted fixes the track coasts with
growing covariance and is declared lost after `lost_after_s`. A run of consistent fixes outside
the gate re-initialises the track (a relocalisation, counted in `resets`).

Manoeuvres: the process noise suits a ROV holding or cruising, not one starting or ending a leg
(ArduSub accelerates at up to WPNAV_ACCEL, 1 m/s^2 by default): at a leg's start the track
lags, the fixes, still on the ROV, fall outside its gate and the track coasts away from them.
So a confirmed track whose gate refuses every candidate tries once more: predicted from its
last fused fix with the manoeuvre process noise (`manoeuvre_accel_density_*`) over the whole
time since (at most `manoeuvre_window_s`: longer, a wide gate would take clutter), the same
gate. A candidate that fits that wider prediction, and may start a track
(never mapped or static clutter), is fused with it (the velocity catches up in a few pings);
each such fix is counted in `manoeuvres`. A jump the manoeuvre model cannot explain either
still coasts and, repeated, relocalises.

A new track (first start, after a loss, after a relocalisation) is "tentative" until
`confirm_after` fixes fell inside its gate: one stray echo is never called the ROV. The caller
may mark candidates that must not start a track (static clutter, capsd.services.locator.clutter);
they are still associated with an existing track, but do not count towards confirming a
tentative one. Learned static clutter (`static`) updates a track only until it has coasted
`static_coast_s`: a ROV lost beside a sandbag (its echo merged or missed) and the sandbag's
echo, inside the coasting track's growing gate, would take the track and be called the ROV, and
the ROV's own echo, seen again, then falls outside the dragged gate (nfp demo, seed 2, session
38: a fix 0.5 m off sent as good, then a 100 s loss).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from capsd.geometry import Array

TrackState = Literal["none", "tentative", "tracking", "coasting", "lost"]


@dataclass(frozen=True)
class TrackerSettings:
    """Tuning of the tracker; see the module docstring for the model."""

    accel_density_xy: float = 0.02  # m^2/s^3: a BlueROV2 changes speed gently in a tank
    accel_density_z: float = 0.0005  # the locator config's default (why: its comment)
    initial_speed_sigma_m_s: float = 0.5
    gate_chi2: float = 16.27  # chi-square 3 dof, p = 0.999
    lost_after_s: float = 2.0
    reinit_after: int = 5  # consecutive out-of-gate fixes that start a new track
    confirm_after: int = 3  # gated fixes before a new track is more than tentative
    # A ROV starting, ending or turning a leg (see the module docstring); 0: no manoeuvre gate.
    manoeuvre_accel_density_xy: float = 0.5
    manoeuvre_accel_density_z: float = 0.1
    manoeuvre_window_s: float = 1.0  # only this soon after the last fused fix
    # Coasting this long, the track takes no echo of learned static clutter (module docstring).
    static_coast_s: float = 0.5


@dataclass(frozen=True)
class Estimate:
    """The tracker's state at one instant."""

    state: TrackState
    stamp_ns: int
    position_m: Array | None
    velocity_m_s: Array | None
    covariance_m2: Array | None  # position block only
    resets: int


@dataclass(frozen=True)
class Association:
    """Which candidate the tracker took, and its squared Mahalanobis distance."""

    index: int | None
    distance2: float | None
    reinitialised: bool


class Tracker:
    """One ROV track; feed it time-ordered fixes through `update` and `coast`."""

    def __init__(self, settings: TrackerSettings):
        self.settings = settings
        self.x = np.zeros(6)
        self.P = np.eye(6)
        self.stamp_ns: int | None = None
        self.last_update_ns: int | None = None
        self.state: TrackState = "none"
        self.resets = 0
        self._outside = 0
        self._outside_last: Array | None = None
        self._hits = 0  # fixes fused since the track started
        self._fused: tuple[int, Array, Array] | None = None  # stamp, x, P after the last fix
        self.manoeuvres = 0  # fixes fused through the manoeuvre gate

    @property
    def confirmed(self) -> bool:
        return self._hits >= self.settings.confirm_after

    # ------------------------------------------------------------------ model

    def _predict(self, stamp_ns: int) -> tuple[Array, Array]:
        assert self.stamp_ns is not None
        s = self.settings
        return _predicted(
            self.x, self.P, (stamp_ns - self.stamp_ns) / 1e9, s.accel_density_xy, s.accel_density_z
        )

    def _start(self, stamp_ns: int, position: Array, covariance: Array) -> None:
        self.x = np.concatenate([position, np.zeros(3)])
        self.P = np.zeros((6, 6))
        self.P[0:3, 0:3] = covariance
        self.P[3:6, 3:6] = np.eye(3) * self.settings.initial_speed_sigma_m_s**2
        self.stamp_ns = self.last_update_ns = stamp_ns
        self.state = "tracking"
        self._outside = 0
        self._outside_last = None
        self._hits = 1
        self._fused = (stamp_ns, self.x.copy(), self.P.copy())

    # ------------------------------------------------------------------ inputs

    def gated(self, stamp_ns: int, fixes: list[tuple[Array, Array]]) -> list[bool]:
        """Whether each fix falls inside the current track's gate now (no track: none does)."""
        if self.state in ("none", "lost") or self.stamp_ns is None or stamp_ns < self.stamp_ns:
            return [False] * len(fixes)
        x_pred, p_pred = self._predict(stamp_ns)
        return [d <= self.settings.gate_chi2 for d, _ in _scored(fixes, x_pred, p_pred)]

    def restart(self, stamp_ns: int, position: Array, covariance: Array) -> None:
        """Start a new (tentative) track on this fix, whatever the current one; a reset."""
        self.resets += 1
        self._start(stamp_ns, position, covariance)

    def update(
        self,
        stamp_ns: int,
        fixes: list[tuple[Array, Array]],
        *,
        may_start: list[bool] | None = None,
        static: list[bool] | None = None,
    ) -> Association:
        """Fuse the best gated fix among `fixes` (position, covariance) taken at `stamp_ns`.

        `may_start[i]` False: candidate i may update the track but never start a new one.
        `static[i]` True: candidate i is learned static clutter: it starts no track either, and
        no track that has coasted `static_coast_s` takes it.
        """
        self._expire(stamp_ns)
        starters = [True] * len(fixes) if may_start is None else may_start
        if static is not None:
            starters = [s and not st for s, st in zip(starters, static, strict=True)]
        if not fixes:
            self.coast(stamp_ns)
            return Association(None, None, reinitialised=False)
        if self.state in ("none", "lost") or self.stamp_ns is None:
            # No track: start on the most certain candidate that may start one.
            allowed = [i for i in range(len(fixes)) if starters[i]]
            if not allowed:
                return Association(None, None, reinitialised=False)
            best = min(allowed, key=lambda i: float(np.trace(fixes[i][1])))
            self._start(stamp_ns, *fixes[best])
            return Association(best, None, reinitialised=True)
        if stamp_ns < self.stamp_ns:
            return Association(None, None, reinitialised=False)  # older than the track: ignore
        x_pred, p_pred = self._predict(stamp_ns)
        h = np.hstack([np.eye(3), np.zeros((3, 3))])
        scored = _scored(fixes, x_pred, p_pred)
        if static is not None and self._coasted_s(stamp_ns) >= self.settings.static_coast_s:
            scored = [(math.inf if static[i] else d, i) for d, i in scored]
        distance2, index = min(scored)
        if distance2 > self.settings.gate_chi2:
            manoeuvre = self._manoeuvre(stamp_ns, fixes, starters)
            if manoeuvre is not None:
                x_pred, p_pred, distance2, index = manoeuvre
                self.manoeuvres += 1
        if distance2 > self.settings.gate_chi2:
            self.x, self.P, self.stamp_ns = x_pred, p_pred, stamp_ns
            self.state = "coasting"
            outside = [(d, i) for d, i in scored if starters[i]]
            if not outside:
                return Association(None, distance2, reinitialised=False)
            index = min(outside)[1]
            if self._consistent_outside(fixes[index][0]):
                self.resets += 1
                self._start(stamp_ns, *fixes[index])
                return Association(index, distance2, reinitialised=True)
            return Association(None, distance2, reinitialised=False)
        z, r = fixes[index]
        s = h @ p_pred @ h.T + r
        gain = p_pred @ h.T @ np.linalg.inv(s)
        self.x = x_pred + gain @ (z - x_pred[0:3])
        joseph = np.eye(6) - gain @ h
        self.P = joseph @ p_pred @ joseph.T + gain @ r @ gain.T
        self.stamp_ns = self.last_update_ns = stamp_ns
        self._fused = (stamp_ns, self.x.copy(), self.P.copy())
        self.state = "tracking"
        self._outside = 0
        if self.confirmed or starters[index]:
            # A new track is confirmed only by fixes that could each have started it: an echo
            # that may not start one (static or mapped clutter) still moves a tentative track
            # but does not vouch for it.
            self._hits += 1
        return Association(index, distance2, reinitialised=False)

    def _manoeuvre(
        self, stamp_ns: int, fixes: list[tuple[Array, Array]], starters: list[bool]
    ) -> tuple[Array, Array, float, int] | None:
        """The manoeuvre gate (module docstring): prediction, distance^2, candidate; or None."""
        s = self.settings
        if (
            not self.confirmed
            or self._fused is None
            or s.manoeuvre_accel_density_xy <= 0.0
            or not any(starters)
            or stamp_ns - self._fused[0] > s.manoeuvre_window_s * 1e9
        ):
            return None
        fused_ns, x, p = self._fused
        x_pred, p_pred = _predicted(
            x,
            p,
            (stamp_ns - fused_ns) / 1e9,
            s.manoeuvre_accel_density_xy,
            s.manoeuvre_accel_density_z,
        )
        scored = [(d, i) for d, i in _scored(fixes, x_pred, p_pred) if starters[i]]
        distance2, index = min(scored)
        if distance2 > s.gate_chi2:
            return None
        return x_pred, p_pred, distance2, index

    def update_velocity(self, stamp_ns: int, velocity: Array, covariance: Array) -> None:
        """Fuse the ROV's own velocity in W (e.g. from a DVL or its EKF)."""
        if self.state in ("none", "lost") or self.stamp_ns is None or stamp_ns < self.stamp_ns:
            return
        x_pred, p_pred = self._predict(stamp_ns)
        h = np.hstack([np.zeros((3, 3)), np.eye(3)])
        s = h @ p_pred @ h.T + covariance
        gain = p_pred @ h.T @ np.linalg.inv(s)
        self.x = x_pred + gain @ (velocity - x_pred[3:6])
        joseph = np.eye(6) - gain @ h
        self.P = joseph @ p_pred @ joseph.T + gain @ covariance @ gain.T
        self.stamp_ns = stamp_ns

    def coast(self, stamp_ns: int) -> None:
        """Advance without a measurement: the covariance grows; lost after `lost_after_s`."""
        self._expire(stamp_ns)
        if self.state in ("tracking", "coasting") and self.stamp_ns is not None:
            if stamp_ns >= self.stamp_ns:
                self.x, self.P = self._predict(stamp_ns)
                self.stamp_ns = stamp_ns
            self.state = "coasting"

    def _coasted_s(self, stamp_ns: int) -> float:
        """How long the track has coasted (0 while its last ping fused a fix)."""
        if self.state != "coasting" or self.last_update_ns is None:
            return 0.0
        return (stamp_ns - self.last_update_ns) / 1e9

    def _expire(self, stamp_ns: int) -> None:
        if (
            self.state in ("tracking", "coasting")
            and self.last_update_ns is not None
            and (stamp_ns - self.last_update_ns) / 1e9 > self.settings.lost_after_s
        ):
            self.state = "lost"

    def _consistent_outside(self, position: Array) -> bool:
        """Count consecutive out-of-gate fixes that agree with each other (within 1 m)."""
        if self._outside_last is not None and np.linalg.norm(position - self._outside_last) < 1.0:
            self._outside += 1
        else:
            self._outside = 1
        self._outside_last = position
        return self._outside >= self.settings.reinit_after

    # ------------------------------------------------------------------ output

    def estimate(self) -> Estimate:
        if self.state in ("none", "lost") or self.stamp_ns is None:
            return Estimate(self.state, self.stamp_ns or 0, None, None, None, self.resets)
        cov = 0.5 * (self.P[0:3, 0:3] + self.P[0:3, 0:3].T)
        state: TrackState = self.state if self.confirmed else "tentative"
        return Estimate(
            state, self.stamp_ns, self.x[0:3].copy(), self.x[3:6].copy(), cov, self.resets
        )


def _predicted(
    x: Array, p: Array, dt_s: float, density_xy: float, density_z: float
) -> tuple[Array, Array]:
    """State and covariance `dt_s` on under white acceleration of these densities (m^2/s^3)."""
    dt = max(0.0, dt_s)
    f = np.eye(6)
    f[0:3, 3:6] = dt * np.eye(3)
    q = np.zeros((6, 6))
    for axis, density in ((0, density_xy), (1, density_xy), (2, density_z)):
        q[axis, axis] = density * dt**3 / 3.0
        q[axis, axis + 3] = q[axis + 3, axis] = density * dt**2 / 2.0
        q[axis + 3, axis + 3] = density * dt
    return f @ x, f @ p @ f.T + q


def _scored(fixes: list[tuple[Array, Array]], x: Array, p: Array) -> list[tuple[float, int]]:
    """Each fix's squared Mahalanobis distance from the predicted position, and its index."""
    out = []
    for i, (z, r) in enumerate(fixes):
        innovation = z - x[0:3]
        out.append((float(innovation @ np.linalg.solve(p[0:3, 0:3] + r, innovation)), i))
    return out
