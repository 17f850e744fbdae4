"""Bearer-token authentication with expiry, and a per-user request rate limit.

Every request with a token resolves it by its SHA-256 (one indexed SELECT): unknown, revoked and expired tokens
get 401 with a message that says which (an expired token names its expiry time). A valid token then draws
from its user's bucket: ``rate_limit_per_s`` requests per second on average with bursts of ``rate_limit_burst``;
an empty bucket gets 429 with ``Retry-After``. All tokens of a user share one bucket: with a bucket per token,
a user who minted k tokens had k times the limit. The buckets live in the server process, so with N worker
processes a user may make up to N times the limit (the benchmarks and the default deployment use one).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Hashable
from datetime import datetime, timezone
from typing import Any

from fastapi import HTTPException, status
from sqlalchemy import select
from sqlalchemy.orm import Session

from server.models import Token
from server.security import hash_token

__all__ = ["QUERY_TOKEN_ROUTE", "FailedAuthGuard", "RateLimiter", "admit", "authenticate", "query_token_refused",
           "require_token", "token_expiry"]

_T = Token.__table__


class RateLimiter:
    """Token buckets keyed by user id (any hashable key).

    Parameters
    ----------
    rate_per_s : float
        Sustained requests per second per key; 0 disables the limit.
    burst : int
        Bucket size: requests a key may make at once after being idle.
    max_keys : int
        Buckets kept; the least recently used full ones are dropped beyond this (a full bucket carries no
        information).
    """

    def __init__(self, rate_per_s: float, burst: int, max_keys: int = 100_000) -> None:
        self.rate = float(rate_per_s)
        self.burst = float(burst)
        self.max_keys = max_keys
        self._buckets: dict[Hashable, tuple[float, float]] = {}  # key -> (tokens, last refill time)
        self._lock = threading.Lock()

    @property
    def enabled(self) -> bool:
        return self.rate > 0

    def hit(self, key: Hashable, now: float | None = None) -> float:
        """Take one request from ``key``'s bucket; returns 0 when allowed, else the wait [s] until it would be."""
        if not self.enabled:
            return 0.0
        t = time.monotonic() if now is None else now
        with self._lock:
            tokens, last = self._buckets.get(key, (self.burst, t))
            tokens = min(self.burst, tokens + (t - last) * self.rate)
            if tokens >= 1.0:
                self._buckets[key] = (tokens - 1.0, t)
                if len(self._buckets) > self.max_keys:
                    self._prune(t)
                return 0.0
            self._buckets[key] = (tokens, t)
            return (1.0 - tokens) / self.rate

    def peek(self, key: Hashable, now: float | None = None) -> float:
        """The wait [s] until ``key`` may make a request (0: now), taking nothing from its bucket."""
        if not self.enabled:
            return 0.0
        t = time.monotonic() if now is None else now
        with self._lock:
            tokens, last = self._buckets.get(key, (self.burst, t))
        tokens = min(self.burst, tokens + (t - last) * self.rate)
        return 0.0 if tokens >= 1.0 else (1.0 - tokens) / self.rate

    def _prune(self, t: float) -> None:
        full = [k for k, (tok, last) in self._buckets.items() if tok + (t - last) * self.rate >= self.burst]
        for k in full:
            del self._buckets[k]


class FailedAuthGuard:
    """Failed authentications per client address: ``burst`` of them at once, then ``rate_per_s`` on average; a
    client past that gets 429 with ``Retry-After`` for every request that carries a token, before its token is
    looked up. Invalid tokens were not limited at all (the rate limit is per user, and an invalid token has no
    user): 1,000 guesses at ~300 requests/s each cost a database lookup.

    The address is the peer the server sees (behind a load balancer run uvicorn with ``--proxy-headers`` and
    ``--forwarded-allow-ips`` so that it is the client's). Kept per server process.
    """

    def __init__(self, rate_per_s: float, burst: int) -> None:
        self.limiter = RateLimiter(rate_per_s, burst)

    def check(self, client: str | None) -> None:
        """429 when ``client`` has used up its failures (call before looking the token up)."""
        wait = self.limiter.peek(client)
        if wait > 0:
            raise HTTPException(
                status.HTTP_429_TOO_MANY_REQUESTS,
                f"too many failed authentications from this client: at most {self.limiter.rate:g} per second "
                f"(bursts of {self.limiter.burst:g}); retry in {wait:.2f} s",
                headers={"Retry-After": str(max(1, math.ceil(wait)))},
            )

    def failed(self, client: str | None) -> None:
        """Count one failed authentication (401) of ``client``."""
        self.limiter.hit(client)


