"""``pednav export SESSION``: a session's trajectory from the server as JSON, GeoJSON, GPX, KML or CSV.

GeoJSON (RFC 7946), GPX 1.1 and KML need an anchored session (``pednav sessions anchor``, the API's PATCH, or
the session's start); CSV keeps the NED columns and adds latitude/longitude when anchored. A local replay
writes the same files with ``pednav replay FILE --anchor LAT,LON --export OUT.gpx``. ``--fuse-with WATCH``: a
phone session's steps fused with those of the watch worn on the same walk.
"""

from __future__ import annotations

import argparse
import json
import sys

from clients.commands._server import add_server_options, client_of

__all__ = ["register"]

FORMATS = ("json", "geojson", "gpx", "kml", "csv")


def _run(args: argparse.Namespace) -> int:
    fmt = args.format
    if fmt is None and args.output:
        suffix = args.output.rsplit(".", 1)[-1].lower() if "." in args.output else ""
        fmt = suffix if suffix in FORMATS else "json"
    fmt = fmt or "json"
    with client_of(args) as api:
        doc = api.trajectory(args.session, fmt, fuse_with=args.fuse_with)
    text = doc if isinstance(doc, str) else json.dumps(doc, indent=None if args.output else 2)
    if args.output:
        with open(args.output, "w", encoding="utf-8") as fh:
            fh.write(text)
        print(f"wrote {args.output} ({fmt})", file=sys.stderr)
    else:
        sys.stdout.write(text if text.endswith("\n") else text + "\n")
    return 0


def _session_id(v: str) -> int:
    try:
        n = int(v)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{v!r} is not a session id (a number; 'pednav sessions list' shows them)") from None
    if not 0 < n < 2**63:
        raise argparse.ArgumentTypeError(f"{v!r} is not a session id (a positive number)")
    return n


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export", help="export a session's trajectory from the server (JSON, GeoJSON, GPX, KML, CSV)",
                       description=__doc__.split("\n\n")[0] + " " + __doc__.split("\n\n")[1].replace("\n", " "))
    p.add_argument("session", type=_session_id, help="session id ('pednav sessions list')")
    add_server_options(p)
    p.add_argument("--format", choices=FORMATS, default=None,
                   help="output format (default: by the suffix of --output, else json)")
    p.add_argument("--fuse-with", type=_session_id, default=None, metavar="SESSION",
                   help="a phone session's steps fused with the same walk's watch session (000 eq. 70)")
    p.add_argument("-o", "--output", default=None, help="write to this file instead of stdout")
    p.add_argument("--json", action="store_true", help="(accepted for symmetry; JSON formats print JSON)")
    p.set_defaults(func=_run)
