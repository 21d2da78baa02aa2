"""A signal handler sets an Event without waiting for the lock the interrupted thread holds."""

from __future__ import annotations

import threading

from capsd.stop_signal import set_after_handler


def test_the_event_is_set_after_the_interrupted_thread_lets_go_of_its_lock() -> None:
    event = threading.Event()
    ran: list[str] = []
    with event._cond:  # type: ignore[attr-defined]  # what a thread inside event.wait() holds
        set_after_handler(event, before=lambda: ran.append("before"))  # returns at once
        assert not event.is_set()
    assert event.wait(2.0)
    assert ran == ["before"]
