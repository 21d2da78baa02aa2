"""A new track far from where the ROV was lost is unsure until it moves as a ROV or persists.

The tracker confirms a new track on hits alone (`confirm_after` gated fixes, under a second of
pings). After a loss that is too little: in a recorded closed-loop run (session 34) the detector
lost the ROV over a rack, 5 s later a new track started on an unmapped echo 2.1 m from where
the paused ROV held, was confirmed within a second and reported good for 8 s, 2.2-4.5 m off; the
ROV's autopilot, fed those positions, flew 1.5 m off its lane. A static echo vouches for itself
as well as a static ROV does: hits cannot tell them apart, where the ROV was last seen can.

So a track that starts (after a loss or a relocalisation) farther than the ROV could have gone
since its last confirmed fix is a relocation, and stays unsure until either
- its echo moved as no static source's could (capsd.services.locator.moving_echo, the same test
  the map-explained echoes pass): a ROV flown by its pilot, or resuming, proves itself in a
  second or two; or
- it has been followed for `confirm_after_s` without a candidate appearing where the ROV could
  be: a ROV that really drifted far while unseen is taken back, late rather than wrong.
Meanwhile a candidate where the ROV could be (and allowed to start a track) takes the track
over at once: the ROV reappearing where it was lost wins. Not the relocated track's own echo:
the reach grows with the time since the loss and may come to hold it (a static echo would then
be confirmed on hits after all).

Where the ROV could be: within `radius_m` + `drift_m_s` x elapsed of the segment from its last
confirmed position to where its velocity then would have carried it in `carry_s` (or the time
elapsed, if shorter). A mission pauses within its fix timeout (0.5 s in the shipped plans) and
stops the ROV (ArduSub decelerates at 1 m/s^2); ArduSub's position hold without fixes drifts
slowly (under 1 m in a 10-20 s re-station of the ASV in SITL). A ROV that kept going, flown by
its pilot or on a trajectory, moves and so proves itself. The same reach bounds where an echo a
mapped fixture explains may restart a track (the locator's reacquire rule): there a wide radius
lets a rack's echo beside the ROV in (0.5 m + 0.2 m/s: `capsd bench accuracy` as before this
rule; 1 m + 0.1 m/s: a good fix 1.21 m off in nfp bouncing, 76 fewer good pings).
"""

from __future__ import annotations

from dataclasses import dataclass

from capsd.geometry import Array, Transform, distance_to_segment
from capsd.services.locator.moving_echo import MovingEchoes, MovingEchoSettings
from capsd.sonar_geometry import BeamModel


@dataclass(frozen=True)
class RelocationSettings:
    """Where a lost ROV can be, and how long a far track waits; see the module docstring."""

    radius_m: float = 0.5
    drift_m_s: float = 0.2
    carry_s: float = 2.0
    confirm_after_s: float = 20.0


@dataclass(frozen=True)
class LastSeen:
    """The ROV's last confirmed fix: when, where and how fast it went."""

    stamp_ns: int
    position_m: Array
    velocity_m_s: Array


class Relocation:
    """Whether the current track is an unproven relocation; feed it the track's fixes."""

    def __init__(
        self,
        settings: RelocationSettings,
        moving: MovingEchoSettings,
        *,
        beam_model: BeamModel,
        half_aperture_rad: float,
    ):
        self.settings = settings
        self._moving = moving
        self._beam_model = beam_model
        self._half_aperture_rad = half_aperture_rad
        self._since_ns: int | None = None
        self._movers: MovingEchoes | None = None
        self.started = 0  # relocations begun
        self.proven_moving = 0  # ... ended because the echo moved
        self.proven_waiting = 0  # ... ended because they persisted
        self.taken_over = 0  # ... ended by a candidate where the ROV could be

    @property
    def active(self) -> bool:
        return self._since_ns is not None

    def reachable(self, stamp_ns: int, position_m: Array, last: LastSeen | None) -> bool:
        """Whether the ROV could be at `position_m` now, given where it was last confirmed."""
        if last is None:
            return True  # never seen: anywhere
        elapsed_s = max(0.0, (stamp_ns - last.stamp_ns) / 1e9)
        start = last.position_m
        end = start + last.velocity_m_s * min(elapsed_s, self.settings.carry_s)
        radius_m = self.settings.radius_m + self.settings.drift_m_s * elapsed_s
        return distance_to_segment(position_m, start, end) <= radius_m

    def begin(self, stamp_ns: int) -> None:
        """A track started where the ROV could not be: unproven from now."""
        self._since_ns = stamp_ns
        self._movers = MovingEchoes(
            self._moving,
            beam_model=self._beam_model,
            half_aperture_rad=self._half_aperture_rad,
        )
        self.started += 1

    def end(self) -> None:
        """The track is gone or taken over: nothing to prove."""
        self._since_ns = None
        self._movers = None

    def take_over(self) -> None:
        """A candidate where the ROV could be restarted the track."""
        if self.active:
            self.taken_over += 1
        self.end()

    def observe(
        self,
        stamp_ns: int,
        sonar_pose: Transform,
        *,
        range_m: float,
        azimuth_rad: float,
        position_m: Array,
    ) -> None:
        """One fix the relocated track took; it may prove the track."""
        if self._since_ns is None or self._movers is None:
            return
        moved = self._movers.observe(
            stamp_ns, sonar_pose, range_m=range_m, azimuth_rad=azimuth_rad, position_m=position_m
        )
        if moved:
            self.proven_moving += 1
            self.end()
        elif (stamp_ns - self._since_ns) / 1e9 >= self.settings.confirm_after_s:
            self.proven_waiting += 1
            self.end()
