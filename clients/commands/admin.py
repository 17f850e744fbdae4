"""``pednav admin``: bootstrap users and tokens, run migrations (direct database access, no server needed).

The database is decided as for ``pednav serve`` (--database-url, else PEDNAV_DATABASE_URL, else pednav.db in the
current folder) and printed on stderr, so a token made for one database is not used against a server on another.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

__all__ = ["register"]


def _settings(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    from server.settings import SettingsError, load_settings

    if args.database_url:
        os.environ["PEDNAV_DATABASE_URL"] = args.database_url
    try:
        return load_settings()
    except SettingsError as exc:
        from clients.errors import UserError

        raise UserError(str(exc), 2) from None


def _ttl_arg(v: str) -> int:
    try:
        n = int(v)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{v!r} is not a number of seconds") from None
    if n < 0 or 0 < n < 60:
        raise argparse.ArgumentTypeError("must be 0 (never expires) or at least 60 s")
    return n


def _db(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    from clients.commands.serve import database_source, describe_database
    from server.db import make_engine, make_sessionmaker, migrate

    settings = _settings(args)
    print(f"database: {describe_database(settings.database_url)} [{database_source(args.database_url)}]", file=sys.stderr)
    eng = make_engine(settings)
    migrate(eng)
    return eng, make_sessionmaker(eng)


def _ttl(args: argparse.Namespace) -> float | None:
    """Token lifetime [s]: --ttl-s, else the server's PEDNAV_TOKEN_TTL_S; None = never expires."""
    ttl = args.ttl_s if args.ttl_s is not None else _settings(args).token_ttl_s
    return ttl or None


def _expiry(db, token: str) -> str | None:  # type: ignore[no-untyped-def]
    from sqlalchemy import select

    from server.models import Token
    from server.security import hash_token

    exp = db.execute(select(Token.expires_at).where(Token.token_hash == hash_token(token))).scalar_one()
    return None if exp is None else exp.isoformat(timespec="seconds")


def _create_user(args: argparse.Namespace) -> int:
    from sqlalchemy.exc import IntegrityError

    from server import crud
    from server.schemas import check_user_name

    try:
        check_user_name(args.name)  # as POST /v1/users: "" or a name with blanks or controls was created
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    eng, sm = _db(args)
    try:
        with sm() as db:
            try:
                user, token = crud.create_user(db, args.name, is_admin=args.admin, ttl_s=_ttl(args))
                db.commit()
            except IntegrityError:
                print(f"error: user {args.name!r} already exists (use 'pednav admin token {args.name}')", file=sys.stderr)
                return 1
            out = {"user_id": user.id, "token": token, "expires_at": _expiry(db, token)}
    finally:
        eng.dispose()
    print(json.dumps(out) if args.json else
          f"user {args.name} (id {out['user_id']}), token: {token} (expires {out['expires_at'] or 'never'})")
    return 0


def _token(args: argparse.Namespace) -> int:
    from server import crud

    eng, sm = _db(args)
    try:
        with sm() as db:
            user = crud.user_by_name(db, args.name)
            if user is None:
                print(f"error: no user {args.name!r}", file=sys.stderr)
                return 1
            token = crud.issue_token(db, user, "cli", _ttl(args))
            db.commit()
            out = {"user_id": user.id, "token": token, "expires_at": _expiry(db, token)}
    finally:
        eng.dispose()
    print(json.dumps(out) if args.json else f"token for {args.name}: {token} (expires {out['expires_at'] or 'never'})")
    return 0


def _migrate(args: argparse.Namespace) -> int:
    eng, _ = _db(args)
    eng.dispose()
    print(json.dumps({"migrated": True}) if args.json else "database is at the latest schema")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("admin", help="bootstrap users/tokens and migrate the database")
    asub = p.add_subparsers(dest="admin_cmd", metavar="ACTION", required=True)

    def common(q: argparse.ArgumentParser) -> None:
        q.add_argument("--database-url", default=None, help="SQLAlchemy URL (default PEDNAV_DATABASE_URL or sqlite:///pednav.db)")
        q.add_argument("--json", action="store_true", help="print one JSON document")

    c = asub.add_parser("create-user", help="create a user and print its first token")
    c.add_argument("name")
    c.add_argument("--admin", action="store_true", help="the user may create other users through the API")
    c.add_argument("--ttl-s", type=_ttl_arg, default=None,
                   help="token lifetime [s]; 0 = never expires (default PEDNAV_TOKEN_TTL_S, 30 days)")
    common(c)
    c.set_defaults(func=_create_user)
    t = asub.add_parser("token", help="issue another token for an existing user")
    t.add_argument("name")
    t.add_argument("--ttl-s", type=_ttl_arg, default=None,
                   help="token lifetime [s]; 0 = never expires (default PEDNAV_TOKEN_TTL_S, 30 days)")
    common(t)
    t.set_defaults(func=_token)
    m = asub.add_parser("migrate", help="upgrade the database schema to the latest version")
    common(m)
    m.set_defaults(func=_migrate)
