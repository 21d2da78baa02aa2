"""The service runner every service shares: session, liveliness, health, logs, signals, sd_notify.

Usage, inside a service's `main(config)`:

    with ServiceRunner("locator", config) as runner:
        fixes = runner.publisher(topics.ROV_FIX)
        runner.subscribe(topics.SONAR_DETECTIONS, on_detections, vehicle="asv")
        runner.run()            # returns on SIGTERM/SIGINT

Inputs are decoded and validated here: a malformed payload or a wildcard key is counted,
logged (rate limited) and dropped; a handler that raises is counted and logged; the service
keeps running either way.
"""

from __future__ import annotations

import faulthandler
import logging
import math
import os
import signal
import socket
import threading
import time
import types
from collections import deque
from collections.abc import Callable, Mapping
from typing import Generic, Self, TypeVar

import zenoh

from capsd import __version__, sdnotify
from capsd.bus import open_session
from capsd.codec import Codec
from capsd.config import ServiceConfig
from capsd.errors import KeyExprError, PayloadError
from capsd.keys import TRUTH_SUBJECTS, alive_key, check_name, health_key, is_concrete, log_key
from capsd.latency import LatencyRecorder
from capsd.logs import BusLogHandler, log_fields
from capsd.payloads import Health, HealthState, LatencyStats, Log, Payload, StreamStats
from capsd.signing import TAG_BYTES, SiteKey
from capsd.stop_signal import set_after_handler
from capsd.topics import Topic

P = TypeVar("P", bound=Payload)

logger = logging.getLogger(__name__)

_ERROR_LOG_INTERVAL_S = 1.0
_SHUTDOWN_LIMIT_S = 1.5
# An input whose stamps are this far in the future, or this old on arrival (the bridge's
# freshness limit), makes the service "degraded" with the reason.
INPUT_FUTURE_LIMIT_MS = 50.0
INPUT_AGE_LIMIT_MS = 300.0
_PUT_TIME_BYTES = 8  # the attachment of every put: the wall clock (ns) when it was put


def put_time_ns(sample: zenoh.Sample) -> int | None:
    """When the sample was put (sender's wall clock), from its attachment; None if absent."""
    attachment = sample.attachment
    if attachment is None:
        return None
    raw = attachment.to_bytes()
    if len(raw) not in (_PUT_TIME_BYTES, _PUT_TIME_BYTES + TAG_BYTES):
        return None
    return int.from_bytes(raw[:_PUT_TIME_BYTES], "little")


def attachment_tag(sample: zenoh.Sample) -> bytes:
    """The authentication tag after the put time in the attachment (b"" if none)."""
    attachment = sample.attachment
    if attachment is None:
        return b""
    return attachment.to_bytes()[_PUT_TIME_BYTES:]


