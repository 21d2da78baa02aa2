"""Record the bus into MCAP and replay it: what a laptop in the field does with `capsd record`.

Recording: every sample on the key expression becomes an MCAP message on a channel named by
its key. CAP-SD payloads get their JSON Schema (from the msgspec Struct, the one source of
truth, in the dialect viewers accept: capsd.viewer_schema) registered with encoding
`jsonschema`; JSON payloads are `json` messages (Foxglove and the `mcap` tools read them),
without their null members so that they validate against that schema (the same values: an
absent optional field decodes to None), sonar frames `msgpack`, bytes as sent. The Zenoh
encoding is kept in the channel's metadata, so a replay puts the same payloads with the very
same encoding.
`log_time` is the arrival (wall clock, ns); `publish_time` is the payload's `stamp_ns` when it
has one. Wildcard keys (never a real publisher) are refused and counted.

With a view (capsd.scene), the recording also holds the operator's 3D scene, trails, LiDAR,
logs and sonar fan images as Foxglove messages on `/capsd/...` channels, derived as the live
view derives them; replay leaves those channels out.

Replay: messages in `log_time` order, at the recorded spacing divided by `speed`, bytes and
stamps untouched; keys can be included or excluded by key expression (e.g. replay the
locator's inputs without its recorded fixes).
"""

from __future__ import annotations

import dataclasses
import queue
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec
import zenoh
from mcap.exceptions import McapError
from mcap.reader import McapReader, NonSeekingReader, make_reader
from mcap.summary import Summary
from mcap.writer import CompressionType, Writer

from capsd.codec import SCHEMAS, decode_any, split_encoding
from capsd.errors import CapsdError, PayloadError
from capsd.foxglove_messages import SCHEMA_NAMES
from capsd.keys import is_concrete
from capsd.scene import SceneView
from capsd.viewer_schema import viewer_schema, without_nulls

_STAMP = msgspec.json.Decoder(dict[str, object])
_JSON = msgspec.json.Decoder()
_ENCODE = msgspec.json.Encoder()


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


def _without_nulls(sample: Sample) -> Sample:
    """A JSON payload without null members (left as it is when it is not JSON at all)."""
    try:
        value = _JSON.decode(sample.data)
    except msgspec.DecodeError:
        return sample  # recorded as it came; whoever reads it sees what was sent
    return dataclasses.replace(sample, data=_ENCODE.encode(without_nulls(value)))


# The locator config a recording was made with (`capsd record --locator-config`), attached so
# that `capsd replay-check` replays into a locator configured as the live one was.
LOCATOR_CONFIG_ATTACHMENT = "capsd/locator.yaml"


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
            schema = msgspec.json.encode(viewer_schema(cls))
            # Log lines keep Foxglove's name, so its Log panel takes the services' own channels.
            self._schemas[cls.__name__] = self._writer.register_schema(
                name=getattr(cls, "SCHEMA_NAME", cls.__name__), encoding="jsonschema", data=schema
            )
        return self._schemas[cls.__name__]

    def write(self, sample: Sample) -> None:
        mime, schema = split_encoding(sample.encoding)
        if mime == "application/json" and schema in SCHEMAS:
            sample = _without_nulls(sample)
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

    def write_view(self, topic: str, message: msgspec.Struct, log_time_ns: int) -> None:
        """One of the operator view's Foxglove messages (capsd.scene) on its own channel."""
        cls = type(message)
        name = SCHEMA_NAMES[cls]
        if name not in self._schemas:
            self._schemas[name] = self._writer.register_schema(
                name=name, encoding="jsonschema", data=msgspec.json.encode(viewer_schema(cls))
            )
        channel = self._channels.get((topic, name))
        if channel is None:
            channel = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=self._schemas[name]
            )
            self._channels[(topic, name)] = channel
        timestamp = getattr(message, "timestamp", None)
        publish = log_time_ns
        if timestamp is not None:
            publish = timestamp.sec * 1_000_000_000 + timestamp.nsec
        self._writer.add_message(
            channel_id=channel,
            log_time=log_time_ns,
            data=msgspec.json.encode(message),
            publish_time=publish,
            sequence=self.counts[topic],
        )
        self.counts[topic] += 1

    def attach(self, name: str, data: bytes, *, media_type: str) -> None:
        """A file kept beside the messages (an MCAP attachment)."""
        now = time.time_ns()
        self._writer.add_attachment(
            create_time=now, log_time=now, name=name, media_type=media_type, data=data
        )

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
    view: SceneView | None = None,
    logs: str | None = None,
    on_progress: Callable[[int], None] | None = None,
    attachments: dict[str, bytes] | None = None,
) -> Counter[str]:
    """Record until `stop` (or `duration_s`); returns the message count per key.

    Keys intersecting an `exclude` expression are not written (e.g. the sonar images); with
    `view`, every sample (excluded ones too) also feeds the operator's scene, whose messages are
    written on their own channels (capsd.scene). `logs`: a key expression of log lines to
    record as well (the services' `services/.../log`). `attachments`: files (by name) kept in
    the recording, e.g. LOCATOR_CONFIG_ATTACHMENT.
    """
    pending: queue.Queue[tuple[Sample, bool]] = queue.Queue()
    refused: Counter[str] = Counter()
    skip = [zenoh.KeyExpr(e) for e in exclude]

    def on_sample(s: zenoh.Sample) -> None:
        key = str(s.key_expr)
        if not is_concrete(key):
            refused["wildcard_keys"] += 1
            return
        keep = not any(e.intersects(s.key_expr) for e in skip)
        if keep or view is not None:
            pending.put((Sample(key, str(s.encoding), s.payload.to_bytes(), time.time_ns()), keep))

    recorder = McapRecorder(out)
    for name, data in (attachments or {}).items():
        recorder.attach(name, data, media_type="application/yaml")
    if view is not None:
        now = time.time_ns()
        for topic, message in view.static(now):
            recorder.write_view(topic, message, now)
    subscribers = [session.declare_subscriber(key_expr, on_sample)]
    if logs is not None:
        subscribers.append(session.declare_subscriber(logs, on_sample))
    deadline = None if duration_s is None else time.monotonic() + duration_s
    written = 0

    def write(sample: Sample, keep: bool) -> None:
        if keep:
            recorder.write(sample)
        if view is not None:
            for topic, message in _derive(view, sample):
                recorder.write_view(topic, message, sample.arrival_ns)

    try:
        while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
            try:
                write(*pending.get(timeout=0.1))
                written += 1
                if on_progress is not None and written % 200 == 0:
                    on_progress(written)
            except queue.Empty:
                continue
    finally:
        for subscriber in subscribers:
            subscriber.undeclare()
        while not pending.empty():
            write(*pending.get_nowait())
        recorder.close()
    counts = Counter(recorder.counts)
    if refused:
        counts["(refused wildcard samples)"] = refused["wildcard_keys"]
    return counts


