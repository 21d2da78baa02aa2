"""The locator without a bus: feed a time-ordered stream of payloads, get fixes (and truth)."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass

from capsd.payloads import (
    AsvPose,
    GroundTruth,
    Payload,
    RovAttitude,
    RovDepth,
    RovFix,
    RovVelocity,
    SonarDetections,
)
from services.locator.service import Config, Locator


@dataclass(frozen=True)
class Scored:
    """A fix and the ground truth of the same ping (None when the stream has no truth)."""

    fix: RovFix
    truth: GroundTruth | None


def run_offline(config: Config, payloads: Iterable[Payload]) -> Iterator[Scored]:
    """Run one Locator over `payloads` in the given order; pair each fix with its truth.

    The simulator emits a ping's truth right after its detections, with the same stamp.
    """
    locator = Locator(config)
    seq = 0
    waiting: RovFix | None = None
    for payload in payloads:
        if isinstance(payload, AsvPose):
            locator.on_pose(payload)
        elif isinstance(payload, RovDepth):
            locator.on_depth(payload)
        elif isinstance(payload, RovAttitude):
            locator.on_attitude(payload)
        elif isinstance(payload, RovVelocity):
            locator.on_velocity(payload)
        elif isinstance(payload, SonarDetections):
            if waiting is not None:
                yield Scored(waiting, None)
            waiting = locator.locate(payload, seq=seq)
            seq += 1
        elif isinstance(payload, GroundTruth) and waiting is not None:
            yield Scored(waiting, payload if payload.stamp_ns == waiting.stamp_ns else None)
            waiting = None
    if waiting is not None:
        yield Scored(waiting, None)
