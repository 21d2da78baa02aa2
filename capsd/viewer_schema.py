"""JSON Schemas that data viewers (Foxglove, Lichtblick) accept, made from the msgspec Structs.

msgspec writes standard JSON Schema: the root a `$ref` into `$defs`, optional fields as
`anyOf [T, null]`, enums without a `type`, fixed-length tuples as `prefixItems`. Viewers build
their message definitions from a much smaller dialect (Foxglove's documentation: the root is
`"type": "object"`; every field has one plain `type`; an array has one `items` schema; an
object lists its `properties`). This module rewrites the one into the other, so the Structs
stay the single source and recordings and the live view carry the same schemas; their JSON
messages leave null members out (`without_nulls`), so they also validate against them.
`viewer_rules` states that dialect as a check (the tests run it on every channel's schema).
"""

from __future__ import annotations

from typing import Any

import msgspec

_PLAIN = {"boolean", "string", "number", "integer", "object", "array"}


def viewer_schema(cls: Any) -> dict[str, Any]:
    """The viewer-dialect JSON Schema of a msgspec Struct (or any type msgspec describes)."""
    raw = msgspec.json.schema(cls)
    defs = raw.pop("$defs", {})
    out = _plain(raw, defs, path=getattr(cls, "__name__", str(cls)))
    if out.get("type") != "object":
        raise ValueError(f"{cls}: a viewer schema's root must be an object")
    return out


def _plain(node: dict[str, Any], defs: dict[str, Any], *, path: str) -> dict[str, Any]:
    if "$ref" in node:
        name = node["$ref"].rsplit("/", 1)[-1]
        rest = {k: v for k, v in node.items() if k != "$ref"}
        return _plain({**defs[name], **rest}, defs, path=path)
    if "anyOf" in node:
        # An optional value: the viewer sees its type; absence (null) needs no type of its own.
        options = [o for o in node["anyOf"] if o.get("type") != "null"]
        if len(options) != 1:
            raise ValueError(f"{path}: a union of {len(options)} types has no viewer form")
        rest = {k: v for k, v in node.items() if k not in ("anyOf", "default")}
        return _plain({**options[0], **rest}, defs, path=path)
    out = {k: v for k, v in node.items() if k not in ("prefixItems", "items", "properties")}
    kind = node.get("type")
    if isinstance(kind, list):
        kinds = [k for k in kind if k != "null"]
        if len(kinds) != 1:
            raise ValueError(f"{path}: types {kind} have no viewer form")
        kind = out["type"] = kinds[0]
    if "enum" in node and kind is None:
        values = node["enum"]
        if all(isinstance(v, str) for v in values):
            kind = out["type"] = "string"
        elif all(isinstance(v, int) and not isinstance(v, bool) for v in values):
            kind = out["type"] = "integer"
        else:
            raise ValueError(f"{path}: an enum of mixed values has no viewer form")
    if kind == "array":
        if "prefixItems" in node:
            items = [_plain(i, defs, path=f"{path}[]") for i in node["prefixItems"]]
            if any(i != items[0] for i in items):
                raise ValueError(f"{path}: a tuple of different types has no viewer form")
            out["items"] = items[0]
            out["minItems"] = out["maxItems"] = len(items)
        else:
            out["items"] = _plain(node.get("items", {}), defs, path=f"{path}[]")
    elif kind == "object":
        out["properties"] = {
            name: _plain(value, defs, path=f"{path}.{name}")
            for name, value in node.get("properties", {}).items()
        }
        if isinstance(node.get("additionalProperties"), dict):
            out["additionalProperties"] = _plain(
                node["additionalProperties"], defs, path=f"{path}{{}}"
            )
    elif kind not in _PLAIN:
        raise ValueError(f"{path}: no viewer form for {node}")
    return out


def without_nulls(value: Any) -> Any:
    """A JSON value with every null member left out (absent means None to every decoder).

    The message form its viewer schema describes: an optional field there has its value's
    type, so a null would fail a JSON Schema validator.
    """
    if isinstance(value, dict):
        return {k: without_nulls(v) for k, v in value.items() if v is not None}
    if isinstance(value, list):
        return [without_nulls(v) for v in value]
    return value


def viewer_rules(schema: dict[str, Any], *, path: str = "") -> list[str]:
    """Where `schema` leaves the viewers' dialect (empty when it does not)."""
    problems: list[str] = []
    if schema.get("type") != "object":
        return [f'{path or "root"}: not "type": "object"']
    if not isinstance(schema.get("properties"), dict):
        return [f'{path or "root"}: an object without "properties"']
    for name, field in schema["properties"].items():
        where = f"{path}.{name}" if path else name
        kind = field.get("type")
        if kind in ("boolean", "number", "integer"):
            continue
        if kind == "string":
            if field.get("contentEncoding") not in (None, "base64"):
                problems.append(f"{where}: contentEncoding {field['contentEncoding']!r}")
        elif kind == "object":
            problems += viewer_rules(field, path=where)
        elif kind == "array":
            items = field.get("items")
            if not isinstance(items, dict):
                problems.append(f'{where}: an array without one "items" schema')
                continue
            item_kind = items.get("type")
            if item_kind == "object":
                problems += viewer_rules(items, path=f"{where}[]")
            elif item_kind == "string" and items.get("contentEncoding") is not None:
                problems.append(f"{where}[]: an encoded string in an array")
            elif item_kind not in ("boolean", "string", "number", "integer"):
                problems.append(f"{where}[]: item type {item_kind!r}")
        else:
            problems.append(f"{where}: type {kind!r}")
    return problems
