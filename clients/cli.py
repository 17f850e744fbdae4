"""The ``pednav`` command line. Each sub-command lives in its own module under ``clients.commands``.

A command module exposes ``register(subparsers) -> None``, which adds its parser and sets
``func=callable(args) -> int``. Heavy imports happen inside the callables so ``--help`` stays fast.

Ordinary mistakes (a server that does not answer, a refused request, a missing or unreadable file, a database
that cannot be opened, a bad value) end with one line on stderr, ``error: ...``, and a non-zero exit code, never
a traceback (:func:`main`); ``--debug`` shows the traceback as well. Exit codes: 0 success, 1 the request or
input was refused, 2 wrong usage, 3 the server could not be reached, 130 interrupted.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from clients.errors import UserError

__all__ = ["main", "build_parser", "UserError", "PLACEMENTS_NAVIGATED"]

# Order = order in --help.
COMMAND_MODULES: tuple[str, ...] = (
    "clients.commands.demo",
    "clients.commands.eval",
    "clients.commands.bench",
    "clients.commands.energy",
    "clients.commands.serve",
    "clients.commands.admin",
    "clients.commands.replay",
    "clients.commands.export",
    "clients.commands.config",
    "clients.commands.sessions",
)

PLACEMENTS_NAVIGATED = "a foot-mounted sensor (on the shoe); a phone in the hand or a pocket (step-and-heading)"
"""What the engine navigates today; the README and ``--help`` say the same."""


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("pednav")
    except PackageNotFoundError:  # running from a source tree that was never installed
        return "unknown (not installed)"


def _one_line(exc: BaseException) -> tuple[str, int] | None:
    """The message and exit code of an ordinary mistake, None for anything else (a bug: traceback)."""
    import sqlite3

    from clients.sdk import ApiError, Offline

    try:
        from sqlalchemy.exc import OperationalError
    except ImportError:  # pragma: no cover - sqlalchemy is a dependency
        OperationalError = ()  # type: ignore[assignment,misc]
    try:
        import httpx2

        transport: tuple[type[BaseException], ...] = (httpx2.TransportError,)
    except ImportError:  # pragma: no cover
        transport = ()
    if isinstance(exc, UserError):
        return str(exc), exc.code
    if isinstance(exc, ApiError):
        hint = {401: " (check --token / PEDNAV_TOKEN: missing, wrong, expired or revoked)",
                404: " (not found, or it belongs to another user)"}.get(exc.status, "")
        return f"the server refused the request: HTTP {exc.status}: {exc.detail}{hint}", 1
    if isinstance(exc, (Offline, *transport)):
        return f"{exc}; is the server running? (start it with 'pednav serve', or give --server URL)", 3
    if isinstance(exc, (FileNotFoundError, IsADirectoryError, NotADirectoryError, PermissionError)):
        name = getattr(exc, "filename", None)
        return f"{name}: {exc.strerror or exc}" if name else str(exc), 1
    if isinstance(exc, (OperationalError, sqlite3.OperationalError)):
        orig = getattr(exc, "orig", exc)
        return f"database: {orig} (check --database-url / PEDNAV_DATABASE_URL)", 1
    return None


def _database_help() -> str:
    return ("database of 'serve' and 'admin': --database-url, else PEDNAV_DATABASE_URL, else sqlite:///pednav.db "
            "in the current folder (server.settings.Settings.database_url); both commands print the one they use")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pednav",
        description="Energy-aware pedestrian navigation: evaluation, benchmarks, energy simulation, server. "
                    f"Placements navigated today: {PLACEMENTS_NAVIGATED}.",
        epilog=_database_help(),
    )
    parser.add_argument("--version", action="version", version=f"pednav {_version()}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    parser.add_argument("--debug", action="store_true", help="show the traceback of an error as well")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:  # command not written yet
                continue
            raise
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - ordinary mistakes get one line; anything else is re-raised
        said = _one_line(exc)
        if said is None:
            raise
        if args.debug:
            import traceback

            traceback.print_exc()
        print(f"error: {said[0]}", file=sys.stderr)
        return said[1]


if __name__ == "__main__":
    raise SystemExit(main())
