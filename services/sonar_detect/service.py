"""The sonar detection service: frames in, ROV candidates out, newest frame first.

Frames arrive on Zenoh's callback thread and go into a one-slot mailbox; a worker thread takes
the newest frame, detects, and publishes SonarDetections stamped with the frame's `stamp_ns`
and `ping_id`. A frame replaced in the mailbox before the worker took it is dropped and counted:
a stale frame is never processed. Every `snapshot_every_s` a fan PNG with the detections is
written for people.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from pathlib import Path
from typing import Annotated, Literal, NamedTuple, Protocol

import msgspec
import numpy as np

from capsd import topics
from capsd.config import ConfigSection, ServiceConfig
from capsd.errors import CapsdError, ConfigError
from capsd.geometry import Transform, quat_to_matrix
from capsd.mailbox import Mailbox
from capsd.mounts import SonarMountConfig
from capsd.payloads import (
    AsvPose,
    Detection,
    RovDepth,
    SonarDetections,
    SonarFrame,
    SonarTilt,
)
from capsd.runner import Publisher, ServiceRunner
from capsd.services.sonar_detect.classical import ClassicalDetector, ClassicalSettings
from capsd.services.sonar_detect.depth_gate import DepthGate
from capsd.services.sonar_detect.one_rov import DEFAULT_CONFIDENCE, Confidence, scored
from capsd.services.sonar_detect.range_bias import DEFAULT_TABLE as DEFAULT_RANGE_BIAS
from capsd.services.sonar_detect.range_bias import RangeBias
from capsd.services.sonar_detect.range_bias import load as load_range_bias
from capsd.servo_motion import ServoMotion, ServoState

logger = logging.getLogger(__name__)


class ClassicalConfig(ConfigSection, frozen=True, kw_only=True):
    margin: Annotated[float, msgspec.Meta(gt=0.0, le=255.0)] = 70.0
    background_margin: Annotated[float, msgspec.Meta(gt=0.0, le=255.0)] | None = None
    range_bias_m: Annotated[float, msgspec.Meta(ge=-1.0, le=1.0)] = 0.12
    max_candidates: Annotated[int, msgspec.Meta(ge=1, le=20)] = 3

    def settings(self) -> ClassicalSettings:
        return ClassicalSettings(
            margin=self.margin,
            background_margin=self.background_margin,
            range_bias_m=self.range_bias_m,
            max_candidates=self.max_candidates,
        )


class CnnConfig(ConfigSection, frozen=True, kw_only=True):
    # None: the weights shipped with the package (services/sonar_detect/weights/polar_net.pt).
    weights: str | None = None
    proposal_threshold: Annotated[float, msgspec.Meta(gt=0.0, lt=1.0)] = 0.1
    # The same inside the depth gate's range window if lower (capsd.services.sonar_detect.cnn;
    # null: proposal_threshold there too).
    gated_proposal_threshold: Annotated[float, msgspec.Meta(gt=0.0, lt=1.0)] | None = None
    # Proposals refined per whole-frame search (capsd.services.sonar_detect.cnn, since session
    # 65: 6; 3 before).
    max_candidates: Annotated[int, msgspec.Meta(ge=1, le=20)] = 6
    refine_passes: Annotated[int, msgspec.Meta(ge=1, le=5)] = 2
    # Ping time between whole-frame searches; between them only the last ping's confident
    # detections are refined (a quarter of the work at 40 Hz). 0: search every frame.
    search_every_s: Annotated[float, msgspec.Meta(ge=0.0, le=10.0)] = 0.1
    # Added to the logit of a candidate that continues a detection of the last ping (<= 0.2 s
    # before, within 0.3 m): hysteresis, so a ROV at the beam's edge is not dropped. 0: none.
    track_prior_logit: Annotated[float, msgspec.Meta(ge=0.0, le=10.0)] = 1.0
    # What a whole-frame search refines: the proposals, or also the last ping's tracked ROV
    # (keeps a far, faint ROV the proposals rank below clutter; through the depth gate more
    # ROVs found and fewer false alarms: cnn.CnnSettings, session 68).
    search_refines: Literal["proposals", "proposals_and_track"] = "proposals_and_track"
    # After pings without a confident ROV, keep refining where it last was for this long
    # (without the prior); 0: forget it at the first miss.
    track_hold_s: Annotated[float, msgspec.Meta(ge=0.0, le=10.0)] = 0.0
    # In a whole-frame search, a proposal within 0.3 m of the last ping's confident ROV needs
    # only this much heat (a near ROV's heat sits under proposal_threshold); null: none.
    track_proposal_threshold: Annotated[float, msgspec.Meta(gt=0.0, lt=1.0)] | None = 0.03
    # refiner: its last pass also reads each crop mirrored across the boresight, the answers
    # averaged (fewer false alarms on looks not trained on); both: the proposals' heat too
    # (more time per search again); off: neither.
    mirror_average: Literal["off", "refiner", "both"] = "refiner"
    # on: candidates where the weights' near refiner takes over (in the shipped ones: nearer
    # than 1.5 m, or 2 m within 20 deg of the fan's edge) go to it (`capsd train
    # near-refiner`); off: every candidate to the main refiner. Weights without one: the main
    # refiner either way.
    near_refiner: Literal["on", "off"] = "on"
    # on: the heat of the frame's rows where the weights' close proposal network takes over (in
    # the shipped ones: nearer than 2.5 m) from it (`capsd train proposal`); off: the main
    # proposal network everywhere. Weights without one: the main one either way.
    close_proposal: Literal["on", "off"] = "on"
    # exclusive: each candidate's confidence the probability that it is the one ROV among the
    # frame's, from the network's calibrated scores (capsd.services.sonar_detect.one_rov: a
    # confident echo beside a surer one is not sent as sure); independent: each scored alone.
    # (The classical detector's scores are no probabilities: it reports them as they are.)
    confidence: Confidence = DEFAULT_CONFIDENCE
    threads: Annotated[int, msgspec.Meta(ge=1, le=64)] = 1
    # by_elevation: with the depth gate, a near ROV's range corrected for where it lies in the
    # vertical aperture and how steeply the sonar looks down at it (capsd.services.sonar_detect
    # .range_bias; the table measured on training runs by `capsd train range-bias`); off: as
    # the network says.
    range_bias: Literal["by_elevation", "off"] = "by_elevation"
    # None: the table shipped beside the weights (services/sonar_detect/weights/range_bias.json).
    range_bias_table: str | None = None

    def range_bias_correction(self) -> RangeBias | None:
        """The table to correct ranges with (None: off); a bad file is a config error.

        The shipped table was measured for the shipped weights: with other weights and no
        table of their own, none (the service says so when it starts).
        """
        if self.range_bias == "off" or (self.weights and not self.range_bias_table):
            return None
        path = Path(self.range_bias_table) if self.range_bias_table else DEFAULT_RANGE_BIAS
        try:
            return load_range_bias(path)
        except CapsdError as exc:
            raise ConfigError("config", "cnn.range_bias_table", str(exc)) from None


DetectorName = Literal["cnn", "classical"]


def confidence_of(detector: DetectorName, cnn: CnnConfig) -> Confidence:
    """How a detector's candidates are scored (its `confidence` in `detect_gated`).

    The CNN's as `cnn.confidence` says; the classical detector's as they are (its scores are no
    probabilities: a bright blob saturates near 1).
    """
    return cnn.confidence if detector == "cnn" else "independent"


class Detector(Protocol):
    def detect(
        self, frame: SonarFrame, *, range_window: tuple[float, float] | None = None
    ) -> list[Detection]: ...


class Found(NamedTuple):
    """What `detect_gated` leaves of a frame's candidates, and what it took out."""

    detections: list[Detection]  # as the locator gets them: plausible, confident
    rejected_by_depth: int  # confident candidates the depth gate ruled out
    ambiguous: int  # confident alone, not as the one ROV beside the others (one_rov)


