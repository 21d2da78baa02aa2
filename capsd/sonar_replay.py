"""A sonar replay source: recorded frames onto the bus as if a sonar were pinging now.

Two recordings are read:
- `oculus`: raw Oculus protocol bytes as captured off the wire (the fixtures in
  tests/fixtures/oculus are such files); parsed with the driver's stream parser (broken
  messages are counted and skipped, as live) and played at `ping_rate_hz`;
- `dataset`: a simulator dataset directory (capsd.simulator.dataset); its sonar frames are played
  with their recorded spacing divided by `speed`.
Each frame is re-stamped to the moment it is published (`stamps: now`, for a live pipeline) or
keeps its recorded stamp (`stamps: original`). The file is checked before the first frame: a
missing or unreadable recording is a config error (exit 2), never a silent idle service.
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated, Literal

import msgspec

from capsd import topics
from capsd.config import ServiceConfig
from capsd.errors import CapsdError, ConfigError
from capsd.payloads import SonarFrame
from capsd.protocols.oculus import PingStream, ProtocolError
from capsd.runner import ServiceRunner
from capsd.services.sonar_detect.driver import Config as DriverConfig
from capsd.services.sonar_detect.driver import to_frame

logger = logging.getLogger(__name__)
CHUNK_BYTES = 1 << 16


class Config(ServiceConfig, frozen=True, kw_only=True):
    """Sonar replay configuration."""

    vehicle: str = "asv"
    path: str = ""
    format: Literal["oculus", "dataset"] = "oculus"
    ping_rate_hz: Annotated[float, msgspec.Meta(gt=0.0, le=100.0)] = 10.0  # oculus files
    speed: Annotated[float, msgspec.Meta(gt=0.0, le=100.0)] = 1.0  # datasets
    repeat: Literal["once", "loop"] = "loop"
    stamps: Literal["now", "original"] = "now"
    mount: Literal["upright", "inverted"] = "upright"  # oculus files, as the driver's
    vertical_aperture_deg: Annotated[float, msgspec.Meta(gt=0.0, le=90.0)] = 20.0


def recorded_frames(config: Config, counts: Counter[str]) -> Iterator[tuple[float, SonarFrame]]:
    """(seconds after the first frame, frame) for one pass over the recording."""
    path = Path(config.path)
    if config.format == "dataset":
        from capsd.simulator.dataset import read

        first_ns: int | None = None
        for record in read(path):
            if isinstance(record.payload, SonarFrame):
                frame = record.payload
                first_ns = frame.stamp_ns if first_ns is None else first_ns
                yield (frame.stamp_ns - first_ns) / 1e9 / config.speed, frame
        return
    driver = DriverConfig(mount=config.mount, vertical_aperture_deg=config.vertical_aperture_deg)
    stream = PingStream()
    k = 0
    with path.open("rb") as data:
        while chunk := data.read(CHUNK_BYTES):
            for item in stream.feed(chunk):
                if isinstance(item, ProtocolError):
                    counts["protocol_errors"] += 1
                    logger.warning("%s: %s (resynchronising)", path, item)
                    continue
                yield k / config.ping_rate_hz, to_frame(item, config=driver, stamp_ns=0, seq=0)
                k += 1


def check(config: Config) -> None:
    """Fail before the first message: the recording must exist and hold at least one frame."""
    if not config.path:
        raise ConfigError("config", "path", "a recording is required")
    path = Path(config.path)
    if not path.exists():
        raise ConfigError("config", "path", f"{path}: no such file or directory")
    try:
        next(recorded_frames(config, Counter()))
    except StopIteration:
        raise ConfigError("config", "path", f"{path}: no sonar frame in it") from None
    except (CapsdError, OSError) as exc:
        raise ConfigError("config", "path", f"{path}: {exc}") from None


def main(config: Config) -> int:
    """Replay until the recording ends (`once`) or until stopped (`loop`)."""
    check(config)
    counts: Counter[str] = Counter()
    with ServiceRunner("sonar_replay", config) as runner:
        out = runner.publisher(topics.SONAR_FRAME)
        runner.add_counters(lambda: dict(counts))
        stop = runner.stop_event
        while not stop.is_set():
            start = time.monotonic()
            try:
                for offset_s, frame in recorded_frames(config, counts):
                    if stop.wait(max(0.0, start + offset_s - time.monotonic())):
                        break
                    stamp = time.time_ns() if config.stamps == "now" else frame.stamp_ns
                    out.put(msgspec.structs.replace(frame, stamp_ns=stamp, seq=out.next_seq()))
                    counts["frames"] += 1
            except (CapsdError, OSError) as exc:
                counts["read_errors"] += 1
                runner.report_error(f"replay of {config.path} stopped: {exc}")
            counts["passes"] += 1
            if config.repeat == "once":
                break
            stop.wait(0.1)
    return 0
