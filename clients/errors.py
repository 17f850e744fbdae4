"""The error a command raises for an ordinary user mistake (``clients.cli.main`` prints it as one line)."""

from __future__ import annotations

__all__ = ["UserError"]


class UserError(Exception):
    """An ordinary mistake a command found: ``pednav`` prints ``error: <message>`` and exits with ``code``
    (1 refused, 2 wrong usage, 3 server unreachable)."""

    def __init__(self, message: str, code: int = 1) -> None:
        super().__init__(message)
        self.code = code
