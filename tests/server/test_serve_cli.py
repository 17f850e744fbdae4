"""``pednav serve`` says where it serves and which database it uses, and logs each request as one JSON line
(without the query string, where the Sensor Logger push carries its token); ``pednav admin`` prints the same
database."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx2


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_serve_prints_url_database_docs_and_logs_requests(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith("PEDNAV_")}
    port = _free_port()
    adm = subprocess.run([sys.executable, "-m", "clients.cli", "admin", "create-user", "ann", "--json"], cwd=tmp_path,
                         env=env, capture_output=True, text=True, timeout=120)
    assert adm.returncode == 0, adm.stderr
    db = tmp_path / "pednav.db"
    assert f"database: sqlite:///{db} (new: created now) [default: pednav.db in the current folder]" in adm.stderr
    token = json.loads(adm.stdout)["token"]
    p = subprocess.Popen([sys.executable, "-m", "clients.cli", "serve", "--port", str(port), "--log-level", "info"],
                         cwd=tmp_path, env=env, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    try:
        lines: list[str] = []
        deadline = time.monotonic() + 60
        url = f"http://127.0.0.1:{port}"
        while time.monotonic() < deadline:
            try:
                if httpx2.get(url + "/healthz", timeout=1).status_code == 200:
                    break
            except httpx2.TransportError:
                time.sleep(0.2)
        r = httpx2.post(url + f"/v1/sensorlogger?token={token}", json={"messageId": 1, "sessionId": "s", "payload": []})
        assert r.status_code == 200
        assert httpx2.get(url + "/v1/sessions", headers={"Authorization": f"Bearer {token}"}).status_code == 200
        time.sleep(0.5)
    finally:
        p.send_signal(signal.SIGINT)
        try:
            _, err = p.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            p.kill()
            _, err = p.communicate()
    lines = err.splitlines()
    assert f"serving {url}" in err and f"web viewer  {url}/app" in err and f"API docs    {url}/docs" in err
    assert f"database    sqlite:///{db} (exists)" in err and "a foot-mounted sensor" in err
    access = [json.loads(line.split("pednav.access: ", 1)[1]) for line in lines if "pednav.access: " in line]
    paths = [(a["method"], a["path"], a["status"]) for a in access]
    assert ("POST", "/v1/sensorlogger", 200) in paths and ("GET", "/v1/sessions", 200) in paths
    assert all({"ms", "bytes", "client"} <= set(a) for a in access)
    assert token not in err  # the push's ?token= is never logged
