"""`capsd label`: labelled sonar frames from a recording's confident tracked fixes.

After a first dive, the recording holds the sonar frames, the ASV's poses and the locator's
fixes. A fix that is "good" and whose track was already established says where the ROV's
centre was at that ping; projected back through the ASV's pose and the sonar's mount into the
sonar's polar coordinates it labels the frame. The labels go into a folder:
- `labels.msgpack`: each labelled ping (the frame's bytes as recorded, range, azimuth, the
  fix's horizontal sigma);
- `sheet_NNN.png`: contact sheets of the labelled crops (the normalised image the network
  sees, the label at the centre), numbered, for a person to check;
- `rejected.txt`: the numbers a person rejects, one per line (written empty; `capsd train
  detector --finetune` leaves them out).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import msgspec
import numpy as np

from capsd.codec import Codec
from capsd.errors import CapsdError
from capsd.keys import Subject, subject_of
from capsd.mounts import SonarMountConfig
from capsd.payloads import AsvPose, RovFix, SonarFrame
from capsd.pose_lookup import PoseLookup
from capsd.recording import read
from capsd.sonar_geometry import to_polar

LABELS_FILE = "labels.msgpack"
REJECTED_FILE = "rejected.txt"
SHEET_COLUMNS = 8
SHEET_ROWS = 6


class LabelledPing(msgspec.Struct, frozen=True, kw_only=True):
    """One frame and where the ROV's centre was in it (sonar frame S, polar)."""

    frame: bytes  # the SonarFrame payload as recorded (msgpack)
    range_m: float
    azimuth_rad: float
    sigma_m: float  # the fix's largest horizontal standard deviation


@dataclass(frozen=True)
class LabelSummary:
    frames: int
    fixes: int
    confident: int
    labelled: int
    outside_fan: int
    unreadable: int


def label_recording(
    recording: Path, *, sonar: SonarMountConfig, max_sigma_m: float = 0.05
) -> tuple[list[LabelledPing], LabelSummary]:
    """The labelled pings of a recording (confident, tracked fixes only)."""
    frames: dict[int, bytes] = {}
    fixes: list[RovFix] = []
    poses: list[AsvPose] = []
    unreadable = 0
    fix_codec, pose_codec, frame_codec = Codec(RovFix), Codec(AsvPose), Codec(SonarFrame)
    for message in read(recording):
        subject = subject_of(message.key)
        try:
            if subject == Subject.SONAR_FRAME.value:
                frame = frame_codec.decode(
                    message.data, encoding=message.encoding, key_expr=message.key
                )
                frames[frame.stamp_ns] = message.data
            elif subject == Subject.ROV_FIX.value:
                fixes.append(
                    fix_codec.decode(message.data, encoding=message.encoding, key_expr=message.key)
                )
            elif subject == Subject.ASV_POSE.value:
                poses.append(
                    pose_codec.decode(message.data, encoding=message.encoding, key_expr=message.key)
                )
        except CapsdError:
            unreadable += 1  # reported in the summary; the rest is still labelled
    if not frames:
        raise CapsdError(f"{recording}: no sonar frames in it (record cap/** with the frames)")
    lookup = PoseLookup(poses)
    mount = sonar.transform()
    labelled: list[LabelledPing] = []
    confident = outside = 0
    for fix in fixes:
        if fix.quality != "good" or fix.track_state != "tracking" or fix.position_m is None:
            continue
        cov = np.array(fix.covariance_m2 or fix.raw_covariance_m2 or (1.0,) * 9).reshape(3, 3)
        sigma = math.sqrt(max(float(np.linalg.eigvalsh(cov[:2, :2])[-1]), 0.0))
        if sigma > max_sigma_m or fix.stamp_ns not in frames:
            continue
        asv = lookup.at(fix.stamp_ns)
        if asv is None:
            continue
        confident += 1
        p_s = asv.compose(mount).inverse().apply(np.array(fix.position_m))
        r, azimuth, elevation = to_polar(sonar.beam_model, p_s)
        frame = frame_codec.decode(frames[fix.stamp_ns], encoding=None, key_expr=str(recording))
        half_fov = max(abs(a) for a in frame.azimuths_rad)
        half_aperture = frame.vertical_aperture_rad / 2
        reach = frame.range_start_m + frame.n_ranges * frame.range_resolution_m
        if abs(azimuth) > half_fov or abs(elevation) > 1.3 * half_aperture or r >= reach:
            outside += 1
            continue
        labelled.append(
            LabelledPing(frame=frames[fix.stamp_ns], range_m=r, azimuth_rad=azimuth, sigma_m=sigma)
        )
    return labelled, LabelSummary(
        len(frames), len(fixes), confident, len(labelled), outside, unreadable
    )


