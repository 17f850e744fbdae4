"""``pednav serve``: run the REST API with uvicorn (migrations applied once before the workers start).

Prints where it serves (the URL, the web viewer, the OpenAPI page) and the database it uses, then logs one
structured line per request at ``--log-level info`` (the default) or lower.
"""

from __future__ import annotations

import argparse
import os
import sys

__all__ = ["register", "describe_database"]

LEVELS = ("critical", "error", "warning", "info", "debug")


def describe_database(url: str) -> str:
    """The database URL as a person should read it: a SQLite file as its absolute path (a relative
    ``sqlite:///pednav.db`` is a file in the current folder, another file in another folder)."""
    from sqlalchemy.engine import make_url

    u = make_url(url)
    if u.get_backend_name() == "sqlite":
        db = u.database or ""
        if db in ("", ":memory:"):
            return f"{url} (in memory: nothing is kept)"
        path = os.path.abspath(db)
        return f"sqlite:///{path} ({'exists' if os.path.exists(path) else 'new: created now'})"
    return u.render_as_string(hide_password=True)


def database_source(args_url: str | None) -> str:
    if args_url:
        return "--database-url"
    if os.environ.get("PEDNAV_DATABASE_URL"):
        return "PEDNAV_DATABASE_URL"
    return "default: pednav.db in the current folder"


def _run(args: argparse.Namespace) -> int:
    import uvicorn

    from clients.cli import _version
    from clients.errors import UserError
    from server.app import configure_logging
    from server.db import make_engine, migrate
    from server.settings import SettingsError, load_settings

    if args.database_url:
        os.environ["PEDNAV_DATABASE_URL"] = args.database_url
    try:
        settings = load_settings()  # validates PEDNAV_* now: a bad value fails before anything starts
    except SettingsError as exc:
        raise UserError(str(exc), 2) from None
    if not 0 < args.port < 65536:
        raise UserError(f"--port {args.port}: must be 1-65535", 2)
    if args.workers < 1:
        raise UserError(f"--workers {args.workers}: must be at least 1", 2)
    import socket

    try:  # a port in use: one clear line now, not uvicorn's error after the migrations
        with socket.socket(socket.AF_INET6 if ":" in args.host else socket.AF_INET) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind((args.host, args.port))
    except OSError as exc:
        raise UserError(f"cannot listen on {args.host}:{args.port}: {exc.strerror or exc} "
                        "(another server running? use --port)", 1) from None
    where = describe_database(settings.database_url)
    eng = make_engine(settings)
    migrate(eng)
    eng.dispose()
    os.environ["PEDNAV_MIGRATE_ON_STARTUP"] = "false"  # done above, not once per worker
    os.environ["PEDNAV_LOG_LEVEL"] = args.log_level  # the workers configure their logging from it
    configure_logging(args.log_level)
    host = f"[{args.host}]" if ":" in args.host else args.host
    url = f"http://{host}:{args.port}"
    print(f"pednav {_version()} serving {url}\n"
          f"  web viewer  {url}/app\n"
          f"  API docs    {url}/docs (OpenAPI: {url}/openapi.json)\n"
          f"  database    {where} [{database_source(args.database_url)}; 'pednav admin' must use the same]\n"
          f"  navigates   a foot-mounted sensor\n"
          f"  log level   {args.log_level} (one JSON line per request at info)\n"
          "Ctrl-C stops it.", file=sys.stderr, flush=True)
    uvicorn.run(
        "server.app:app_from_env", factory=True, host=args.host, port=args.port, workers=args.workers,
        log_level=args.log_level, access_log=False,  # pednav.access logs requests without their query strings
    )
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("serve", help="run the REST API and the web viewer (OpenAPI page at /docs, viewer at /app)",
                       description="Run the REST API and the web viewer. The database is --database-url, else "
                                   "PEDNAV_DATABASE_URL, else the SQLite file pednav.db in the current folder; "
                                   "'pednav admin' decides it the same way and both print it.")
    p.add_argument("--host", default="127.0.0.1", help="bind address (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=8000, help="port (default 8000)")
    p.add_argument("--database-url", default=None,
                   help="SQLAlchemy URL (default PEDNAV_DATABASE_URL or sqlite:///pednav.db in the current folder)")
    p.add_argument("--workers", type=int, default=1, help="uvicorn worker processes (default 1)")
    p.add_argument("--log-level", default="info", choices=LEVELS, type=str.lower,
                   help="log level (default info: one JSON line per request on the pednav.access logger)")
    p.set_defaults(func=_run)