def detect_gated(
    detector: Detector,
    frame: SonarFrame,
    gate: DepthGate | None,
    *,
    min_confidence: float,
    confidence: Confidence,
    range_bias: RangeBias | None = None,
) -> Found:
    """The frame's confident candidates as the service finds them, and what it took out.

    With a gate, proposals only at the ranges where the ROV's depth plane crosses the fan, and
    candidates that cannot lie on that plane inside the aperture rejected (depth-aware search);
    then each candidate's confidence as `confidence` says (one_rov: "exclusive", the
    probability that it is the one ROV among those the gate left); with a `range_bias` table
    too, each kept candidate's range corrected for where the gate places it in the aperture.
    """
    window = None
    if gate is not None:
        half_fov = max(abs(a) for a in frame.azimuths_rad)
        window = gate.range_window(half_fov) or (0.0, 0.0)
    found = detector.detect(frame, range_window=window)
    plausible = (
        found if gate is None else [d for d in found if gate.plausible(d.range_m, d.azimuth_rad)]
    )
    sure_alone = sum(d.confidence >= min_confidence for d in plausible)
    rejected = sum(d.confidence >= min_confidence for d in found) - sure_alone
    kept = [d for d in scored(plausible, confidence) if d.confidence >= min_confidence]
    if gate is not None and range_bias is not None:
        kept = [range_bias.corrected(d, gate) for d in kept]
    return Found(kept, rejected, sure_alone - len(kept))


