"""The locator without a bus: feed a time-ordered stream of payloads, get fixes (and truth)."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass

from capsd.payloads import (
    AsvPose,
    Payload,
    RovAttitude,
    RovDepth,
    RovFix,
    RovVelocity,
    SonarDetections,
    SonarLabel,
    SonarTilt,
)
from capsd.services.locator.service import Config, Locator


@dataclass(frozen=True)
class Scored:
    """A fix and the simulator's label of the same ping (None when the stream has none)."""

    fix: RovFix
    label: SonarLabel | None

    @property
    def truth_position_m(self) -> tuple[float, float, float] | None:
        return None if self.label is None else self.label.rov_position_m


def run_offline(config: Config, payloads: Iterable[Payload]) -> Iterator[Scored]:
    """Run one Locator over `payloads` in the given order; pair each fix with its label.

    The simulator emits a ping's label with the frame's stamp and ping id, so the pairing holds
    whatever the vehicles' clock offsets.
    """
    locator = Locator(config)
    seq = 0
    labels: dict[int, SonarLabel] = {}
    fixes: list[RovFix] = []
    for payload in payloads:
        if isinstance(payload, AsvPose):
            locator.on_pose(payload)
        elif isinstance(payload, RovDepth):
            locator.on_depth(payload)
        elif isinstance(payload, RovAttitude):
            locator.on_attitude(payload)
        elif isinstance(payload, RovVelocity):
            locator.on_velocity(payload)
        elif isinstance(payload, SonarTilt):
            locator.on_tilt(payload)
        elif isinstance(payload, SonarDetections):
            fixes.append(locator.locate(payload, seq=seq))
            seq += 1
        elif isinstance(payload, SonarLabel):
            labels[payload.stamp_ns] = payload
        while fixes and (fixes[0].stamp_ns in labels or len(fixes) > 1):
            fix = fixes.pop(0)
            yield Scored(fix, labels.pop(fix.stamp_ns, None))
    for fix in fixes:
        yield Scored(fix, labels.pop(fix.stamp_ns, None))
