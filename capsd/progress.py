"""A progress line on stderr for long work: a bar on a terminal, a line per 10% otherwise."""

from __future__ import annotations

import sys
import time
from typing import TextIO


class Progress:
    """`update(done)` as work advances; `close()` at the end. Throttled to 5 updates a second."""

    def __init__(self, total: float, *, label: str, unit: str = "", out: TextIO | None = None):
        self.total = max(total, 1e-9)
        self.label = label
        self.unit = unit
        self.out = out or sys.stderr
        self.tty = self.out.isatty()
        self.start = time.monotonic()
        self._last_draw = 0.0
        self._last_decile = -1

    def update(self, done: float) -> None:
        fraction = min(max(done / self.total, 0.0), 1.0)
        now = time.monotonic()
        elapsed = now - self.start
        speed = done / elapsed if elapsed > 0 else 0.0
        text = (
            f"{self.label} {100 * fraction:5.1f}%  {done:.1f}/{self.total:.1f}{self.unit}"
            f"  {speed:.2f}{self.unit}/s"
        )
        if self.tty:
            if now - self._last_draw >= 0.2 or fraction >= 1.0:
                self._last_draw = now
                bar = "#" * int(30 * fraction)
                self.out.write(f"\r[{bar:<30}] {text}")
                self.out.flush()
        else:
            decile = int(10 * fraction)
            if decile > self._last_decile:
                self._last_decile = decile
                self.out.write(text + "\n")
                self.out.flush()

    def close(self) -> None:
        if self.tty:
            self.out.write("\n")
            self.out.flush()
