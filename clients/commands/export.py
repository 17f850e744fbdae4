"""``pednav export SESSION``: a session's trajectory from the server as JSON, GeoJSON or CSV."""

from __future__ import annotations

import argparse
import json
import os
import sys

__all__ = ["register"]


def _run(args: argparse.Namespace) -> int:
    from clients.sdk import ApiError, PednavClient

    token = args.token or os.environ.get("PEDNAV_TOKEN")
    if not token:
        print("error: --token or PEDNAV_TOKEN is required", file=sys.stderr)
        return 2
    with PednavClient(args.server, token, retries=2) as api:
        try:
            doc = api.trajectory(args.session, args.format)
        except ApiError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 1
    text = doc if isinstance(doc, str) else json.dumps(doc, indent=None if args.output else 2)
    if args.output:
        with open(args.output, "w", encoding="utf-8") as fh:
            fh.write(text)
    else:
        sys.stdout.write(text if text.endswith("\n") else text + "\n")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export", help="export a session's trajectory (JSON, GeoJSON, CSV)")
    p.add_argument("session", type=int, help="session id")
    p.add_argument("--server", default=os.environ.get("PEDNAV_SERVER", "http://127.0.0.1:8000"), help="server URL")
    p.add_argument("--token", default=None, help="bearer token (default PEDNAV_TOKEN)")
    p.add_argument("--format", choices=("json", "geojson", "csv"), default="json")
    p.add_argument("-o", "--output", default=None, help="write to this file instead of stdout")
    p.add_argument("--json", action="store_true", help="(accepted for symmetry; JSON formats print JSON)")
    p.set_defaults(func=_run)
