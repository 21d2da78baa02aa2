"""Record the bus into MCAP and replay it: what a laptop in the field does with `capsd record`.

Recording: every sample on the key expression becomes an MCAP message on a channel named by
its key. CAP-SD payloads get their JSON Schema (from the msgspec Struct, the one source of
truth) registered with encoding `jsonschema`; JSON payloads are `json` messages (Foxglove and
the `mcap` tools read them), sonar frames `msgpack`. The Zenoh encoding is kept in the
channel's metadata, so a replay puts the very same bytes with the very same encoding.
`log_time` is the arrival (wall clock, ns); `publish_time` is the payload's `stamp_ns` when it
has one. Wildcard keys (never a real publisher) are refused and counted.

Replay: messages in `log_time` order, at the recorded spacing divided by `speed`, bytes and
stamps untouched; keys can be included or excluded by key expression (e.g. replay the
locator's inputs without its recorded fixes).
"""

from __future__ import annotations

import queue
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import msgspec
import zenoh
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from capsd.codec import SCHEMAS, split_encoding
from capsd.errors import CapsdError
from capsd.keys import is_concrete

_STAMP = msgspec.json.Decoder(dict[str, object])


@dataclass(frozen=True)
class Sample:
    key: str
    encoding: str
    data: bytes
    arrival_ns: int


def _stamp_ns(sample: Sample) -> int:
    """The payload's own stamp (JSON payloads), else the arrival time."""
    mime, _ = split_encoding(sample.encoding)
    if mime == "application/json":
        try:
            value = _STAMP.decode(sample.data).get("stamp_ns")
        except msgspec.DecodeError:
            return sample.arrival_ns
        if isinstance(value, int) and value >= 0:
            return value
    return sample.arrival_ns


class McapRecorder:
    """Writes samples to an MCAP file; channels and schemas registered on first sight."""

    def __init__(self, out: Path):
        self._file = out.open("wb")
        self._writer = Writer(self._file, compression=CompressionType.ZSTD)
        self._writer.start(profile="", library="capsd")
        self._schemas: dict[str, int] = {}
        self._channels: dict[tuple[str, str], int] = {}
        self.counts: Counter[str] = Counter()

    def _schema(self, encoding: str) -> int:
        _, name = split_encoding(encoding)
        cls = SCHEMAS.get(name or "")
        if cls is None:
            return 0  # not ours: recorded without a schema
        if cls.__name__ not in self._schemas:
            schema = msgspec.json.encode(msgspec.json.schema(cls))
            self._schemas[cls.__name__] = self._writer.register_schema(
                name=cls.__name__, encoding="jsonschema", data=schema
            )
        return self._schemas[cls.__name__]

    def write(self, sample: Sample) -> None:
        ident = (sample.key, sample.encoding)
        channel = self._channels.get(ident)
        if channel is None:
            mime, _ = split_encoding(sample.encoding)
            message_encoding = {"application/json": "json", "application/msgpack": "msgpack"}
            channel = self._writer.register_channel(
                topic=sample.key,
                message_encoding=message_encoding.get(mime, mime or "unknown"),
                schema_id=self._schema(sample.encoding),
                metadata={"zenoh_encoding": sample.encoding},
            )
            self._channels[ident] = channel
        self._writer.add_message(
            channel_id=channel,
            log_time=sample.arrival_ns,
            data=sample.data,
            publish_time=_stamp_ns(sample),
            sequence=self.counts[sample.key],
        )
        self.counts[sample.key] += 1

    def close(self) -> None:
        self._writer.finish()  # type: ignore[no-untyped-call]
        self._file.close()

    def __enter__(self) -> McapRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def record(
    session: zenoh.Session,
    key_expr: str,
    out: Path,
    *,
    stop: threading.Event,
    duration_s: float | None = None,
    exclude: tuple[str, ...] = (),
    on_progress: Callable[[int], None] | None = None,
) -> Counter[str]:
    """Record until `stop` (or `duration_s`); returns the message count per key.

    Keys intersecting an `exclude` expression are not written (e.g. the sonar images).
    """
    pending: queue.Queue[Sample] = queue.Queue()
    refused: Counter[str] = Counter()
    skip = [zenoh.KeyExpr(e) for e in exclude]

    def on_sample(s: zenoh.Sample) -> None:
        key = str(s.key_expr)
        if not is_concrete(key):
            refused["wildcard_keys"] += 1
            return
        if any(e.intersects(s.key_expr) for e in skip):
            return
        pending.put(Sample(key, str(s.encoding), s.payload.to_bytes(), time.time_ns()))

    recorder = McapRecorder(out)
    subscriber = session.declare_subscriber(key_expr, on_sample)
    deadline = None if duration_s is None else time.monotonic() + duration_s
    written = 0
    try:
        while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
            try:
                recorder.write(pending.get(timeout=0.1))
                written += 1
                if on_progress is not None and written % 200 == 0:
                    on_progress(written)
            except queue.Empty:
                continue
    finally:
        subscriber.undeclare()
        while not pending.empty():
            recorder.write(pending.get_nowait())
        recorder.close()
    counts = Counter(recorder.counts)
    if refused:
        counts["(refused wildcard samples)"] = refused["wildcard_keys"]
    return counts