def write_labels(labels: list[LabelledPing], out: Path) -> list[Path]:
    """labels.msgpack, an empty rejected.txt (kept if there) and the contact sheets."""
    out.mkdir(parents=True, exist_ok=True)
    (out / LABELS_FILE).write_bytes(msgspec.msgpack.encode(labels))
    rejected = out / REJECTED_FILE
    if not rejected.exists():
        rejected.write_text("# numbers of the crops to leave out of fine-tuning, one per line\n")
    return contact_sheets(labels, out)


def read_labels(folder: Path) -> list[LabelledPing]:
    """The labelled pings a person kept (those in rejected.txt left out)."""
    path = folder / LABELS_FILE
    try:
        labels = msgspec.msgpack.decode(path.read_bytes(), type=list[LabelledPing])
    except FileNotFoundError:
        raise CapsdError(f"{path}: no labels (make them with `capsd label`)") from None
    except msgspec.DecodeError as exc:
        raise CapsdError(f"{path}: not a labels file ({exc})") from None
    rejected: set[int] = set()
    reject_path = folder / REJECTED_FILE
    if reject_path.exists():
        for n, line in enumerate(reject_path.read_text().splitlines(), 1):
            text = line.split("#", 1)[0].strip()
            if not text:
                continue
            if not text.isdigit() or int(text) >= len(labels):
                raise CapsdError(f"{reject_path}:{n}: {text!r} is not a crop number")
            rejected.add(int(text))
    return [label for k, label in enumerate(labels) if k not in rejected]


def frames_of(labels: Iterable[LabelledPing]) -> Iterable[tuple[SonarFrame, LabelledPing]]:
    codec = Codec(SonarFrame)
    for label in labels:
        yield codec.decode(label.frame, encoding=None, key_expr=LABELS_FILE), label


def contact_sheets(labels: list[LabelledPing], out: Path) -> list[Path]:
    """PNG pages of numbered crops, each centred on its label (a cross marks the centre)."""
    import matplotlib.pyplot as plt

    from capsd.plots import save_sheet, show_crop  # matplotlib's Agg backend chosen there
    from capsd.services.sonar_detect.polar_input import BeamTable, crop, normalised_image

    per_sheet = SHEET_COLUMNS * SHEET_ROWS
    paths = []
    items = list(frames_of(labels))
    for first in range(0, len(items), per_sheet):
        fig, axes = plt.subplots(
            SHEET_ROWS, SHEET_COLUMNS, figsize=(2 * SHEET_COLUMNS, 2.2 * SHEET_ROWS)
        )
        for k, ax in enumerate(np.ravel(axes)):
            ax.axis("off")
            if first + k >= len(items):
                continue
            frame, label = items[first + k]
            patch = crop(
                normalised_image(frame),
                frame,
                BeamTable(frame.azimuths_rad),
                range_m=label.range_m,
                azimuth_rad=label.azimuth_rad,
            )
            show_crop(ax, patch, title=f"{first + k}: {label.range_m:.1f} m", colour="red",
                      fontsize=8)  # fmt: skip
        fig.suptitle(
            f"labelled crops {first}-{min(first + per_sheet, len(items)) - 1} "
            "(1.9 m square; range up, cross-range right); reject by number in rejected.txt"
        )
        paths.append(save_sheet(fig, out / f"sheet_{first // per_sheet:03d}.png"))
    return paths
