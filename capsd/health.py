"""Asking a live service for its Health (its queryable answers with the current state)."""

from __future__ import annotations

import zenoh

from capsd.codec import Codec
from capsd.errors import PayloadError
from capsd.keys import health_key
from capsd.payloads import Health

_CODEC = Codec(Health)


def query_health(
    session: zenoh.Session, *, site: str, vehicle: str, service: str, timeout_s: float = 2.0
) -> Health | None:
    """The service's current Health, or None if it did not answer (in time, or validly)."""
    key = health_key(site, vehicle, service)
    for reply in session.get(key, timeout=timeout_s):
        if reply.ok is None:
            continue
        try:
            return _CODEC.decode(
                reply.ok.payload.to_bytes(), encoding=str(reply.ok.encoding), key_expr=key
            )
        except PayloadError:
            continue
    return None
