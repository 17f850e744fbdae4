"""Bearer tokens: random secrets handed out once, stored only as SHA-256 hashes."""

from __future__ import annotations

import hashlib
import secrets

__all__ = ["new_token", "hash_token"]


def new_token() -> str:
    """A fresh URL-safe token (256 bits)."""
    return "pn_" + secrets.token_urlsafe(32)


def hash_token(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()
