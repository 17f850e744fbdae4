"""Tokens never reach a log: a logging filter that masks bearer tokens and ``token=`` query values.

``POST /v1/sensorlogger?token=...`` is the one route that takes its token in the URL (the Sensor Logger app
cannot set headers), and a client may put ``?token=`` on any other route (refused with 401): uvicorn's access
log wrote the URL, token and all, for both. The filter rewrites each record's message and arguments before any
handler formats them; install it on the loggers that may see a URL or a header (:func:`install`).
"""

from __future__ import annotations

import logging
import re
from typing import Any

__all__ = ["REDACTED", "RedactTokens", "install", "redact"]

REDACTED = "[redacted]"
_PATTERNS = (
    re.compile(r"(?i)((?:^|[?&;\s])token=)[^&\s\"']*"),  # ?token=..., &token=...
    re.compile(r"(?i)(bearer\s+)[A-Za-z0-9._~+/=-]+"),  # Authorization: Bearer ...
    re.compile(r"()\bpn_[A-Za-z0-9_-]{20,}"),  # a pednav token anywhere (security.new_token's form)
)


def redact(text: str) -> str:
    """``text`` with every token masked."""
    for p in _PATTERNS:
        text = p.sub(lambda m: m.group(1) + REDACTED, text)
    return text


def _clean(v: Any) -> Any:
    return redact(v) if isinstance(v, str) else v


class RedactTokens(logging.Filter):
    """Masks tokens in a record's message and string arguments (the record is kept)."""

    def filter(self, record: logging.LogRecord) -> bool:
        record.msg = _clean(record.msg)
        if isinstance(record.args, tuple):
            record.args = tuple(_clean(a) for a in record.args)
        elif isinstance(record.args, dict):
            record.args = {k: _clean(v) for k, v in record.args.items()}
        return True


LOGGERS = ("uvicorn.access", "uvicorn.error", "uvicorn", "pednav", "pednav.access", "pednav.server")


def install(names: tuple[str, ...] = LOGGERS) -> None:
    """Add :class:`RedactTokens` to each named logger (once)."""
    for name in names:
        log = logging.getLogger(name)
        if not any(isinstance(f, RedactTokens) for f in log.filters):
            log.addFilter(RedactTokens())