def _derive(view: SceneView, sample: Sample) -> list[tuple[str, Any]]:
    """The scene's messages from one sample (none from one that does not decode)."""
    try:
        payload = decode_any(sample.data, encoding=sample.encoding, key_expr=sample.key)
    except PayloadError:
        return []  # recorded as it came (or not at all), drawn by no one
    return view.on_payload(sample.key, payload)


@dataclass(frozen=True)
class Recorded:
    key: str
    encoding: str
    data: bytes
    log_time_ns: int


@contextmanager
def _opened(path: Path) -> Iterator[McapReader]:
    """A reader of the recording at `path`; a missing or unreadable file is an error naming it."""
    try:
        with path.open("rb") as stream:
            yield make_reader(stream)
    except FileNotFoundError:
        raise CapsdError(f"{path}: no such recording") from None
    except CapsdError:
        raise
    except Exception as exc:  # mcap raises several types for a bad file
        raise CapsdError(f"{path}: not a readable MCAP recording ({exc})") from exc


def read(path: Path) -> Iterable[Recorded]:
    """Messages of a recording in log-time order.

    A recording cut short (the recorder killed, the laptop's power lost) has no summary: it is
    read from the start up to its last complete chunk instead, in the order it was written
    (the arrival order, which is the log time's), and how much was read is said on stderr.
    """
    yielded = False
    try:
        with _opened(path) as reader:
            for _schema, channel, message in reader.iter_messages(log_time_order=True):
                encoding = channel.metadata.get("zenoh_encoding", "")
                yielded = True
                yield Recorded(channel.topic, encoding, message.data, message.log_time)
    except CapsdError as exc:
        if yielded or not isinstance(exc.__cause__, McapError):
            raise
        yield from _read_cut_short(path, exc)


def _read_cut_short(path: Path, cause: CapsdError) -> Iterator[Recorded]:
    """Every message up to where a recording without a summary ends (see `read`)."""
    count = 0
    with path.open("rb") as stream:
        messages = NonSeekingReader(stream).iter_messages(log_time_order=False)
        while True:
            try:
                _schema, channel, message = next(messages)
            except StopIteration:
                break
            except (McapError, EOFError, ValueError):
                break  # the cut: the rest of the file is an incomplete record
            count += 1
            yield Recorded(
                channel.topic,
                channel.metadata.get("zenoh_encoding", ""),
                message.data,
                message.log_time,
            )
    if not count:
        raise cause
    print(
        f"{path}: cut short (no summary: {cause.__cause__}); read {count} messages up to its "
        "last complete chunk",
        file=sys.stderr,
        flush=True,
    )


def summary_of(path: Path) -> Summary:
    """The file's summary with its statistics (what `mcap info` prints); a clear error else."""
    with _opened(path) as reader:
        summary = reader.get_summary()
    if summary is None or summary.statistics is None:
        raise CapsdError(f"{path}: MCAP without a summary (was the recording cut short?)")
    return summary


def attachment(path: Path, name: str) -> bytes | None:
    """The recording's attachment of that name (the last, if several), or None."""
    found: bytes | None = None
    with _opened(path) as reader:
        for item in reader.iter_attachments():
            if item.name == name:
                found = bytes(item.data)
    return found


def channel_counts(path: Path) -> dict[str, int]:
    """Message count per channel, from the file's summary."""
    summary = summary_of(path)
    assert summary.statistics is not None  # summary_of checked it
    counts = summary.statistics.channel_message_counts
    return {summary.channels[cid].topic: n for cid, n in counts.items()}


def time_span_ns(path: Path) -> tuple[int, int]:
    """The first and last log time of a recording, from its summary."""
    statistics = summary_of(path).statistics
    assert statistics is not None  # summary_of checked it
    if statistics.message_count == 0:
        raise CapsdError(f"{path}: a recording without messages")
    return statistics.message_start_time, statistics.message_end_time


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
        if key.startswith("/"):
            return False  # the operator view's channels (capsd.scene): for viewers, not the bus
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
