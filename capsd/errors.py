"""Exception types of CAP-SD: every error a user can cause names what and where."""

from __future__ import annotations


class CapsdError(Exception):
    """Base of every error CAP-SD raises on purpose."""


class ConfigError(CapsdError):
    """A configuration file or flag is invalid; the message names the file, key path and reason."""

    def __init__(self, source: str, key_path: str, reason: str, *, line: int | None = None):
        self.source = source
        self.key_path = key_path
        self.reason = reason
        self.line = line
        where = f"{source}:{line}" if line is not None else source
        super().__init__(f"config error in {where} at '{key_path or '<root>'}': {reason}")


class PayloadError(CapsdError):
    """A payload could not be decoded or validated; the message names the key and schema."""

    def __init__(self, key_expr: str, schema: str, reason: str):
        self.key_expr = key_expr
        self.schema = schema
        self.reason = reason
        super().__init__(f"bad payload on '{key_expr}' (schema {schema}): {reason}")


class KeyExprError(CapsdError):
    """A key expression is malformed, or a wildcard where a concrete key is required."""


class BusError(CapsdError):
    """The Zenoh session could not be opened or used."""
