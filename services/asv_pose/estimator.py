"""The ASV's pose from its IMU and LiDAR: tilt at IMU rate, (x, y, yaw) from scan matching.

- Roll/pitch: the tilt filter (capsd.services.asv_pose.tilt), fed the ASV's own acceleration from a
  quadratic fit to the last ~0.7 s of scan matches (rotated into the body frame), so manoeuvres
  do not leak into tilt.
- Yaw between scans: integrated from the gyro (world z rate from the body rates and tilt). A
  match corrects the heading at the scan's own stamp, not at the newest IMU sample's: the
  gyro's rotation between the two is kept. On a live bus the two streams arrive in any order
  by a few tens of milliseconds, and a turning ASV (15 deg/s) would otherwise take a heading
  error of the turn rate times that gap (0.5-3 deg seen in a closed-loop run: 5-30 cm at the
  ROV 6 m off).
- Each scan, levelled with the current roll/pitch, is matched against the tank's walls, seeded
  by the prediction (last match + velocity, yaw from the gyro). A match is accepted only if it
  passes the health checks: inlier ratio, residual, degeneracy, and the jump from the
  prediction; otherwise the prediction coasts and the failure is counted. After `lost_after`
  consecutive failures the pose is reported lost.
- Output at IMU rate: position extrapolated from the last match with the track's velocity,
  orientation from yaw and tilt, a 6 x 6 covariance growing with the time since the last match.
- Global search (capsd.services.asv_pose.global_search) at start-up and after `lost_after`
  consecutive failures, at most once per `search_interval_s`: no position seed is needed. The
  bare rectangle is 180-degree symmetric, so a heading prior picks the side: the configured one
  at start-up (compass or launch orientation; None: only a map without that symmetry works),
  the gyro-propagated heading after a loss. An ambiguous search keeps the pose lost.
"""

from __future__ import annotations

import math
from bisect import bisect_left
from collections import deque
from dataclasses import dataclass
from typing import Literal

import numpy as np

from capsd.geometry import Array, euler_zyx_to_matrix, matrix_to_quat
from capsd.payloads import AsvPose, AsvPoseSource, AsvPoseStatus
from capsd.services.asv_pose.global_search import MapRaster, SearchSettings, search
from capsd.services.asv_pose.scan_match import MatchResult, Segment, level_points, match
from capsd.services.asv_pose.tilt import TiltFilter, TiltSettings


@dataclass(frozen=True)
class EstimatorSettings:
    min_inlier_ratio: float = 0.6
    max_residual_m: float = 0.06
    min_degeneracy: float = 10.0
    max_jump_m: float = 0.5
    max_jump_rad: float = math.radians(5.0)
    lost_after: int = 10
    # Without a scan match for this long the pose is "degraded" (coasting on the last
    # velocity), and after `coast_limit_s` "lost": a floating ASV is not held by an IMU, and a
    # fix from a drifting pose is wrong by more than its covariance says (measured: a 5 s
    # LiDAR dropout gave 19 estimates off by > 3 sigma while the pose still said "ok").
    coast_degraded_s: float = 0.25
    coast_limit_s: float = 1.0
    search_interval_s: float = 1.0
    # The scanner's position in the body frame, its height above the origin included.
    lidar_position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    track_fit_scans: int = 11  # ~0.7 s at 15 Hz
    # "track": the tilt filter is told the ASV's own acceleration (from the scan track), so
    # manoeuvres do not read as tilt; "none": the paper's filter, which is not.
    accel_compensation: Literal["track", "none"] = "track"


@dataclass(frozen=True)
class PoseEstimate:
    stamp_ns: int
    position_m: Array
    rotation: Array
    covariance: Array  # 6 x 6 over (x, y, z, roll, pitch, yaw)
    status: AsvPoseStatus  # "ok", "degraded" (coasting), "lost"


def pose_payload(est: PoseEstimate, *, seq: int, source: AsvPoseSource) -> AsvPose:
    """The bus payload of an estimate."""
    q = matrix_to_quat(est.rotation)
    return AsvPose(
        stamp_ns=est.stamp_ns,
        seq=seq,
        position_m=(float(est.position_m[0]), float(est.position_m[1]), float(est.position_m[2])),
        orientation_xyzw=(float(q[0]), float(q[1]), float(q[2]), float(q[3])),
        covariance=tuple(float(v) for v in est.covariance.ravel()),
        status=est.status,
        source=source,
    )


