"""The service runner: no truth or reference subscriptions; a stop signal takes no lock."""

from __future__ import annotations

import signal
import threading

import pytest

from capsd import topics
from capsd.config import ServiceConfig
from capsd.errors import KeyExprError
from capsd.keys import TRUTH_SUBJECTS
from capsd.payloads import Payload
from capsd.runner import ServiceRunner

TRUTH_TOPICS = [t for t in vars(topics).values() if isinstance(t, topics.Topic)]


@pytest.mark.parametrize(
    "topic",
    [t for t in TRUTH_TOPICS if t.subject in TRUTH_SUBJECTS],
    ids=lambda t: t.subject.value,
)
def test_a_service_cannot_subscribe_to_truth(topic: topics.Topic[Payload]) -> None:
    runner = ServiceRunner("locator", ServiceConfig(), install_signals=False)
    with pytest.raises(KeyExprError, match="simulator truth or a reference"):
        runner.subscribe(topic, lambda payload: None, vehicle="sim")


def test_every_sim_subject_but_control_is_truth() -> None:
    sim_subjects = {t.subject for t in TRUTH_TOPICS if t.subject.value.startswith("sim/")}
    assert sim_subjects - TRUTH_SUBJECTS == {topics.SIM_CONTROL.subject}
    assert TRUTH_SUBJECTS - sim_subjects == {topics.REFERENCE_POSE.subject}


def test_a_stop_signal_inside_the_main_loops_wait_stops_the_service() -> None:
    """The handler may run while the main thread holds stop_event's lock (inside its wait)."""
    runner = ServiceRunner("locator", ServiceConfig(), install_signals=False)
    returned = threading.Event()

    def handler() -> None:
        runner._on_signal(signal.SIGTERM, None)
        returned.set()

    # What the interrupted main thread holds: the event's own lock (its private condition).
    with runner.stop_event._cond:  # type: ignore[attr-defined]
        threading.Thread(target=handler, daemon=True).start()
        # Setting the event in the handler waited here for the lock (forever, in the thread).
        assert returned.wait(2.0), "the signal handler waited for a lock"
    assert runner.stop_event.wait(2.0)