def _unauthorized(detail: str) -> HTTPException:
    return HTTPException(status.HTTP_401_UNAUTHORIZED, detail, headers={"WWW-Authenticate": "Bearer"})


QUERY_TOKEN_ROUTE = "POST /v1/sensorlogger"
"""The only route that takes its token as the ``token`` query parameter: the Sensor Logger app cannot set headers.
Everywhere else a token in the URL would end up in access logs (of this server and of every proxy on the way)."""


def query_token_refused() -> HTTPException:
    """401 for a request that carries ``?token=`` on a route other than :data:`QUERY_TOKEN_ROUTE` (refused even
    with a valid ``Authorization`` header: the client is told before its tokens spread through more logs)."""
    return _unauthorized(
        "token in the query string (?token=) is refused on this route: URLs end up in access logs; send the header "
        f"'Authorization: Bearer <token>' (only {QUERY_TOKEN_ROUTE} takes ?token=, for the Sensor Logger app)"
    )


def require_token(token: str | None) -> str:
    """``token`` itself, or 401 when the request carried none."""
    if not token:
        raise _unauthorized("missing bearer token (header 'Authorization: Bearer <token>')")
    return token


def authenticate(db: Session, token: str | None, limiter: RateLimiter | None) -> int:
    """The user id of a valid token, after taking one request from its user's rate limit.

    Raises
    ------
    HTTPException
        401 missing / invalid / revoked / expired token; 429 rate limit exceeded (``Retry-After`` set).
    """
    h = hash_token(require_token(token))
    row = db.execute(select(_T.c.user_id, _T.c.revoked, _T.c.expires_at).where(_T.c.token_hash == h)).first()
    return admit(h, row, limiter)


def token_expiry(expires_at: Any) -> datetime | None:
    """A token's ``expires_at`` as a driver reads it (raw SQLite rows: SQLAlchemy's text form of a UTC
    datetime; naive datetimes are UTC) as an aware datetime, or None (never expires)."""
    if expires_at is None:
        return None
    if isinstance(expires_at, str):
        expires_at = datetime.fromisoformat(expires_at)
    return expires_at if expires_at.tzinfo else expires_at.replace(tzinfo=timezone.utc)


def admit(h: str, row: Any, limiter: RateLimiter | None) -> int:
    """The user id of the token whose hash is ``h`` and whose row ``(user_id, revoked, expires_at)`` was read
    (``None``: no such token), after taking one request from its user's rate limit (shared by all the user's
    tokens); raises as :func:`authenticate`."""
    if row is None or row[0] is None:
        raise _unauthorized("invalid token")
    user_id, revoked = row[0], row[1]
    if revoked:
        raise _unauthorized("token revoked")
    exp = token_expiry(row[2])
    if exp is not None:
        if exp <= datetime.now(timezone.utc):
            raise _unauthorized(
                f"token expired at {exp.isoformat(timespec='seconds')}; mint a new one (POST /v1/tokens with a valid "
                "token, or 'pednav admin token NAME')"
            )
    if limiter is not None:
        wait = limiter.hit(int(user_id))
        if wait > 0:
            raise HTTPException(
                status.HTTP_429_TOO_MANY_REQUESTS,
                f"rate limit exceeded: at most {limiter.rate:g} requests/s per user, shared by all of the user's "
                f"tokens (bursts of {limiter.burst:g}); retry in {wait:.2f} s",
                headers={"Retry-After": str(max(1, math.ceil(wait)))},
            )
    return int(user_id)
