"""The service runner's guard: no service can subscribe to simulator truth or a reference."""

from __future__ import annotations

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
