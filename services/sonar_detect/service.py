"""The sonar detection service: frames in, ROV candidates out, newest frame first.

Frames arrive on Zenoh's callback thread and go into a one-slot mailbox; a worker thread takes
the newest frame, detects, and publishes SonarDetections stamped with the frame's `stamp_ns`
and `ping_id`. A frame replaced in the mailbox before the worker took it is dropped and counted:
a stale frame is never processed. Every `snapshot_every_s` a fan PNG with the detections is
written for people.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Literal

import msgspec

from capsd import topics
from capsd.config import ConfigSection, ServiceConfig
from capsd.errors import CapsdError, ConfigError
from capsd.payloads import Detection, SonarDetections, SonarFrame
from capsd.runner import Publisher, ServiceRunner
from services.sonar_detect.classical import ClassicalDetector, ClassicalSettings

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
    max_candidates: Annotated[int, msgspec.Meta(ge=1, le=20)] = 3
    refine_passes: Annotated[int, msgspec.Meta(ge=1, le=5)] = 2
    # Ping time between whole-frame searches; between them only the last ping's confident
    # detections are refined (a quarter of the work at 40 Hz). 0: search every frame.
    search_every_s: Annotated[float, msgspec.Meta(ge=0.0, le=10.0)] = 0.1
    # Added to the logit of a candidate that continues a detection of the last ping (<= 0.2 s
    # before, within 0.3 m): hysteresis, so a ROV at the beam's edge is not dropped. 0: none.
    track_prior_logit: Annotated[float, msgspec.Meta(ge=0.0, le=10.0)] = 2.0
    threads: Annotated[int, msgspec.Meta(ge=1, le=64)] = 1


Detect = Callable[[SonarFrame], list[Detection]]


class Config(ServiceConfig, frozen=True, kw_only=True):
    """Sonar detection configuration."""

    vehicle: str = "asv"
    sonar_vehicle: str = "asv"
    # cnn: the polar network (needs the `detect` extra, torch); classical: CFAR, no torch.
    detector: Literal["cnn", "classical"] = "cnn"
    cnn: CnnConfig = CnnConfig()
    classical: ClassicalConfig = ClassicalConfig()
    min_confidence: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)] = 0.5
    snapshot_every_s: Annotated[float, msgspec.Meta(gt=0.0)] | None = None
    snapshot_dir: str = "snapshots"


class Mailbox:
    """One slot: `put` replaces what was there (counted as dropped); `take` waits for news.

    Each frame is held with its arrival time (wall clock ns), for the latency figures.
    """

    def __init__(self) -> None:
        self._item: tuple[SonarFrame, int] | None = None
        self._cond = threading.Condition()
        self.dropped = 0

    def put(self, frame: SonarFrame, received_ns: int) -> None:
        with self._cond:
            if self._item is not None:
                self.dropped += 1
            self._item = (frame, received_ns)
            self._cond.notify()

    def take(self, timeout_s: float) -> tuple[SonarFrame, int] | None:
        with self._cond:
            if self._item is None:
                self._cond.wait(timeout_s)
            item, self._item = self._item, None
            return item


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


def make_detector(config: Config) -> Detect:
    """The configured detector, its weights loaded: a bad weights file is a config error."""
    if config.detector == "classical":
        return ClassicalDetector(config.classical.settings()).detect
    try:
        from services.sonar_detect.cnn import DEFAULT_WEIGHTS, CnnDetector, CnnSettings
    except ImportError as exc:
        raise ConfigError(
            "config", "detector", f"'cnn' needs torch (install capsd[detect]): {exc}"
        ) from None
    c = config.cnn
    weights = Path(c.weights) if c.weights is not None else DEFAULT_WEIGHTS
    settings = CnnSettings(
        weights=weights,
        proposal_threshold=c.proposal_threshold,
        max_candidates=c.max_candidates,
        refine_passes=c.refine_passes,
        threads=c.threads,
        search_every_s=c.search_every_s,
        track_prior_logit=c.track_prior_logit,
        track_confidence=config.min_confidence,
    )
    try:
        return CnnDetector(settings).detect
    except CapsdError as exc:
        raise ConfigError("config", "cnn.weights", str(exc)) from None


def main(config: Config) -> int:
    """Run the detector until stopped."""
    detect = make_detector(config)
    mailbox = Mailbox()
    counts = {
        "frames": 0,
        "detections": 0,
        "snapshots": 0,
        "errors": 0,
        "dropped_older_than_period": 0,
    }
    cadence = Cadence()
    with ServiceRunner("sonar_detect", config) as runner:
        out: Publisher[SonarDetections] = runner.publisher(topics.SONAR_DETECTIONS)
        runner.add_counters(lambda: {**counts, "dropped_stale_frames": mailbox.dropped})
        # Frame age when its detection starts (ping to now): the "never a stale frame" check.
        age_at_start = runner.latency("frame age at detection start")
        # Frame arrival to detections put: decoding, waiting for the worker, detecting, encoding.
        stage = runner.latency("detection")
        inference = runner.latency("detector compute")  # the detect() call alone
        runner.subscribe(
            topics.SONAR_FRAME,
            lambda frame: mailbox.put(frame, runner.received_ns()),
            vehicle=config.sonar_vehicle,
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
                    started_ns = time.time_ns()
                    candidates = detect(frame)
                    inference.record_ns(time.time_ns() - started_ns)
                    found = [d for d in candidates if d.confidence >= config.min_confidence]
                    out.put(
                        SonarDetections(
                            stamp_ns=frame.stamp_ns,
                            seq=out.next_seq(),
                            ping_id=frame.ping_id,
                            detector=config.detector,
                            detections=tuple(found),
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
    from services.sonar_detect.fan import draw_fan

    detections = SonarDetections(
        stamp_ns=frame.stamp_ns,
        seq=0,
        ping_id=frame.ping_id,
        detector=config.detector,
        detections=tuple(found),
    )
    draw_fan(frame, None, detections, Path(config.snapshot_dir) / f"fan_{frame.ping_id:08d}.png")
