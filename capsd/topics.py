"""Topics: each data subject bound to the one payload type it carries."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from capsd import payloads as pl
from capsd.keys import Subject, data_key

P = TypeVar("P", bound=pl.Payload)


# Every payload but a sonar frame is small (a LiDAR scan of 1000 points is ~30 kB of JSON).
MAX_PAYLOAD_BYTES = 256 * 1024
# A sonar frame: at most 512 beams x 1500 bins x 2 bytes, its bearing table and header.
MAX_FRAME_BYTES = 512 * 1500 * 2 + 64 * 1024


@dataclass(frozen=True)
class Topic(Generic[P]):
    """A subject and its payload type; `key()` places it in a site/vehicle namespace.

    `max_bytes` bounds an encoded payload: a larger one is refused before it is copied or
    decoded.
    """

    subject: Subject
    payload: type[P]
    max_bytes: int = MAX_PAYLOAD_BYTES

    def key(self, site: str, vehicle: str) -> str:
        return data_key(site, vehicle, self.subject)


ASV_POSE = Topic(Subject.ASV_POSE, pl.AsvPose)
ASV_POSE_EXTERNAL = Topic(Subject.ASV_POSE_EXTERNAL, pl.AsvPose)
ASV_IMU = Topic(Subject.ASV_IMU, pl.ImuSample)
ASV_SCAN = Topic(Subject.ASV_SCAN, pl.LidarScan)
SONAR_FRAME = Topic(Subject.SONAR_FRAME, pl.SonarFrame, MAX_FRAME_BYTES)
SONAR_DETECTIONS = Topic(Subject.SONAR_DETECTIONS, pl.SonarDetections)
SONAR_TILT = Topic(Subject.SONAR_TILT, pl.SonarTilt)
ROV_DEPTH = Topic(Subject.ROV_DEPTH, pl.RovDepth)
ROV_ATTITUDE = Topic(Subject.ROV_ATTITUDE, pl.RovAttitude)
ROV_VELOCITY = Topic(Subject.ROV_VELOCITY, pl.RovVelocity)
ROV_STATUS = Topic(Subject.ROV_STATUS, pl.AutopilotStatus)
ROV_FIX = Topic(Subject.ROV_FIX, pl.RovFix)
ROV_COMMAND = Topic(Subject.ROV_COMMAND, pl.VehicleCommand)
ASV_COMMAND = Topic(Subject.ASV_COMMAND, pl.VehicleCommand)
ASV_AUTOPILOT = Topic(Subject.ASV_AUTOPILOT, pl.AutopilotStatus)
REFERENCE_POSE = Topic(Subject.REFERENCE_POSE, pl.ReferencePose)
SIM_TRUTH = Topic(Subject.SIM_TRUTH, pl.GroundTruth)
SIM_LABEL = Topic(Subject.SIM_LABEL, pl.SonarLabel)
SIM_ASV_POSE = Topic(Subject.SIM_ASV_POSE, pl.AsvPose)
SIM_DETECTIONS = Topic(Subject.SIM_DETECTIONS, pl.SonarDetections)
SIM_CONTROL = Topic(Subject.SIM_CONTROL, pl.SimControl)

ALL_TOPICS: tuple[Topic[Any], ...] = (
    ASV_POSE, ASV_POSE_EXTERNAL, ASV_IMU, ASV_SCAN, SONAR_FRAME, SONAR_DETECTIONS, SONAR_TILT,
    ROV_DEPTH, ROV_ATTITUDE, ROV_VELOCITY, ROV_STATUS, ROV_FIX, ROV_COMMAND, ASV_COMMAND,
    ASV_AUTOPILOT, REFERENCE_POSE,
    SIM_TRUTH, SIM_LABEL, SIM_ASV_POSE, SIM_DETECTIONS, SIM_CONTROL,
)  # fmt: skip
