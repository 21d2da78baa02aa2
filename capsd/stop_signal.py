"""Setting a threading.Event from a signal handler without deadlocking the interrupted thread."""

from __future__ import annotations

import threading
from collections.abc import Callable


def set_after_handler(event: threading.Event, *, before: Callable[[], None] = lambda: None) -> None:
    """Set `event` from a signal handler without taking its lock there.

    A handler runs in the main thread between two bytecodes, possibly inside that thread's own
    `event.wait()` while it holds the event's lock: `event.set()` in the handler then waits for
    that lock forever. A short thread runs `before` and sets the event once the handler has
    returned and the lock is free.
    """

    def stop() -> None:
        before()
        event.set()

    threading.Thread(target=stop, name="stop-signal", daemon=True).start()