@dataclass(frozen=True)
class Recorded:
    key: str
    encoding: str
    data: bytes
    log_time_ns: int


def read(path: Path) -> Iterable[Recorded]:
    """Messages of a recording in log-time order."""
    try:
        with path.open("rb") as stream:
            reader = make_reader(stream)
            for _schema, channel, message in reader.iter_messages(log_time_order=True):
                encoding = channel.metadata.get("zenoh_encoding", "")
                yield Recorded(channel.topic, encoding, message.data, message.log_time)
    except FileNotFoundError:
        raise CapsdError(f"{path}: no such recording") from None
    except CapsdError:
        raise
    except Exception as exc:  # mcap raises several types for a bad file
        raise CapsdError(f"{path}: not a readable MCAP recording ({exc})") from exc


def channel_counts(path: Path) -> dict[str, int]:
    """Message count per channel, from the file's summary (what `mcap info` prints)."""
    try:
        with path.open("rb") as stream:
            summary = make_reader(stream).get_summary()
    except FileNotFoundError:
        raise CapsdError(f"{path}: no such recording") from None
    except Exception as exc:
        raise CapsdError(f"{path}: not a readable MCAP recording ({exc})") from exc
    if summary is None or summary.statistics is None:
        raise CapsdError(f"{path}: MCAP without a summary (was the recording cut short?)")
    counts = summary.statistics.channel_message_counts
    return {summary.channels[cid].topic: n for cid, n in counts.items()}


def replay(
    session: zenoh.Session,
    path: Path,
    *,
    speed: float,
    stop: threading.Event,
    include: str = "**",
    exclude: tuple[str, ...] = (),
    settle_s: float = 0.5,
) -> Counter[str]:
    """Put the recorded samples again, in recorded order and paced; returns the count per key.

    Every publisher is declared, and given `settle_s` to be routed, before the first put: the
    first put on a fresh route could otherwise be lost, and a replay must not lose anything.
    """
    inc = zenoh.KeyExpr(include)
    exc = [zenoh.KeyExpr(e) for e in exclude]

    def wanted(key: str) -> bool:
        k = zenoh.KeyExpr(key)
        return inc.intersects(k) and not any(e.intersects(k) for e in exc)

    counts: Counter[str] = Counter()
    start_wall: float | None = None
    first_log = 0
    publishers = {
        key: session.declare_publisher(key) for key in channel_counts(path) if wanted(key)
    }
    try:
        if publishers and stop.wait(settle_s):
            return counts
        for item in read(path):
            pub = publishers.get(item.key)
            if pub is None:
                continue
            if start_wall is None:
                start_wall, first_log = time.monotonic(), item.log_time_ns
            due = start_wall + (item.log_time_ns - first_log) / 1e9 / speed
            if stop.wait(max(0.0, due - time.monotonic())):
                break
            pub.put(item.data, encoding=zenoh.Encoding(item.encoding) if item.encoding else None)
            counts[item.key] += 1
    finally:
        for pub in publishers.values():
            pub.undeclare()
    return counts
