"""``pednav serve``: run the REST API with uvicorn (migrations applied once before the workers start)."""

from __future__ import annotations

import argparse
import os

__all__ = ["register"]


def _run(args: argparse.Namespace) -> int:
    import uvicorn

    from server.db import make_engine, migrate
    import sys

    from server.settings import SettingsError, load_settings

    if args.database_url:
        os.environ["PEDNAV_DATABASE_URL"] = args.database_url
    try:
        settings = load_settings()  # validates PEDNAV_* now: a bad value fails before anything starts
    except SettingsError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    eng = make_engine(settings)
    migrate(eng)
    eng.dispose()
    os.environ["PEDNAV_MIGRATE_ON_STARTUP"] = "false"  # done above, not once per worker
    uvicorn.run(
        "server.app:app_from_env", factory=True, host=args.host, port=args.port, workers=args.workers,
        log_level=args.log_level,
    )
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("serve", help="run the REST API (OpenAPI page at /docs)")
    p.add_argument("--host", default="127.0.0.1", help="bind address (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=8000, help="port (default 8000)")
    p.add_argument("--database-url", default=None,
                   help="SQLAlchemy URL (default PEDNAV_DATABASE_URL or sqlite:///pednav.db in the current folder)")
    p.add_argument("--workers", type=int, default=1, help="uvicorn worker processes (default 1)")
    p.add_argument("--log-level", default="warning", help="uvicorn log level (default warning)")
    p.set_defaults(func=_run)