class DepthGateConfig(ConfigSection, frozen=True, kw_only=True):
    """Depth-aware search: what cannot lie on the ROV's depth plane is not the ROV."""

    mode: Literal["reject", "off"] = "reject"
    asv_vehicle: str = "asv"  # publishes the ASV's pose
    rov_vehicle: str = "rov"  # publishes the ROV's depth
    # A candidate further than this from the ROV's plane is rejected. What it allows for
    # (docs/INSTALL-ERRORS.md's sigmas, three of each, added): where on the ROV's body the
    # detector puts it against the centre (up to 0.18 m, every held-out, near and close run
    # of `capsd bench detect` through the gate from the truth, session 66), the depth
    # reading's bias and drift (0.06 m before calibration, 0.03 m an hour), its port's
    # lever arm as the ROV tilts (0.03 m) and the ASV's unobserved heave and the sonar's
    # height on it (0.03 m): 0.3 m. Until session 66 0.6 m, which let clutter 0.35 m above
    # a ROV at 1.4 m through (mockup bouncing, seed 121: 90 false alarms in 303 pings).
    tolerance_m: Annotated[float, msgspec.Meta(gt=0.0, le=10.0)] = 0.3
    # Beyond the nominal vertical aperture: the beam's skirts still see an ROV there (5 deg),
    # and the sonar's pitch and roll as installed are off by up to 2 deg (0.7 deg sigma).
    aperture_margin_deg: Annotated[float, msgspec.Meta(ge=0.0, le=30.0)] = 7.0
    # Pose and depth older (or newer) than this against the ping's stamp are not used.
    max_age_s: Annotated[float, msgspec.Meta(gt=0.0, le=10.0)] = 0.5
    sonar: SonarMountConfig = SonarMountConfig()  # H_B_S, as the locator's

    def gate_at(self, sonar_in_world: Transform, rov_z_m: float) -> DepthGate:
        """The gate for a ping whose sonar pose (H_W_S) and ROV depth plane (world z) are these."""
        return DepthGate(
            sonar_in_world=sonar_in_world,
            rov_z_m=rov_z_m,
            tolerance_m=self.tolerance_m,
            half_aperture_rad=math.radians(
                self.sonar.vertical_aperture_deg / 2 + self.aperture_margin_deg
            ),
            beam_model=self.sonar.beam_model,
        )


class Config(ServiceConfig, frozen=True, kw_only=True):
    """Sonar detection configuration."""

    vehicle: str = "asv"
    sonar_vehicle: str = "asv"
    # cnn: the polar network (needs the `detect` extra, torch); classical: CFAR, no torch.
    detector: DetectorName = "cnn"
    cnn: CnnConfig = CnnConfig()
    classical: ClassicalConfig = ClassicalConfig()
    min_confidence: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)] = 0.5
    depth_gate: DepthGateConfig = DepthGateConfig()
    snapshot_every_s: Annotated[float, msgspec.Meta(gt=0.0)] | None = None
    snapshot_dir: str = "snapshots"


