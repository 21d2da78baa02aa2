"""Offline datasets: the simulator's stream as the exact bytes the bus would carry.

A dataset is a directory:
- `dataset.json`: {"format": "capsd-sim-dataset", "version": 1, "duration_s", "start_ns",
  "config" (the simulator config, every key), "streams": [{"index", "subject", "vehicle",
  "key", "encoding", "count"}]}, written with sorted keys;
- `events.bin`: the events in time order, each `<u16 stream index><u32 length><payload>`,
  little-endian, where the payload is the encoded wire bytes (JSON or msgpack, as on the bus).
Same config and seed give the same bytes (the stamps start at a fixed `start_ns`).
"""

from __future__ import annotations

import json
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec

from capsd.codec import Codec
from capsd.errors import CapsdError
from capsd.payloads import Payload
from capsd.progress import Progress
from capsd.simulator.config import OFFLINE_START_NS, Config
from capsd.simulator.sim import Simulation
from capsd.topics import ALL_TOPICS, Topic

FORMAT = "capsd-sim-dataset"
VERSION = 1
_RECORD = struct.Struct("<HI")


@dataclass(frozen=True)
class Record:
    """One event read back: its topic, vehicle and decoded payload."""

    topic: Topic[Any]
    vehicle: str
    payload: Payload


def write(
    directory: Path,
    config: Config,
    *,
    duration_s: float,
    start_ns: int = OFFLINE_START_NS,
    progress: bool = True,
) -> dict[str, Any]:
    """Simulate `duration_s` offline into `directory`; returns the metadata written."""
    directory.mkdir(parents=True, exist_ok=True)
    sim = Simulation(config, horizon_s=duration_s + 10.0)
    streams: dict[tuple[str, str], dict[str, Any]] = {}
    codecs: dict[type[Payload], Codec[Any]] = {}
    bar = Progress(duration_s, label="simulating", unit=" s") if progress else None
    with (directory / "events.bin").open("wb") as out:
        for event in sim.events(start_ns=start_ns, duration_s=duration_s):
            ident = (event.topic.subject.value, event.vehicle)
            stream = streams.get(ident)
            if stream is None:
                codec = codecs.setdefault(event.topic.payload, Codec(event.topic.payload))
                stream = streams[ident] = {
                    "index": len(streams),
                    "subject": ident[0],
                    "vehicle": ident[1],
                    "key": event.topic.key(config.site, event.vehicle),
                    "encoding": codec.encoding,
                    "count": 0,
                }
            data = codecs[event.topic.payload].encode(event.payload)
            out.write(_RECORD.pack(stream["index"], len(data)))
            out.write(data)
            stream["count"] += 1
            if bar is not None:
                bar.update(event.t_s)
    if bar is not None:
        bar.update(duration_s)
        bar.close()
    meta = {
        "format": FORMAT,
        "version": VERSION,
        "duration_s": duration_s,
        "start_ns": start_ns,
        "config": msgspec.to_builtins(config),
        "streams": sorted(streams.values(), key=lambda s: s["index"]),
    }
    (directory / "dataset.json").write_text(json.dumps(meta, indent=1, sort_keys=True) + "\n")
    return meta


def read(directory: Path) -> Iterator[Record]:
    """The events of a dataset in their recorded order, decoded and validated."""
    meta_path = directory / "dataset.json"
    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, ValueError) as exc:
        raise CapsdError(f"{meta_path}: not a readable dataset description ({exc})") from None
    if meta.get("format") != FORMAT or meta.get("version") != VERSION:
        raise CapsdError(f"{meta_path}: not a {FORMAT} version {VERSION}")
    by_subject = {t.subject.value: t for t in ALL_TOPICS}
    table: dict[int, tuple[Topic[Any], str, Codec[Any], str]] = {}
    for stream in meta["streams"]:
        topic = by_subject[stream["subject"]]
        table[stream["index"]] = (topic, stream["vehicle"], Codec(topic.payload), stream["key"])
    with (directory / "events.bin").open("rb") as data:
        while header := data.read(_RECORD.size):
            if len(header) < _RECORD.size:
                raise CapsdError(f"{directory}/events.bin: truncated record header")
            index, length = _RECORD.unpack(header)
            body = data.read(length)
            if len(body) < length or index not in table:
                raise CapsdError(f"{directory}/events.bin: truncated or unknown record {index}")
            topic, vehicle, codec, key = table[index]
            yield Record(topic, vehicle, codec.decode(body, encoding=None, key_expr=key))