def _median(values: deque[float]) -> float | None:
    """The median of at least 10 values, else None (too few to say)."""
    if len(values) < 10:
        return None
    ordered = sorted(values)
    return ordered[len(ordered) // 2]


class StreamCounter:
    """Thread-safe counters of one stream: messages, errors, sequence gaps, rate."""

    def __init__(self, key: str):
        self.key = key
        self._lock = threading.Lock()
        self.count = 0
        self.errors = 0
        self.unauthenticated = 0  # refused: no valid authentication tag (capsd.signing)
        self.dropped = 0
        self.seq_regressions = 0
        self.shared_memory = 0
        self._ages_ms: deque[float] = deque(maxlen=32)
        self._recent_regressions: deque[float] = deque(maxlen=64)
        self.last_stamp_ns: int | None = None
        self._last_seq: int | None = None
        self._rate_count = 0
        self._rate_since = time.monotonic()
        self.rate_hz = 0.0
        self._last_error_log = 0.0
        self._suppressed = 0

    def record(self, payload: Payload) -> None:
        age_ms = (time.time_ns() - payload.stamp_ns) / 1e6
        with self._lock:
            self._ages_ms.append(age_ms)
            self.count += 1
            self._rate_count += 1
            self.last_stamp_ns = payload.stamp_ns
            if self._last_seq is not None:
                if payload.seq > self._last_seq + 1:
                    self.dropped += payload.seq - self._last_seq - 1
                elif payload.seq <= self._last_seq:
                    self.seq_regressions += 1
                    self._recent_regressions.append(time.monotonic())
            self._last_seq = payload.seq

    def age_ms(self) -> float | None:
        """Median of the recent (arrival - stamp), ms; None before 10 messages."""
        with self._lock:
            return _median(self._ages_ms)

    def interleaved(self, *, window_s: float = 5.0, threshold: int = 3) -> bool:
        """True when seq went backwards repeatedly of late: more than one publisher."""
        with self._lock:
            now = time.monotonic()
            while self._recent_regressions and now - self._recent_regressions[0] > window_s:
                self._recent_regressions.popleft()
            return len(self._recent_regressions) >= threshold

    def record_error(self) -> int | None:
        """Count one error; returns how many were suppressed if this one should be logged."""
        with self._lock:
            self.errors += 1
            now = time.monotonic()
            if now - self._last_error_log >= _ERROR_LOG_INTERVAL_S:
                self._last_error_log = now
                suppressed, self._suppressed = self._suppressed, 0
                return suppressed
            self._suppressed += 1
            return None

    def snapshot(self) -> StreamStats:
        with self._lock:
            now = time.monotonic()
            elapsed = now - self._rate_since
            if elapsed >= 0.5:
                self.rate_hz = self._rate_count / elapsed
                self._rate_count = 0
                self._rate_since = now
            return StreamStats(
                key=self.key,
                count=self.count,
                rate_hz=self.rate_hz,
                errors=self.errors,
                dropped=self.dropped,
                seq_regressions=self.seq_regressions,
                last_stamp_ns=self.last_stamp_ns,
                shared_memory=self.shared_memory,
                age_ms=_median(self._ages_ms),
            )


class Publisher(Generic[P]):
    """Encodes and puts one payload type on one key; owns the stream's `seq`."""

    def __init__(
        self,
        session: zenoh.Session,
        key: str,
        codec: Codec[P],
        counter: StreamCounter,
        *,
        signer: SiteKey | None = None,
    ):
        self.key = key
        self.codec = codec
        self.counter = counter
        self.signer = signer
        self._publisher = session.declare_publisher(key, encoding=zenoh.Encoding(codec.encoding))
        self._seq = 0
        self._lock = threading.Lock()

    def next_seq(self) -> int:
        """The `seq` for the next payload of this stream (0, 1, 2, ... from process start)."""
        with self._lock:
            seq, self._seq = self._seq, self._seq + 1
            return seq

    def put(self, payload: P) -> None:
        # The put time travels as an attachment so receivers can measure transport latency.
        stamp = time.time_ns().to_bytes(_PUT_TIME_BYTES, "little")
        data = self.codec.encode(payload)
        if self.signer is not None:
            stamp += self.signer.tag(self.key, data)
        self._publisher.put(data, attachment=stamp)
        self.counter.record(payload)

    def undeclare(self) -> None:
        self._publisher.undeclare()


class ServiceRunner:
    """Runs one service on the bus; a context manager that cleans up on every path."""

    def __init__(self, name: str, config: ServiceConfig, *, install_signals: bool = True):
        self.name = check_name("service", name)
        self.config = config
        self.stop_event = threading.Event()
        self._install_signals = install_signals
        self._state: HealthState = "starting"
        self._state_reason: str | None = None
        self._inputs: list[StreamCounter] = []
        self._outputs: list[StreamCounter] = []
        self._last_error: str | None = None
        self._last_error_stamp_ns: int | None = None
        # Per kind of error: when it was last logged, and how many since were not.
        self._error_log: dict[str, tuple[float, int]] = {}
        self._lock = threading.Lock()
        self._started = time.monotonic()
        self._session: zenoh.Session | None = None
        self._declared: list[
            zenoh.Subscriber[None] | zenoh.LivelinessToken | zenoh.Queryable[None]
        ] = []
        self._publishers: list[Publisher[Payload]] = []
        self._health_pub: Publisher[Health] | None = None
        self._last_health_seq = 0
        self._health_thread: threading.Thread | None = None
        self._log_handler: BusLogHandler | None = None
        self._main_tick = time.monotonic()
        self._old_handlers: dict[int, object] = {}
        self._counter_sources: list[Callable[[], Mapping[str, int]]] = []
        self._latencies: list[LatencyRecorder] = []
        self._arrival = threading.local()
        self._input_problem: str | None = None

    # ------------------------------------------------------------------ lifecycle

    def __enter__(self) -> Self:
        try:
            self._start()
        except BaseException:
            self._shutdown()
            raise
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: types.TracebackType | None,
    ) -> None:
        if exc is not None and not isinstance(exc, KeyboardInterrupt):
            self.report_error(f"stopping on {type(exc).__name__}: {exc}")
        self._shutdown()

    def _start(self) -> None:
        if self._install_signals and threading.current_thread() is threading.main_thread():
            for signum in (signal.SIGTERM, signal.SIGINT):
                self._old_handlers[signum] = signal.signal(signum, self._on_signal)
        cfg = self.config
        sdnotify.notify(f"STATUS=joining Zenoh via {','.join(cfg.bus.connect) or 'listen only'}")
        self._session = open_session(cfg.bus, stop=self.stop_event)
        session = self._session
        self._declared.append(
            session.liveliness().declare_token(alive_key(cfg.site, cfg.vehicle, self.name))
        )
        hkey = health_key(cfg.site, cfg.vehicle, self.name)
        self._health_pub = self._make_publisher(hkey, Codec(Health), count_output=False)
        self._declared.append(session.declare_queryable(hkey, self._answer_health_query))
        if cfg.log_to_bus == "on":
            log_pub = self._make_publisher(
                log_key(cfg.site, cfg.vehicle, self.name), Codec(Log), count_output=False
            )
            self._log_handler = BusLogHandler(self.name, log_pub.put, log_pub.next_seq)
            self._log_handler.setLevel(cfg.log_level.upper())
            logging.getLogger().addHandler(self._log_handler)
        self._publish_health()
        self._health_thread = threading.Thread(
            target=self._health_loop, name=f"{self.name}-health", daemon=True
        )
        self._health_thread.start()
        logger.info(
            "service started",
            extra=log_fields(
                site=cfg.site, vehicle=cfg.vehicle, mode=cfg.bus.mode, zid=str(session.zid())
            ),
        )

    def _shutdown(self) -> None:
        # A wedged cleanup must not outlive systemd's stop timeout: after 1.5 s, dump every
        # thread's stack to stderr (the diagnosis) and exit 1.
        faulthandler.dump_traceback_later(_SHUTDOWN_LIMIT_S, exit=True)
        try:
            self._cleanup()
        finally:
            faulthandler.cancel_dump_traceback_later()

    def _cleanup(self) -> None:
        self.stop_event.set()
        with self._lock:
            self._state = "stopping"
        sdnotify.notify("STOPPING=1")
        if self._health_thread is not None:
            self._health_thread.join(timeout=1.0)
        if self._log_handler is not None:
            logging.getLogger().removeHandler(self._log_handler)
            self._log_handler = None
        if self._session is not None:
            try:
                self._publish_health()  # the last word: state "stopping"
            except Exception:
                logger.debug("final health not sent", exc_info=True)
            # Undeclare first: a declared callback subscriber hangs the exit (FIELD-NOTES).
            for entity in reversed(self._declared):
                try:
                    entity.undeclare()  # type: ignore[no-untyped-call]
                except zenoh.ZError:
                    logger.debug("undeclare failed", exc_info=True)
            self._declared.clear()
            self._session.close()
            self._session = None
        for signum, handler in self._old_handlers.items():
            signal.signal(signum, handler)  # type: ignore[arg-type]
        self._old_handlers.clear()

    def _on_signal(self, signum: int, _frame: types.FrameType | None) -> None:
        # The handler runs in the main thread between two bytecodes, possibly inside that
        # thread's own stop_event.wait() while it holds the event's lock: Event.set() here
        # waited for that lock forever (a locator ignored SIGTERM so, once in a CI run). A
        # short thread sets the event once the handler has returned and the lock is free.
        set_after_handler(self.stop_event, before=lambda: self._log_stop(signum))

    def _log_stop(self, signum: int) -> None:
        logger.info("stop requested", extra=log_fields(signal=signal.Signals(signum).name))

    # ------------------------------------------------------------------ bus access

    @property
    def session(self) -> zenoh.Session:
        if self._session is None:
            raise RuntimeError("the runner is not started")
        return self._session

    def _make_publisher(
        self,
        key: str,
        codec: Codec[P],
        *,
        count_output: bool = True,
        signer: SiteKey | None = None,
    ) -> Publisher[P]:
        counter = StreamCounter(key)
        publisher = Publisher(self.session, key, codec, counter, signer=signer)
        if count_output:
            with self._lock:
                self._outputs.append(counter)
        self._publishers.append(publisher)  # type: ignore[arg-type]
        return publisher

    def publisher(
        self, topic: Topic[P], *, vehicle: str | None = None, signer: SiteKey | None = None
    ) -> Publisher[P]:
        """A publisher for `topic` in this service's site, under `vehicle` (default: own).

        With `signer`, every payload carries its authentication tag (capsd.signing).
        """
        key = topic.key(self.config.site, vehicle or self.config.vehicle)
        return self._make_publisher(key, Codec(topic.payload), signer=signer)

    def subscribe(
        self,
        topic: Topic[P],
        handler: Callable[[P], None],
        *,
        vehicle: str | None = None,
        verifier: SiteKey | None = None,
    ) -> StreamCounter:
        """Call `handler` with each valid payload of `topic`; bad input is counted and dropped.

        A payload larger than the topic's `max_bytes` is refused before it is copied; with
        `verifier`, one whose tag does not check (or has none) is refused before decoding
        (counted in the stream's `unauthenticated`).
        The handler runs on Zenoh's callback thread: keep it short, or hand work to a thread.
        """
        key = topic.key(self.config.site, vehicle or self.config.vehicle)
        if topic.subject in TRUTH_SUBJECTS:
            # Truth reaches benches, taps and recordings only, never a service's logic.
            raise KeyExprError(
                f"'{key}' carries simulator truth or a reference: no service subscribes to it"
            )
        codec = Codec(topic.payload)
        counter = StreamCounter(key)
        transport = self.latency(f"transport {topic.subject.value}")
        with self._lock:
            self._inputs.append(counter)

        def on_sample(sample: zenoh.Sample) -> None:
            received_ns = time.time_ns()
            sent_ns = put_time_ns(sample)
            if sent_ns is not None:
                transport.record_ns(received_ns - sent_ns)
            if sample.payload.as_shm() is not None:
                counter.shared_memory += 1
            self._arrival.ns = received_ns
            sample_key = str(sample.key_expr)
            try:
                if not is_concrete(sample_key):
                    raise PayloadError(
                        sample_key, codec.schema, "wildcard key expression refused on an input"
                    )
                size = len(sample.payload)
                if size > topic.max_bytes:
                    raise PayloadError(
                        sample_key,
                        codec.schema,
                        f"{size} bytes, more than the {topic.max_bytes} this input accepts",
                    )
                data = sample.payload.to_bytes()
                if verifier is not None and not verifier.verify(
                    sample_key, data, attachment_tag(sample)
                ):
                    counter.unauthenticated += 1
                    raise PayloadError(
                        sample_key, codec.schema, "not signed with the site's key: refused"
                    )
                payload = codec.decode(data, encoding=str(sample.encoding), key_expr=sample_key)
            except PayloadError as exc:
                self._input_error(counter, str(exc), kind="decode")
                return
            counter.record(payload)
            try:
                handler(payload)
            except Exception as exc:
                self._input_error(
                    counter,
                    f"handler failed on '{sample_key}': {type(exc).__name__}: {exc}",
                    kind="handler",
                )

        self._declared.append(self.session.declare_subscriber(key, on_sample))
        return counter

    def received_ns(self) -> int:
        """When the payload a handler is working on arrived (wall clock, before decoding)."""
        arrival: int | None = getattr(self._arrival, "ns", None)
        return time.time_ns() if arrival is None else arrival

    def latency(self, name: str) -> LatencyRecorder:
        """A latency histogram reported in this service's Health under `name`."""
        recorder = LatencyRecorder(name)
        with self._lock:
            self._latencies.append(recorder)
        return recorder

    def _input_error(self, counter: StreamCounter, message: str, *, kind: str) -> None:
        suppressed = counter.record_error()
        self._set_last_error(message)
        if suppressed is not None:
            logger.warning(
                message, extra=log_fields(kind=kind, suppressed=suppressed, errors=counter.errors)
            )

    # ------------------------------------------------------------------ state and health

    def add_counters(self, source: Callable[[], Mapping[str, int]]) -> None:
        """Report `source()`'s counts in every Health (called on the health thread)."""
        with self._lock:
            self._counter_sources.append(source)

    def set_state(self, state: HealthState, reason: str | None = None) -> None:
        """Declare the service's own state ("ok", "degraded", "error") for its Health."""
        with self._lock:
            changed = state != self._state
            self._state, self._state_reason = state, reason
        if changed:
            logger.info("state changed", extra=log_fields(state=state, reason=reason or ""))

    def report_error(self, message: str, *, kind: str = "error") -> None:
        """Record `message` as the last error (shown in Health) and log it.

        At most one line a second per `kind`: a flood of bad input cannot become a log storm
        (the line says how many were not logged; Health counts them all where they happen).
        """
        self._set_last_error(message)
        now = time.monotonic()
        with self._lock:
            last, suppressed = self._error_log.get(kind, (-math.inf, 0))
            if now - last < _ERROR_LOG_INTERVAL_S:
                self._error_log[kind] = (last, suppressed + 1)
                return
            self._error_log[kind] = (now, 0)
        logger.error(message if not suppressed else f"{message} ({suppressed} more not logged)")

    def _set_last_error(self, message: str) -> None:
        with self._lock:
            self._last_error = message
            self._last_error_stamp_ns = time.time_ns()

    def health(self, *, seq: int | None = None) -> Health:
        """The current Health payload (without publishing it); `seq` defaults to the next one."""
        with self._lock:
            inputs = tuple(c.snapshot() for c in self._inputs)
            outputs = tuple(c.snapshot() for c in self._outputs)
            state, state_reason = self._state, self._state_reason
            last_error, last_error_stamp = self._last_error, self._last_error_stamp_ns
            counters: dict[str, int] = {}
            for source in self._counter_sources:
                counters.update(source())
            latencies: tuple[LatencyStats, ...] = tuple(r.snapshot() for r in self._latencies)
        assert self._health_pub is not None
        return Health(
            stamp_ns=time.time_ns(),
            seq=self._health_pub.next_seq() if seq is None else seq,
            service=self.name,
            state=state,
            state_reason=state_reason if state != "ok" else None,
            pid=os.getpid(),
            host=socket.gethostname(),
            software_version=__version__,
            uptime_s=time.monotonic() - self._started,
            inputs=inputs,
            outputs=outputs,
            decode_errors=sum(s.errors for s in inputs),
            dropped=sum(s.dropped for s in inputs),
            last_error=last_error,
            last_error_stamp_ns=last_error_stamp,
            counters=counters,
            latencies=latencies,
        )

    def _publish_health(self) -> None:
        if self._health_pub is None:
            return
        health = self.health()
        self._last_health_seq = health.seq
        self._health_pub.put(health)

    def _answer_health_query(self, query: zenoh.Query) -> None:
        """Reply with the live state (seq of the last published Health: replies are no stream)."""
        if self._health_pub is not None:
            health = self.health(seq=self._last_health_seq)
            query.reply(
                self._health_pub.key,
                self._health_pub.codec.encode(health),
                encoding=zenoh.Encoding(self._health_pub.codec.encoding),
            )

    def _check_inputs(self) -> None:
        """Say so, loudly, when an input is suspect (the service goes "degraded" with why).

        Two publishers on one key silently mix two measurements; stamps in this clock's future
        or old on arrival mean clock skew or a slow link.
        """
        with self._lock:
            inputs = list(self._inputs)
        message = None
        shared = [c.key for c in inputs if c.interleaved()]
        if shared:
            message = (
                f"input '{shared[0]}' has more than one publisher (its seq keeps going backwards)"
            )
        for c in inputs:
            age = c.age_ms()
            if message is not None or age is None:
                continue
            if age < -INPUT_FUTURE_LIMIT_MS:
                message = (
                    f"input '{c.key}' is stamped {-age:.0f} ms ahead of this computer's clock "
                    "(clock skew?)"
                )
            elif age > INPUT_AGE_LIMIT_MS:
                message = (
                    f"input '{c.key}' arrives {age:.0f} ms after its stamp (clock skew or a slow "
                    "link?)"
                )
        if message is not None:
            if message != self._input_problem:
                self._set_last_error(message)
                logger.warning(message)
            self.set_state("degraded", message)
            self._input_problem = message
        elif self._input_problem is not None:
            self._input_problem = None
            self.set_state("ok")

    def _health_loop(self) -> None:
        period = self.config.health_period_s
        watchdog = sdnotify.watchdog_interval_s()
        tick = min(period, watchdog) if watchdog else period
        next_health = time.monotonic() + period
        while not self.stop_event.wait(tick):
            now = time.monotonic()
            # Ping the watchdog only while the main loop is alive, so a wedged service restarts.
            if watchdog is not None and now - self._main_tick < 2 * max(watchdog, 1.0):
                sdnotify.notify("WATCHDOG=1")
            if now >= next_health:
                next_health += period
                self._check_inputs()
                try:
                    self._publish_health()
                except Exception as exc:
                    logger.warning("health not published", extra=log_fields(error=str(exc)))

    # ------------------------------------------------------------------ main loop

    def run(self, step: Callable[[], None] | None = None, *, period_s: float = 0.1) -> None:
        """Mark the service ready and loop until stopped, calling `step` every `period_s`.

        A `step` that raises is counted, logged (rate limited) and called again next period.
        """
        with self._lock:
            if self._state == "starting":
                self._state = "ok"
        sdnotify.notify("READY=1", f"STATUS={self.name} running")
        step_errors = StreamCounter(f"{self.name}/step")
        next_time = time.monotonic()
        while not self.stop_event.is_set():
            self._main_tick = time.monotonic()
            if step is not None:
                try:
                    step()
                except Exception as exc:
                    suppressed = step_errors.record_error()
                    self._set_last_error(f"{type(exc).__name__}: {exc}")
                    if suppressed is not None:
                        logger.exception("step failed", extra=log_fields(suppressed=suppressed))
            next_time += period_s
            delay = next_time - time.monotonic()
            if delay < -period_s:  # fell behind: don't burst to catch up
                next_time = time.monotonic()
                delay = 0.0
            self.stop_event.wait(max(delay, 0.0))
