"""``pednav sessions list|show|close|delete|anchor``: a user's sessions on a running server."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from clients.commands._server import add_server_options, client_of
from clients.commands.export import _session_id

__all__ = ["register"]


def _line(s: dict[str, Any]) -> str:
    anchor = (f"{s['latitude_deg']:.5f},{s['longitude_deg']:.5f}" if s.get("latitude_deg") is not None else "no anchor")
    return (f"{s['id']:>6}  {s['status']:<6}  {s['device_kind']:<6}  {s['created_at'][:19]}  "
            f"{s['n_positions']:>6} positions  {s['mode']:<5}  {anchor}")


def _list(args: argparse.Namespace) -> int:
    with client_of(args) as api:
        rows = api.sessions(args.status)
    if args.json:
        print(json.dumps(rows))
    elif not rows:
        print("no sessions")
    else:
        print(f"{'id':>6}  {'status':<6}  {'device':<6}  {'created (UTC)':<19}  {'positions':>16}  {'mode':<5}  anchor")
        for s in rows:
            print(_line(s))
    return 0


def _show(args: argparse.Namespace) -> int:
    with client_of(args) as api:
        s = api.session(args.session)
    if args.json:
        print(json.dumps(s))
        return 0
    for k, v in s.items():
        if k != "sensor_config":
            print(f"{k:<18} {v}")
    return 0


def _close(args: argparse.Namespace) -> int:
    with client_of(args) as api:
        s = api.close_session(args.session)
    print(json.dumps(s) if args.json else f"session {s['id']} closed ({s['n_positions']} positions)")
    return 0


def _delete(args: argparse.Namespace) -> int:
    if not args.yes:
        from clients.errors import UserError

        raise UserError(f"deleting session {args.session} removes its batches, positions and events for good; "
                        "add --yes to confirm", 2)
    with client_of(args) as api:
        api.delete_session(args.session)
    print(json.dumps({"deleted": args.session}) if args.json else f"session {args.session} deleted", file=sys.stdout)
    return 0


def _anchor(args: argparse.Namespace) -> int:
    from clients.errors import UserError
    from models.geo import parse_anchor

    if args.remove:
        body: dict[str, Any] = {"latitude_deg": None, "longitude_deg": None}
    elif args.position:
        try:
            a = parse_anchor(args.position, source="user")
        except ValueError as exc:
            raise UserError(str(exc), 2) from None
        body = {"latitude_deg": a.latitude_deg, "longitude_deg": a.longitude_deg, "altitude_m": a.altitude_m}
        if args.date:
            body["anchor_date"] = args.date
    else:
        raise UserError("give LAT,LON[,ALT] or --remove", 2)
    with client_of(args) as api:
        s = api.patch_session(args.session, **body)
    if args.json:
        print(json.dumps(s))
    elif s["latitude_deg"] is None:
        print(f"session {s['id']}: anchor removed")
    else:
        print(f"session {s['id']}: anchored at {s['latitude_deg']}, {s['longitude_deg']}, {s['altitude_m']} m "
              f"(declination {s['declination_deg']:.2f} deg on {s['anchor_date'] or s['created_at'][:10]})")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sessions", help="list, show, close, delete or anchor your sessions on a server")
    ssub = p.add_subparsers(dest="sessions_cmd", metavar="ACTION", required=True)

    def common(q: argparse.ArgumentParser) -> None:
        add_server_options(q)
        q.add_argument("--json", action="store_true", help="print JSON")

    q = ssub.add_parser("list", help="your sessions, oldest first")
    q.add_argument("--status", choices=("open", "closed"), default=None)
    common(q)
    q.set_defaults(func=_list)
    for name, fn, hlp in (("show", _show, "one session"), ("close", _close, "close a session (its last positions "
                          "are computed and your calibration profile updated)")):
        q = ssub.add_parser(name, help=hlp)
        q.add_argument("session", type=_session_id)
        common(q)
        q.set_defaults(func=fn)
    q = ssub.add_parser("delete", help="delete a session with its batches, positions and events (profiles stay)")
    q.add_argument("session", type=_session_id)
    q.add_argument("--yes", action="store_true", help="confirm")
    common(q)
    q.set_defaults(func=_delete)
    q = ssub.add_parser("anchor", help="set (LAT,LON[,ALT]) or remove (--remove) a session's anchor")
    q.add_argument("session", type=_session_id)
    q.add_argument("position", nargs="?", default=None, metavar="LAT,LON[,ALT]")
    q.add_argument("--date", default=None, metavar="YYYY-MM-DD", help="date of the magnetic declination")
    q.add_argument("--remove", action="store_true", help="remove the anchor")
    common(q)
    q.set_defaults(func=_anchor)
