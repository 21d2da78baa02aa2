"""Structured logging: logfmt lines on stderr, and foxglove.Log payloads on the bus (as BlueOS)."""

from __future__ import annotations

import logging
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

from capsd.payloads import FoxgloveTime, Log

_FOXGLOVE_LEVEL = {
    logging.DEBUG: 1,
    logging.INFO: 2,
    logging.WARNING: 3,
    logging.ERROR: 4,
    logging.CRITICAL: 5,
}


def _quote(value: object) -> str:
    text = str(value)
    if not text or any(c in text for c in ' ="\n\t'):
        text = '"' + text.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'
    return text


class LogfmtFormatter(logging.Formatter):
    """`ts=... level=info service=locator logger=... msg="..." key=value` per line."""

    def __init__(self, service: str):
        super().__init__()
        self.service = service

    def format(self, record: logging.LogRecord) -> str:
        ts = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created))
        parts = [
            f"ts={ts}.{int(record.msecs):03d}Z",
            f"level={record.levelname.lower()}",
            f"service={_quote(self.service)}",
            f"logger={_quote(record.name)}",
            f"msg={_quote(record.getMessage())}",
        ]
        fields: dict[str, Any] = getattr(record, "fields", {}) or {}
        parts.extend(f"{k}={_quote(v)}" for k, v in fields.items())
        if record.exc_info:
            parts.append(f"exc={_quote(self.formatException(record.exc_info))}")
        return " ".join(parts)


class BusLogHandler(logging.Handler):
    """Publishes each record as a foxglove.Log payload; never raises, never recurses."""

    def __init__(self, service: str, publish: Callable[[Log], None], next_seq: Callable[[], int]):
        super().__init__()
        self.service = service
        self._publish = publish
        self._next_seq = next_seq
        self._local = threading.local()
        self.dropped = 0

    def emit(self, record: logging.LogRecord) -> None:
        if getattr(self._local, "busy", False):
            return  # a log line raised while publishing a log line: stderr has it already
        self._local.busy = True
        try:
            stamp_ns = int(record.created * 1e9)
            message = record.getMessage()
            fields: dict[str, Any] = getattr(record, "fields", {}) or {}
            if fields:
                message += " " + " ".join(f"{k}={_quote(v)}" for k, v in fields.items())
            self._publish(
                Log(
                    stamp_ns=stamp_ns,
                    seq=self._next_seq(),
                    timestamp=FoxgloveTime(
                        sec=stamp_ns // 1_000_000_000, nsec=stamp_ns % 1_000_000_000
                    ),
                    level=_FOXGLOVE_LEVEL.get(record.levelno, 0),
                    message=message,
                    name=self.service,
                    file=record.pathname,
                    line=record.lineno,
                )
            )
        except Exception:
            self.dropped += 1
        finally:
            self._local.busy = False


def setup_stderr_logging(service: str, level: str) -> None:
    """Route all logging to stderr as logfmt at `level` (idempotent)."""
    root = logging.getLogger()
    for handler in list(root.handlers):
        if getattr(handler, "_capsd_stderr", False):
            root.removeHandler(handler)
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(LogfmtFormatter(service))
    handler._capsd_stderr = True  # type: ignore[attr-defined]
    root.addHandler(handler)
    root.setLevel(level.upper())


def log_fields(**fields: object) -> dict[str, dict[str, object]]:
    """`extra=` for a structured log call: logger.info("msg", extra=log_fields(key=1))."""
    return {"fields": fields}