class AsvPoseEstimator:
    """Feed IMU samples and scans in time order; read `estimate()` after any of them."""

    def __init__(
        self,
        walls: tuple[Segment, ...],
        *,
        heading_prior_rad: float | None,
        settings: EstimatorSettings | None = None,
        tilt: TiltSettings | None = None,
        search_settings: SearchSettings | None = None,
    ):
        self.walls = walls
        self.settings = settings or EstimatorSettings()
        self.tilt = TiltFilter(tilt)
        self.search_settings = search_settings or SearchSettings()
        self._raster = MapRaster(walls, raster_m=self.search_settings.raster_m)
        self.heading_prior_rad = heading_prior_rad
        self.xy = np.zeros(2)
        self.velocity = np.zeros(2)
        self.acceleration = np.zeros(2)
        self.searches = 0
        self.relocalisations = 0
        self.last_search_ns: int | None = None
        self.last_search_why = ""
        self.match_ns: int | None = None
        self.imu_ns: int | None = None
        self.failures = 0
        self.accepted = 0
        self.rejected: dict[str, int] = {}
        self.match_cov = np.diag([0.05**2, 0.05**2, math.radians(2.0) ** 2])
        self._track: list[tuple[int, Array]] = []
        # The gyro's integrated heading (never reset) by IMU stamp, about the last 2 s; the
        # heading is that plus the offset the last match set.
        self._gyro_yaw = 0.0
        self._gyro_log: deque[tuple[int, float]] = deque(maxlen=512)
        self._gyro_rate = 0.0
        self._yaw_offset = heading_prior_rad if heading_prior_rad is not None else 0.0

    @property
    def yaw(self) -> float:
        """The heading now: the gyro's integrated heading plus the last match's offset."""
        return self._gyro_yaw + self._yaw_offset

    def on_imu(self, stamp_ns: int, gyro: Array, accel: Array) -> None:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        # The track's acceleration in the (levelled) body frame, for the tilt filter.
        a_body = np.array(
            [
                c * self.acceleration[0] + s * self.acceleration[1],
                -s * self.acceleration[0] + c * self.acceleration[1],
                0.0,
            ]
        )
        if self.settings.accel_compensation == "none":
            a_body = np.zeros(3)
        self.tilt.update(stamp_ns, gyro, accel, linear_accel_body_m_s2=a_body)
        if self.imu_ns is not None and stamp_ns > self.imu_ns:
            dt = (stamp_ns - self.imu_ns) / 1e9
            roll, pitch = self.tilt.roll_rad, self.tilt.pitch_rad
            # World yaw rate from body rates (Z-Y-X): (q sin r + r cos r) / cos p.
            g = np.asarray(gyro, dtype=np.float64) - self.tilt.bias
            yaw_rate = (g[1] * math.sin(roll) + g[2] * math.cos(roll)) / max(math.cos(pitch), 0.1)
            self._gyro_yaw += yaw_rate * dt
            self._gyro_rate = yaw_rate
        if self.imu_ns is None or stamp_ns > self.imu_ns:
            self._gyro_log.append((stamp_ns, self._gyro_yaw))
            self.imu_ns = stamp_ns

    def _gyro_yaw_at(self, stamp_ns: int) -> float:
        """The gyro's integrated heading at `stamp_ns` (past the newest sample: extrapolated)."""
        log = self._gyro_log
        if not log or stamp_ns >= log[-1][0]:
            newest = log[-1][0] if log else stamp_ns
            return self._gyro_yaw + self._gyro_rate * (stamp_ns - newest) / 1e9
        if stamp_ns <= log[0][0]:
            return log[0][1]
        i = bisect_left(log, (stamp_ns, -math.inf))
        (t0, y0), (t1, y1) = log[i - 1], log[i]
        return y0 + (y1 - y0) * (stamp_ns - t0) / (t1 - t0)

    def on_scan(self, stamp_ns: int, ranges_m: Array, angles_rad: Array) -> bool:
        """Match one scan; True if accepted."""
        s = self.settings
        predicted = self._predict_xy(stamp_ns)
        points = level_points(
            ranges_m,
            angles_rad,
            roll_rad=self.tilt.roll_rad,
            pitch_rad=self.tilt.pitch_rad,
            mount_m=s.lidar_position_m,
        )
        if len(points) < 20:
            return self._reject("too_few_returns")
        if self.match_ns is None or self.failures >= s.lost_after:
            return self._search(stamp_ns, points)
        result = match(
            points, self.walls, x_m=float(predicted[0]), y_m=float(predicted[1]), yaw_rad=self.yaw
        )
        jump = math.hypot(result.x_m - predicted[0], result.y_m - predicted[1])
        dyaw = abs(
            math.atan2(math.sin(result.yaw_rad - self.yaw), math.cos(result.yaw_rad - self.yaw))
        )
        failed = self._check(result)
        if failed:
            return self._reject(failed)
        if jump > s.max_jump_m or dyaw > s.max_jump_rad:
            return self._reject("jump")
        self._accept(stamp_ns, result)
        return True

    def on_external(
        self, stamp_ns: int, x_m: float, y_m: float, yaw_rad: float, covariance: Array
    ) -> bool:
        """An external pose (an existing SLAM) in place of a scan match; True if used.

        The external source is authoritative: a jump from the prediction is counted (a SLAM
        reset shows up there) but the pose is taken.
        """
        if not all(math.isfinite(v) for v in (x_m, y_m, yaw_rad)):
            return self._reject("external_invalid")
        if self.match_ns is not None:
            predicted = self._predict_xy(stamp_ns)
            if math.hypot(x_m - predicted[0], y_m - predicted[1]) > self.settings.max_jump_m:
                self.rejected["external_jumps"] = self.rejected.get("external_jumps", 0) + 1
                self._track.clear()
        cov = np.asarray(covariance, dtype=np.float64)
        if cov.shape != (3, 3) or not np.all(np.isfinite(cov)):
            cov = np.diag([0.05**2, 0.05**2, math.radians(2.0) ** 2])
        self._accept(stamp_ns, MatchResult(x_m, y_m, yaw_rad, 1.0, 0.0, math.inf, cov, 0))
        return True

    def _check(self, result: MatchResult) -> str:
        """The match health checks; the failed one's name, or '' when all pass."""
        s = self.settings
        if result.inlier_ratio < s.min_inlier_ratio:
            return "inliers"
        if result.residual_rms_m > s.max_residual_m:
            return "residual"
        if result.degeneracy < s.min_degeneracy:
            return "degenerate"
        return ""

    def _search(self, stamp_ns: int, points: Array) -> bool:
        """Global search (rate limited); on success the track restarts from its answer."""
        interval_ns = int(self.settings.search_interval_s * 1e9)
        if self.last_search_ns is not None and stamp_ns - self.last_search_ns < interval_ns:
            return self._reject("lost_waiting_for_search")
        self.last_search_ns = stamp_ns
        self.searches += 1
        # After a loss the gyro-propagated heading is the prior; at start-up the configured one.
        prior = self.yaw if self.match_ns is not None else self.heading_prior_rad
        found = search(
            points,
            self.walls,
            heading_prior_rad=prior,
            settings=self.search_settings,
            raster=self._raster,
        )
        if found.best is None:
            self.last_search_why = found.why
            return self._reject("search_ambiguous" if found.ambiguous else "search_failed")
        failed = self._check(found.best)
        if failed:
            self.last_search_why = f"best hypothesis fails the {failed} check"
            return self._reject("search_failed")
        self.last_search_why = ""
        self._track.clear()
        self.velocity = np.zeros(2)
        self.acceleration = np.zeros(2)
        self.relocalisations += 1
        self._accept(stamp_ns, found.best)
        return True

    def _accept(self, stamp_ns: int, result: MatchResult) -> None:
        new_xy = np.array([result.x_m, result.y_m])
        self._track.append((stamp_ns, new_xy))
        if len(self._track) > self.settings.track_fit_scans:
            self._track.pop(0)
        self._fit_track(stamp_ns)
        self.xy = new_xy
        # The match's heading holds at the scan's stamp; the gyro carries it to the newest.
        self._yaw_offset = result.yaw_rad - self._gyro_yaw_at(stamp_ns)
        self.match_ns = stamp_ns
        self.match_cov = result.covariance
        self.failures = 0
        self.accepted += 1

    def _fit_track(self, stamp_ns: int) -> None:
        """Velocity and acceleration from a quadratic fit to the recent matches.

        Differencing 15 Hz scans amplifies their centimetre noise into metres per second
        squared; a least-squares quadratic over ~0.7 s gives the tilt filter a usable
        acceleration (slightly late, but smooth).
        """
        if len(self._track) < 5:
            return
        t = np.array([(s - stamp_ns) / 1e9 for s, _ in self._track])
        xy = np.array([p for _, p in self._track])
        basis = np.column_stack([np.ones_like(t), t, t * t])
        coeffs, *_ = np.linalg.lstsq(basis, xy, rcond=None)
        self.velocity = coeffs[1]
        self.acceleration = 2.0 * coeffs[2]

    def _reject(self, why: str) -> bool:
        self.failures += 1
        self.rejected[why] = self.rejected.get(why, 0) + 1
        return False

    def _predict_xy(self, stamp_ns: int) -> Array:
        if self.match_ns is None:
            return self.xy.copy()
        dt = max(0.0, (stamp_ns - self.match_ns) / 1e9)
        return np.asarray(self.xy + self.velocity * dt, dtype=np.float64)

    def estimate(self, stamp_ns: int) -> PoseEstimate:
        xy = self._predict_xy(stamp_ns)
        rotation = euler_zyx_to_matrix(self.yaw, self.tilt.pitch_rad, self.tilt.roll_rad)
        age = 0.0 if self.match_ns is None else max(0.0, (stamp_ns - self.match_ns) / 1e9)
        cov = np.zeros((6, 6))
        cov[0:2, 0:2] = self.match_cov[0:2, 0:2] + np.eye(2) * (0.05 * age) ** 2
        cov[2, 2] = 0.02**2  # heave is not observed: the waves' amplitude
        cov[3, 3] = cov[4, 4] = math.radians(0.2) ** 2
        cov[5, 5] = self.match_cov[2, 2] + (math.radians(0.5) * age) ** 2
        status: AsvPoseStatus
        if (
            self.failures >= self.settings.lost_after
            or self.match_ns is None
            or age > self.settings.coast_limit_s
        ):
            status = "lost"
        elif self.failures > 0 or age > self.settings.coast_degraded_s:
            status = "degraded"
        else:
            status = "ok"
        return PoseEstimate(stamp_ns, np.array([xy[0], xy[1], 0.0]), rotation, cov, status)
