"""`capsd calibrate RECORDING`: the sonar mount from a recording of the calibration manoeuvre.

The recording holds the sonar frames and the ASV's poses (`capsd record 'cap/**'` with the
services running) while the ASV turns on the spot near the tank's middle, a turn or two in
about two minutes, walls in the sonar's range. The fit (capsd.mount_calibration) gives the
sonar's heading, roll and horizontal position against the ASV's LiDAR-derived frame, each with
its uncertainty; only what the data determined is written into the new locator config.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from capsd.codec import Codec
from capsd.errors import CapsdError
from capsd.keys import Subject, subject_of
from capsd.mount_calibration import MountFit, Observation, corrected, fit_mount
from capsd.mounts import SonarMountConfig
from capsd.payloads import AsvPose, SonarFrame
from capsd.pose_lookup import PoseLookup
from capsd.recording import read
from capsd.tank import TankBounds

EVERY_S = 0.5  # one frame per half second is plenty: neighbouring frames see the same walls


def observations_of(recording: Path, *, every_s: float = EVERY_S) -> list[Observation]:
    """Frames of `recording` every `every_s`, each with the ASV pose at its stamp."""
    frames: list[tuple[int, bytes, str]] = []
    poses: list[AsvPose] = []
    pose_codec, frame_codec = Codec(AsvPose), Codec(SonarFrame)
    for message in read(recording):
        subject = subject_of(message.key)
        if subject == Subject.SONAR_FRAME.value:
            frames.append((message.log_time_ns, message.data, message.key))
        elif subject == Subject.ASV_POSE.value:
            try:
                poses.append(
                    pose_codec.decode(message.data, encoding=message.encoding, key_expr=message.key)
                )
            except CapsdError:
                continue  # counted by nobody here: the pose stream has its own health
    if not frames:
        raise CapsdError(f"{recording}: no sonar frames in it (record cap/** with the frames)")
    if not poses:
        raise CapsdError(f"{recording}: no ASV poses in it (asv_pose must run while recording)")
    lookup = PoseLookup(poses)
    out: list[Observation] = []
    next_ns = 0
    for _, data, key in sorted(frames, key=lambda f: f[0]):
        try:
            frame = frame_codec.decode(data, encoding=None, key_expr=key)
        except CapsdError:
            continue
        if frame.stamp_ns < next_ns:
            continue
        asv = lookup.at(frame.stamp_ns)
        if asv is not None:
            out.append(Observation(frame, asv))
            next_ns = frame.stamp_ns + int(every_s * 1e9)
    return out


def calibrate(
    recording: Path, *, mount: SonarMountConfig, tank: TankBounds
) -> tuple[MountFit, SonarMountConfig]:
    """The fit and the mount with what it determined applied."""
    fit = fit_mount(observations_of(recording), mount=mount, tank=tank)
    return fit, corrected(mount, fit)


def write_config(
    source: Path, out: Path, mount: SonarMountConfig, fit: MountFit, recording: Path
) -> None:
    """A copy of the locator config `source` with the calibrated sonar mount, and its provenance."""
    data: dict[str, Any] = yaml.safe_load(source.read_text()) or {}
    sonar = dict(data.get("sonar") or {})
    sonar.update(
        position_m=list(mount.position_m),
        yaw_deg=mount.yaw_deg,
        pitch_deg=mount.pitch_deg,
        roll_deg=mount.roll_deg,
    )
    data["sonar"] = sonar
    header = [
        f"# {source.name} with the sonar mount calibrated by `capsd calibrate {recording.name}`:",
        *(f"#   {line}" for line in fit.lines()),
    ]
    out.write_text("\n".join(header) + "\n" + yaml.safe_dump(data, sort_keys=False))
