"""Topics: each data subject bound to the one payload type it carries."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from capsd import payloads as pl
from capsd.keys import Subject, data_key

P = TypeVar("P", bound=pl.Payload)


@dataclass(frozen=True)
class Topic(Generic[P]):
    """A subject and its payload type; `key()` places it in a site/vehicle namespace."""

    subject: Subject
    payload: type[P]

    def key(self, site: str, vehicle: str) -> str:
        return data_key(site, vehicle, self.subject)


ASV_POSE = Topic(Subject.ASV_POSE, pl.AsvPose)
ASV_POSE_EXTERNAL = Topic(Subject.ASV_POSE_EXTERNAL, pl.AsvPose)
ASV_IMU = Topic(Subject.ASV_IMU, pl.ImuSample)
ASV_SCAN = Topic(Subject.ASV_SCAN, pl.LidarScan)
SONAR_FRAME = Topic(Subject.SONAR_FRAME, pl.SonarFrame)
SONAR_DETECTIONS = Topic(Subject.SONAR_DETECTIONS, pl.SonarDetections)
ROV_DEPTH = Topic(Subject.ROV_DEPTH, pl.RovDepth)
ROV_ATTITUDE = Topic(Subject.ROV_ATTITUDE, pl.RovAttitude)
ROV_VELOCITY = Topic(Subject.ROV_VELOCITY, pl.RovVelocity)
ROV_STATUS = Topic(Subject.ROV_STATUS, pl.RovStatus)
ROV_FIX = Topic(Subject.ROV_FIX, pl.RovFix)
SIM_TRUTH = Topic(Subject.SIM_TRUTH, pl.GroundTruth)
SIM_LABEL = Topic(Subject.SIM_LABEL, pl.SonarLabel)
SIM_CONTROL = Topic(Subject.SIM_CONTROL, pl.SimControl)

ALL_TOPICS: tuple[Topic[Any], ...] = (
    ASV_POSE, ASV_POSE_EXTERNAL, ASV_IMU, ASV_SCAN, SONAR_FRAME, SONAR_DETECTIONS,
    ROV_DEPTH, ROV_ATTITUDE, ROV_VELOCITY, ROV_STATUS, ROV_FIX, SIM_TRUTH, SIM_LABEL,
    SIM_CONTROL,
)  # fmt: skip
