"""Wire codec: payload Struct <-> bytes, with the Zenoh encoding `application/<fmt>;<Schema>`."""

from __future__ import annotations

from typing import Any, Generic, TypeVar

import msgspec

from capsd.errors import PayloadError
from capsd.payloads import ALL_PAYLOADS, Payload

P = TypeVar("P", bound=Payload)

_MIME = {"json": "application/json", "msgpack": "application/msgpack"}


def schema_name(cls: type[Payload]) -> str:
    """The schema name a payload class carries on the wire (its class name unless overridden)."""
    name = cls.__dict__.get("SCHEMA_NAME")
    return name if isinstance(name, str) else cls.__name__


def schema_version(cls: type[Payload]) -> int:
    """The schema major version this build reads and writes for `cls`."""
    for field in msgspec.structs.fields(cls):
        if field.name == "schema_version":
            return int(field.default)
    raise TypeError(f"{cls.__name__} has no schema_version field")


def encoding_of(cls: type[Payload]) -> str:
    """The Zenoh encoding string for `cls`, e.g. `application/json;RovFix`."""
    return f"{_MIME[cls.WIRE]};{schema_name(cls)}"


SCHEMAS: dict[str, type[Payload]] = {schema_name(cls): cls for cls in ALL_PAYLOADS}


def split_encoding(encoding: str) -> tuple[str, str | None]:
    """Split `application/json;Schema` into its MIME type and schema (None if absent)."""
    mime, sep, schema = encoding.partition(";")
    return mime, (schema if sep else None)


class Codec(Generic[P]):
    """Encoder and decoder for one payload type; decoding validates and checks the version."""

    def __init__(self, cls: type[P]):
        self.cls = cls
        self.schema = schema_name(cls)
        self.version = schema_version(cls)
        self.encoding = encoding_of(cls)
        self.mime = _MIME[cls.WIRE]
        self._decoder: msgspec.json.Decoder[P] | msgspec.msgpack.Decoder[P]
        if cls.WIRE == "json":
            self._encoder: msgspec.json.Encoder | msgspec.msgpack.Encoder = msgspec.json.Encoder()
            self._decoder = msgspec.json.Decoder(cls)
        else:
            self._encoder = msgspec.msgpack.Encoder()
            self._decoder = msgspec.msgpack.Decoder(cls)

    def encode(self, payload: P) -> bytes:
        return self._encoder.encode(payload)

    def decode(self, data: bytes, *, encoding: str | None, key_expr: str) -> P:
        """Decode and validate `data`; raise PayloadError naming the key, schema and reason."""
        if encoding is not None:
            mime, schema = split_encoding(encoding)
            if mime != self.mime or schema != self.schema:
                raise PayloadError(
                    key_expr, self.schema, f"encoding is '{encoding}', expected '{self.encoding}'"
                )
        try:
            payload = self._decoder.decode(data)
        except (msgspec.DecodeError, msgspec.ValidationError) as exc:
            raise PayloadError(key_expr, self.schema, str(exc)) from None
        if payload.schema_version != self.version:
            raise PayloadError(
                key_expr,
                self.schema,
                f"schema version {payload.schema_version} is not readable by this build "
                f"(reads version {self.version})",
            )
        return payload


def decode_any(data: bytes, *, encoding: str, key_expr: str) -> Payload:
    """Decode a payload of any known schema named by its encoding (for tools like `capsd tap`)."""
    _, schema = split_encoding(encoding)
    cls = SCHEMAS.get(schema or "")
    if cls is None:
        raise PayloadError(key_expr, schema or "?", f"unknown schema in encoding '{encoding}'")
    return Codec(cls).decode(data, encoding=encoding, key_expr=key_expr)


def to_builtins(payload: Payload, *, bytes_as: str = "summary") -> dict[str, Any]:
    """A JSON-ready dict of `payload`; bulky `bytes` fields are summarised unless asked in full."""

    def enc_hook(obj: Any) -> Any:
        raise TypeError(f"cannot convert {type(obj).__name__}")

    result = msgspec.to_builtins(payload, enc_hook=enc_hook)
    assert isinstance(result, dict)
    if bytes_as == "summary":
        for name in payload.__struct_fields__:
            value = getattr(payload, name)
            if isinstance(value, bytes | memoryview):
                result[name] = f"<{len(value)} bytes>"
    return result
