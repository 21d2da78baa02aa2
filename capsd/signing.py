"""Authenticated payloads: an HMAC-SHA256 tag over the key expression and the payload bytes.

The site's locator tags every fix with the site's fix key; the ROV's bridge acts only on fixes
whose tag it can check with the same key, whatever router carried them (BlueOS's router has
no access control). The tag covers the key expression, so a fix for one vehicle cannot be
replayed to another, and the payload bytes, which hold the measurement stamp and `seq`: a
replayed or reordered fix carries an old stamp, which the bridge's gate refuses.

The tag travels in the Zenoh attachment after the 8-byte put time (capsd.runner). Standard
library only: the ROV's install has no cryptography package, and a shared key between the two
services that need it is all the promise "only the locator moves the ROV" requires.
"""

from __future__ import annotations

import hashlib
import hmac
import logging
import os
import stat
from pathlib import Path
from typing import Literal

from capsd.errors import ConfigError

logger = logging.getLogger(__name__)

TAG_BYTES = 32
KEY_BYTES = 32


class SiteKey:
    """The site's fix key: tags and checks payloads."""

    def __init__(self, secret: bytes):
        if len(secret) != KEY_BYTES:
            raise ValueError(f"a fix key is {KEY_BYTES} bytes, not {len(secret)}")
        self._secret = secret

    @staticmethod
    def generate() -> SiteKey:
        return SiteKey(os.urandom(KEY_BYTES))

    @staticmethod
    def load(path: Path, *, config_key: str) -> SiteKey:
        """The key from a file of 64 hex digits; errors name the file and the config key."""
        try:
            text = path.read_text(encoding="ascii").strip()
            mode = path.stat().st_mode
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(str(path), config_key, f"cannot read the fix key: {exc}") from None
        try:
            secret = bytes.fromhex(text)
        except ValueError:
            raise ConfigError(str(path), config_key, "not a hex key") from None
        if len(secret) != KEY_BYTES:
            raise ConfigError(
                str(path), config_key, f"the key is {len(secret)} bytes, expected {KEY_BYTES}"
            )
        if mode & (stat.S_IRWXG | stat.S_IRWXO):
            raise ConfigError(
                str(path),
                config_key,
                f"readable by others (mode {stat.S_IMODE(mode):04o}): chmod 0400 it",
            )
        return SiteKey(secret)

    def hex(self) -> str:
        return self._secret.hex()

    def tag(self, key_expr: str, payload: bytes | memoryview) -> bytes:
        mac = hmac.new(self._secret, key_expr.encode(), hashlib.sha256)
        mac.update(b"\0")
        mac.update(payload)
        return mac.digest()

    def verify(self, key_expr: str, payload: bytes | memoryview, tag: bytes) -> bool:
        return len(tag) == TAG_BYTES and hmac.compare_digest(self.tag(key_expr, payload), tag)


def write_key(path: Path, key: SiteKey) -> None:
    """Write a key file readable by its owner only."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o400)
    with os.fdopen(fd, "w", encoding="ascii") as out:
        out.write(key.hex() + "\n")


def site_key(
    *, auth: Literal["required", "off"], path: str | None, needed_for: str
) -> SiteKey | None:
    """The site's fix key a service's config names, or None with `auth: off` (a bench).

    Required and not named: a ConfigError at the `fix_key` field saying what it is needed for.
    """
    if auth == "off":
        logger.warning("fix_auth is off: %s without the site's key", needed_for)
        return None
    if path is None:
        raise ConfigError(
            "config",
            "fix_key",
            f"{needed_for} needs the site's fix key: give its path "
            "(deploy/security/make-site-certs.sh writes fix.key), or `fix_auth: off` on a bench",
        )
    return SiteKey.load(Path(path), config_key="fix_key")
