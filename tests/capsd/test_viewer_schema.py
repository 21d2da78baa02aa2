"""Viewer JSON Schemas: every payload's passes the viewers' rules and validates its messages."""

from __future__ import annotations

import json

import jsonschema
import msgspec
import pytest

from capsd.payloads import ALL_PAYLOADS, Payload, RovFix
from capsd.viewer_schema import viewer_rules, viewer_schema, without_nulls
from tests.capsd.samples import SAMPLES


@pytest.mark.parametrize("cls", ALL_PAYLOADS, ids=lambda c: c.__name__)
def test_every_payload_has_a_schema_viewers_accept(cls: type[Payload]) -> None:
    assert viewer_rules(msgspec.json.schema(cls)) != []  # msgspec's own form: refused
    schema = viewer_schema(cls)
    assert viewer_rules(schema) == []
    assert "$ref" not in json.dumps(schema)
    assert "anyOf" not in json.dumps(schema)
    jsonschema.Draft202012Validator.check_schema(schema)


@pytest.mark.parametrize("sample", SAMPLES, ids=lambda s: type(s).__name__)
def test_messages_validate_against_their_viewer_schema(sample: Payload) -> None:
    message = json.loads(msgspec.json.encode(sample))
    validator = jsonschema.Draft202012Validator(viewer_schema(type(sample)))
    validator.validate(without_nulls(message))
    # What the bounds say still holds: a negative stamp is refused.
    with pytest.raises(jsonschema.ValidationError):
        validator.validate({**without_nulls(message), "stamp_ns": -1})


def test_nulls_are_what_the_viewer_form_leaves_out() -> None:
    fix = RovFix(stamp_ns=1, seq=0, method="capsd", quality="invalid", no_fix_reason="no detection")
    message = json.loads(msgspec.json.encode(fix))
    assert message["position_m"] is None
    validator = jsonschema.Draft202012Validator(viewer_schema(RovFix))
    with pytest.raises(jsonschema.ValidationError):
        validator.validate(message)
    validator.validate(without_nulls(message))
    assert msgspec.json.decode(json.dumps(without_nulls(message)), type=RovFix) == fix


def test_fixed_length_tuples_become_bounded_arrays() -> None:
    position = viewer_schema(RovFix)["properties"]["position_m"]
    assert position == {"type": "array", "items": {"type": "number"}, "minItems": 3,
                        "maxItems": 3}  # fmt: skip
    state = viewer_schema(RovFix)["properties"]["quality"]
    assert state["type"] == "string"