class Cadence:
    """The sonar's ping period from the frames' stamps; a frame older than it is stale.

    A newer frame is then already on its way: detecting the old one would only delay it (and
    hand the locator a ping whose inputs it may have let go). Applied only while the stamps
    make sense here (frames arrive less than a period after their stamp, and the period is
    a sonar's, >= 5 ms); skewed clocks or replayed stamps leave only the mailbox's rule.
    """

    MIN_PERIOD_NS = 5_000_000

    def __init__(self) -> None:
        self._last_stamp_ns: int | None = None
        self._periods_ns: deque[int] = deque(maxlen=9)
        self._arrival_ages_ns: deque[int] = deque(maxlen=9)

    def too_old(self, stamp_ns: int, *, received_ns: int, now_ns: int) -> bool:
        if self._last_stamp_ns is not None and stamp_ns > self._last_stamp_ns:
            self._periods_ns.append(stamp_ns - self._last_stamp_ns)
        self._last_stamp_ns = stamp_ns
        self._arrival_ages_ns.append(received_ns - stamp_ns)
        if len(self._periods_ns) < 3:
            return False
        # Medians: a dropped frame makes one gap look long, one slow frame one age.
        period = sorted(self._periods_ns)[len(self._periods_ns) // 2]
        typical_age = sorted(self._arrival_ages_ns)[len(self._arrival_ages_ns) // 2]
        if period < self.MIN_PERIOD_NS or not 0 <= typical_age <= period:
            return False
        return now_ns - stamp_ns > period


def make_detector(config: Config) -> Detector:
    """The configured detector, its weights loaded: a bad weights file is a config error."""
    if config.detector == "classical":
        return ClassicalDetector(config.classical.settings())
    try:
        from capsd.services.sonar_detect.cnn import DEFAULT_WEIGHTS, CnnDetector, CnnSettings
    except ImportError as exc:
        raise ConfigError(
            "config", "detector", f"'cnn' needs torch (install capsd[detect]): {exc}"
        ) from None
    c = config.cnn
    weights = Path(c.weights) if c.weights is not None else DEFAULT_WEIGHTS
    settings = CnnSettings(
        weights=weights,
        proposal_threshold=c.proposal_threshold,
        gated_proposal_threshold=c.gated_proposal_threshold,
        max_candidates=c.max_candidates,
        refine_passes=c.refine_passes,
        threads=c.threads,
        search_every_s=c.search_every_s,
        track_prior_logit=c.track_prior_logit,
        search_refines=c.search_refines,
        track_hold_s=c.track_hold_s,
        track_proposal_threshold=c.track_proposal_threshold,
        mirror_average=c.mirror_average,
        near_refiner=c.near_refiner,
        close_proposal=c.close_proposal,
        track_confidence=config.min_confidence,
    )
    try:
        return CnnDetector(settings)
    except CapsdError as exc:
        raise ConfigError("config", "cnn.weights", str(exc)) from None


class GateInputs:
    """The newest ASV pose, ROV depth and sonar tilt (Zenoh's thread writes, the worker reads)."""

    def __init__(self, config: DepthGateConfig):
        self.config = config
        self._mount = config.sonar.transform()
        self.pose: AsvPose | None = None
        self.depth: RovDepth | None = None
        self._tilt: SonarTilt | None = None  # the servos' newest report
        # ... and where they are then, slewing to the angles reported (capsd.servo_motion).
        self._motion = ServoMotion(config.sonar)
        self.servos: ServoState | None = None

    @property
    def tilt(self) -> SonarTilt | None:
        """The sonar's servos' newest report (a mount with a tilt servo)."""
        return self._tilt

    @tilt.setter
    def tilt(self, report: SonarTilt | None) -> None:
        if report is None:
            self._tilt, self.servos = None, None
            return
        pan = report.pan_rad if self.config.sonar.pan is not None else 0.0
        state = self._motion.report(self.servos, report.stamp_ns, report.tilt_rad, pan)
        self._tilt, self.servos = report, state

    def gate(self, stamp_ns: int) -> DepthGate | None:
        """The gate for a ping, or None when off or without fresh inputs."""
        c = self.config
        pose, depth = self.pose, self.depth
        if c.mode == "off" or pose is None or depth is None or pose.status == "lost":
            return None
        limit_ns = c.max_age_s * 1e9
        if abs(stamp_ns - pose.stamp_ns) > limit_ns or abs(stamp_ns - depth.stamp_ns) > limit_ns:
            return None
        mount = self._mount
        if c.sonar.tilt is not None:
            # On a servo, no gate without its angle: a guessed elevation would reject the ROV.
            servos = self.servos
            if servos is None or abs(stamp_ns - servos.stamp_ns) > c.sonar.tilt.max_age_s * 1e9:
                return None
            # Where the servos are at the ping, slewing towards the angles reported.
            at = self._motion.at(servos, max(stamp_ns, servos.stamp_ns))
            mount = c.sonar.transform(tilt_rad=at.tilt_rad, pan_rad=at.pan_rad)
        asv = Transform(quat_to_matrix(np.array(pose.orientation_xyzw)), np.array(pose.position_m))
        return c.gate_at(asv.compose(mount), -depth.depth_m)


def main(config: Config) -> int:
    """Run the detector until stopped."""
    detector = make_detector(config)
    range_bias = config.cnn.range_bias_correction() if config.detector == "cnn" else None
    confidence = confidence_of(config.detector, config.cnn)
    if config.detector == "cnn" and config.cnn.range_bias != "off" and range_bias is None:
        logger.warning(
            "cnn.range_bias: off, the shipped table is for the shipped weights "
            "(measure one for cnn.weights with capsd train range-bias, set cnn.range_bias_table)"
        )
    mailbox: Mailbox[tuple[SonarFrame, int]] = Mailbox()
    counts = {
        "frames": 0,
        "detections": 0,
        "snapshots": 0,
        "errors": 0,
        "dropped_older_than_period": 0,
        # Depth-aware search: frames it applied to, and candidates it rejected.
        "depth_gated_frames": 0,
        "rejected_by_depth": 0,
        # Confident alone, not as the one ROV beside the frame's others (config.confidence).
        "ambiguous_candidates": 0,
    }
    inputs = GateInputs(config.depth_gate)
    cadence = Cadence()
    with ServiceRunner("sonar_detect", config) as runner:
        out: Publisher[SonarDetections] = runner.publisher(topics.SONAR_DETECTIONS)
        runner.add_counters(lambda: {**counts, "dropped_stale_frames": mailbox.dropped})
        # Frame age when its detection starts (ping to now): the "never a stale frame" check.
        age_at_start = runner.latency("frame age at detection start")
        # Frame arrival to detections put: decoding, waiting for the worker, detecting, encoding.
        stage = runner.latency("detection")
        inference = runner.latency("detector compute")  # the detector and its depth gate
        runner.subscribe(
            topics.SONAR_FRAME,
            lambda frame: mailbox.put((frame, runner.received_ns())),
            vehicle=config.sonar_vehicle,
        )
        if config.depth_gate.mode != "off":
            runner.subscribe(
                topics.ASV_POSE,
                lambda pose: setattr(inputs, "pose", pose),
                vehicle=config.depth_gate.asv_vehicle,
            )
            runner.subscribe(
                topics.ROV_DEPTH,
                lambda depth: setattr(inputs, "depth", depth),
                vehicle=config.depth_gate.rov_vehicle,
            )
            if config.depth_gate.sonar.tilt is not None:
                runner.subscribe(
                    topics.SONAR_TILT,
                    lambda tilt: setattr(inputs, "tilt", tilt),
                    vehicle=config.depth_gate.asv_vehicle,
                )
        next_snapshot = time.monotonic()

        def work() -> None:
            nonlocal next_snapshot
            while not runner.stop_event.is_set():
                item = mailbox.take(0.1)
                if item is None:
                    continue
                frame, received_ns = item
                now_ns = time.time_ns()
                age_ns = now_ns - frame.stamp_ns
                if cadence.too_old(frame.stamp_ns, received_ns=received_ns, now_ns=now_ns):
                    counts["dropped_older_than_period"] += 1
                    continue
                age_at_start.record_ns(age_ns)
                try:
                    gate = inputs.gate(frame.stamp_ns)
                    started_ns = time.time_ns()
                    found, rejected, ambiguous = detect_gated(
                        detector, frame, gate, min_confidence=config.min_confidence,
                        confidence=confidence, range_bias=range_bias,
                    )  # fmt: skip
                    counts["ambiguous_candidates"] += ambiguous
                    inference.record_ns(time.time_ns() - started_ns)
                    if gate is not None:
                        counts["depth_gated_frames"] += 1
                        counts["rejected_by_depth"] += rejected
                    out.put(
                        SonarDetections(
                            stamp_ns=frame.stamp_ns,
                            seq=out.next_seq(),
                            ping_id=frame.ping_id,
                            detector=config.detector,
                            detections=tuple(found),
                            sound_speed_m_s=frame.sound_speed_m_s,
                        )
                    )
                    stage.record_ns(time.time_ns() - received_ns)
                    counts["frames"] += 1
                    counts["detections"] += len(found)
                    if config.snapshot_every_s is not None and time.monotonic() >= next_snapshot:
                        next_snapshot = time.monotonic() + config.snapshot_every_s
                        _snapshot(config, frame, found)
                        counts["snapshots"] += 1
                except Exception as exc:
                    counts["errors"] += 1
                    runner.report_error(f"detection failed on ping {frame.ping_id}: {exc}")

        worker = threading.Thread(target=work, name="sonar-detect", daemon=True)
        worker.start()
        try:
            runner.run()
        finally:
            runner.stop_event.set()
            worker.join(timeout=2.0)
    return 0


def _snapshot(config: Config, frame: SonarFrame, found: list[Detection]) -> None:
    from capsd.fan import draw_fan

    detections = SonarDetections(
        stamp_ns=frame.stamp_ns,
        seq=0,
        ping_id=frame.ping_id,
        detector=config.detector,
        detections=tuple(found),
    )
    draw_fan(frame, None, detections, Path(config.snapshot_dir) / f"fan_{frame.ping_id:08d}.png")
