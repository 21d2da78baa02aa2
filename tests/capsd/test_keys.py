"""Key expressions: built in one place, wildcards detected."""

from __future__ import annotations

import pytest

from capsd import topics
from capsd.errors import KeyExprError
from capsd.keys import (
    Subject,
    alive_key,
    data_key,
    health_key,
    is_concrete,
    log_key,
    parse_service_key,
    require_concrete,
)


def test_keys_follow_the_namespace() -> None:
    assert data_key("tank1", "asv", Subject.SONAR_FRAME) == "cap/tank1/asv/sonar/frame"
    assert topics.ROV_FIX.key("t", "topside") == "cap/t/topside/locator/fix"
    assert health_key("t", "rov", "mav_bridge") == "cap/t/rov/health/mav_bridge"
    assert alive_key("t", "rov", "mav_bridge") == "cap/t/rov/alive/mav_bridge"
    assert log_key("t", "rov", "mav_bridge") == "services/capsd-t-rov-mav_bridge/log"
    assert parse_service_key("cap/t/rov/health/mav_bridge") == ("t", "rov", "mav_bridge")


@pytest.mark.parametrize("name", ["", "Tank", "a/b", "*", "**", "a b", "x" * 33, "_x"])
def test_bad_names_are_refused(name: str) -> None:
    with pytest.raises(KeyExprError):
        data_key(name, "asv", Subject.ASV_POSE)


@pytest.mark.parametrize(
    ("key", "concrete"),
    [
        ("cap/t/asv/asv/pose", True),
        ("cap/*/asv/asv/pose", False),
        ("cap/**", False),
        ("cap/t/asv/asv/po$*", False),
        ("cap/t/asv/asv/pose*x", True),  # '*' inside a chunk is not a wildcard in Zenoh 1.x keys
    ],
)
def test_wildcards(key: str, concrete: bool) -> None:
    assert is_concrete(key) is concrete
    if not concrete:
        with pytest.raises(KeyExprError, match="wildcard"):
            require_concrete(key)


def test_every_topic_has_a_unique_subject() -> None:
    subjects = [t.subject for t in topics.ALL_TOPICS]
    assert len(subjects) == len(set(subjects)) == len(Subject)
