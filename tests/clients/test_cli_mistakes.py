"""Ordinary mistakes a user makes with the ``pednav`` command end with one clear ``error:`` line and a non-zero exit,
never a traceback. Each is run as a real process, as a person would type it."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, str]]:
    """A running server with one user, an unanchored session and a closed port nothing listens on."""
    from clients.commands.demo import LocalServer
    from server import crud

    db = tmp_path_factory.mktemp("mistakes") / "pednav.db"
    with LocalServer(f"sqlite:///{db}") as srv:
        with srv.app.state.sessionmaker() as s:
            _, token = crud.create_user(s, "mistaken")
            s.commit()
        import httpx2

        r = httpx2.post(f"{srv.url}/v1/sessions", json={"device_kind": "foot"}, headers={"Authorization": f"Bearer {token}"})
        with socket.socket() as sk:  # a port with no server behind it
            sk.bind(("127.0.0.1", 0))
            closed = sk.getsockname()[1]
        yield {"url": srv.url, "port": str(srv.port), "token": token, "session": str(r.json()["id"]),
               "db": f"sqlite:///{db}", "closed": f"http://127.0.0.1:{closed}"}
        if srv.app.state.host.pool is not None:
            srv.app.state.host.pool.shutdown()


# (name, argv with {placeholders}, exit code, a phrase the error line must hold)
MISTAKES = [
    ("server not running", ["export", "1", "--server", "{closed}", "--token", "x"], 3, "is the server running"),
    ("export without --server and none running", ["export", "1", "--token", "x"], 3, "is the server running"),
    ("export without a token", ["export", "1", "--server", "{url}"], 2, "token is required"),
    ("wrong token", ["export", "{session}", "--server", "{url}", "--token", "pn_wrong"], 1, "HTTP 401"),
    ("session of nobody", ["export", "999999", "--server", "{url}", "--token", "{token}"], 1, "HTTP 404"),
    ("session id not a number", ["export", "first", "--server", "{url}", "--token", "{token}"], 2, "not a session id"),
    ("GPX of an unanchored session", ["export", "{session}", "--server", "{url}", "--token", "{token}", "--format", "gpx"],
     1, "anchor"),
    ("server URL without scheme", ["sessions", "list", "--server", "127.0.0.1:8000", "--token", "{token}"], 2, "expected a URL"),
    ("delete without confirmation", ["sessions", "delete", "{session}", "--server", "{url}", "--token", "{token}"], 2, "--yes"),
    ("anchor out of range", ["sessions", "anchor", "{session}", "95,10", "--server", "{url}", "--token", "{token}"], 2, "latitude_deg"),
    ("missing recording", ["replay", "no-such-walk.csv"], 1, "no such file"),
    ("a folder for a recording", ["replay", "{tmp}"], 1, "folder"),
    ("negative rate", ["replay", "walk", "--rate-hz", "-5"], 1, "--rate-hz"),
    ("zero batch length", ["replay", "walk", "--batch-seconds", "0"], 1, "--batch-seconds"),
    ("anchor not numbers", ["replay", "walk", "--anchor", "north,east"], 1, "numbers"),
    ("anchor latitude out of range", ["replay", "walk", "--anchor", "95,10"], 1, "latitude_deg"),
    ("export format unknown", ["replay", "walk", "--export", "walk.shp"], 1, "unknown suffix"),
    ("GPX without anchor", ["replay", "walk", "--export", "walk.gpx"], 1, "--anchor"),
    ("replay to a stopped server", ["replay", "walk", "--server", "{closed}", "--token", "x"], 3, "is the server running"),
    ("port out of range", ["serve", "--port", "70000"], 2, "--port"),
    ("port in use", ["serve", "--port", "{port}"], 1, "cannot listen"),
    ("bad database URL", ["serve", "--database-url", "mysql://x/y"], 2, "PEDNAV_DATABASE_URL"),
    ("database in a missing folder", ["admin", "create-user", "x", "--database-url", "sqlite:////no/such/folder/p.db"],
     1, "database"),
    ("user exists", ["admin", "create-user", "mistaken", "--database-url", "{db}"], 1, "already exists"),
    ("token lifetime too short", ["admin", "token", "mistaken", "--ttl-s", "10", "--database-url", "{db}"], 2, "at least 60"),
    ("unknown command", ["navigate"], 2, "invalid choice"),
    ("unknown scenario", ["energy", "simulate", "--scenario", "marathon"], 2, "unknown scenario"),
    ("bad log level", ["serve", "--log-level", "loud"], 2, "invalid choice"),
]


@pytest.mark.parametrize("name, argv, code, phrase", MISTAKES, ids=[m[0] for m in MISTAKES])
def test_an_ordinary_mistake_ends_with_one_clear_line(server, tmp_path: Path, name: str, argv: list[str], code: int,
                                                      phrase: str) -> None:
    args = [a.format(tmp=tmp_path, **server) for a in argv]
    env = {k: v for k, v in os.environ.items() if not k.startswith("PEDNAV_")}
    env["PEDNAV_SERVER"] = server["closed"] if "without --server" in name else ""
    if not env["PEDNAV_SERVER"]:
        del env["PEDNAV_SERVER"]
    p = subprocess.run([sys.executable, "-m", "clients.cli", *args], cwd=tmp_path, env=env, capture_output=True,
                       text=True, timeout=300)
    err = p.stderr.strip().splitlines()
    assert "Traceback" not in p.stderr, p.stderr
    assert p.returncode == code, (p.returncode, p.stderr)
    assert err and ("error:" in err[-1]) and phrase in err[-1], p.stderr
    assert p.stdout == "", p.stdout


def test_the_list_is_long_enough() -> None:
    assert len(MISTAKES) >= 15


def test_version_and_placements(capsys: pytest.CaptureFixture[str]) -> None:
    from clients.cli import main

    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0 and capsys.readouterr().out.startswith("pednav ")
    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    assert "foot-mounted sensor" in out and "PEDNAV_DATABASE_URL" in out


def test_debug_shows_the_traceback_too(server) -> None:  # type: ignore[no-untyped-def]
    env = {k: v for k, v in os.environ.items() if not k.startswith("PEDNAV_")}
    p = subprocess.run([sys.executable, "-m", "clients.cli", "--debug", "export", "1", "--server", server["closed"],
                        "--token", "x"], env=env, capture_output=True, text=True, timeout=120)
    assert p.returncode == 3 and "Traceback" in p.stderr and p.stderr.strip().splitlines()[-1].startswith("error:")


def test_sessions_commands_against_a_server(server, capsys: pytest.CaptureFixture[str]) -> None:  # type: ignore[no-untyped-def]
    from clients.cli import main

    common = ["--server", server["url"], "--token", server["token"]]
    assert main(["sessions", "list", *common, "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["id"] for r in rows] == [int(server["session"])]
    assert main(["sessions", "anchor", server["session"], "33.64,-117.84,12", *common]) == 0
    assert "declination" in capsys.readouterr().out
    assert main(["sessions", "show", server["session"], *common, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["latitude_deg"] == 33.64
    sid = json.loads(subprocess.run([sys.executable, "-m", "clients.cli", "sessions", "list", *common, "--json"],
                                    capture_output=True, text=True).stdout)[0]["id"]
    assert main(["sessions", "close", str(sid), *common]) == 0
    assert "closed" in capsys.readouterr().out
    assert main(["sessions", "delete", str(sid), "--yes", *common]) == 0
    assert main(["sessions", "list", *common]) == 0
    assert "no sessions" in capsys.readouterr().out
