"""``pednav admin``: bootstrap users and tokens, run migrations (direct database access, no server needed)."""

from __future__ import annotations

import argparse
import json
import os
import sys

__all__ = ["register"]


def _settings(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    from server.settings import Settings

    if args.database_url:
        os.environ["PEDNAV_DATABASE_URL"] = args.database_url
    return Settings()


def _db(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    from server.db import make_engine, make_sessionmaker, migrate

    eng = make_engine(_settings(args))
    migrate(eng)
    return eng, make_sessionmaker(eng)


def _create_user(args: argparse.Namespace) -> int:
    from sqlalchemy.exc import IntegrityError

    from server import crud

    eng, sm = _db(args)
    try:
        with sm() as db:
            try:
                user, token = crud.create_user(db, args.name, is_admin=args.admin)
                db.commit()
            except IntegrityError:
                print(f"error: user {args.name!r} already exists (use 'pednav admin token {args.name}')", file=sys.stderr)
                return 1
        out = {"user_id": user.id, "token": token}
    finally:
        eng.dispose()
    print(json.dumps(out) if args.json else f"user {args.name} (id {out['user_id']}), token: {token}")
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
            token = crud.issue_token(db, user, "cli")
            db.commit()
            out = {"user_id": user.id, "token": token}
    finally:
        eng.dispose()
    print(json.dumps(out) if args.json else f"token for {args.name}: {token}")
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
    common(c)
    c.set_defaults(func=_create_user)
    t = asub.add_parser("token", help="issue another token for an existing user")
    t.add_argument("name")
    common(t)
    t.set_defaults(func=_token)
    m = asub.add_parser("migrate", help="upgrade the database schema to the latest version")
    common(m)
    m.set_defaults(func=_migrate)
