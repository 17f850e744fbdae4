"""Options and client of the commands that talk to a running server (``export``, ``sessions``)."""

from __future__ import annotations

import argparse
import os

__all__ = ["add_server_options", "client_of"]

DEFAULT_SERVER = "http://127.0.0.1:8000"


def add_server_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--server", default=None,
                   help=f"server URL (default PEDNAV_SERVER, else {DEFAULT_SERVER}: a 'pednav serve' on this machine)")
    p.add_argument("--token", default=None, help="bearer token (default PEDNAV_TOKEN; 'pednav admin create-user' prints one)")


def client_of(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    """A :class:`clients.sdk.PednavClient` for ``--server``/``--token`` (or their environment variables); a
    :class:`clients.cli.UserError` when no token is given or the URL is not one."""
    from clients.errors import UserError
    from clients.sdk import PednavClient

    server = args.server or os.environ.get("PEDNAV_SERVER") or DEFAULT_SERVER
    if not server.startswith(("http://", "https://")):
        raise UserError(f"--server {server!r}: expected a URL such as {DEFAULT_SERVER}", 2)
    token = args.token or os.environ.get("PEDNAV_TOKEN")
    if not token:
        raise UserError("a token is required: --token TOKEN or PEDNAV_TOKEN (create one with "
                        "'pednav admin create-user NAME')", 2)
    return PednavClient(server, token, retries=1, backoff_s=0.2)
