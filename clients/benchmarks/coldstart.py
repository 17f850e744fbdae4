"""``pednav bench coldstart``: the first minutes of a fresh install, as a device meets them.

Starts ``uvicorn server.app:app_from_env`` (default settings: an engine helper that warms up at start) on a fresh
SQLite file with an EMPTY numba cache directory (``NUMBA_CACHE_DIR``: what a fresh install has; ``--keep-cache``
uses the installed cache instead, a restart), then as one device: opens a session as soon as the port answers,
uploads its first batch (timed: the answer comes at once, a 503 ``Retry-After`` while the engines compile), polls
``/healthz`` until it reports ready, and uploads again (timed: the first accepted batch), then a walking batch.
Traffic stays on 127.0.0.1; the server is stopped at the end.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from typing import Any

__all__ = ["add_arguments", "run"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--keep-cache", action="store_true", help="use the installed numba cache (a restart, not a fresh install)")
    p.add_argument("--timeout", type=float, default=900.0, help="longest wait for readiness [s] (default 900)")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def run(args: argparse.Namespace) -> dict[str, Any]:
    import httpx2

    from clients.sdk import encode_batch
    from clients.synth import synthesize

    tmp = tempfile.TemporaryDirectory(prefix="pednav-cold-")
    env = {**os.environ, "PEDNAV_DATABASE_URL": f"sqlite:///{tmp.name}/cold.db"}
    if not args.keep_cache:
        env["NUMBA_CACHE_DIR"] = f"{tmp.name}/numba-cache"
    out = subprocess.run([sys.executable, "-m", "clients.cli", "admin", "create-user", "cold", "--json"], env=env,
                         capture_output=True, text=True, check=True)
    token = json.loads(out.stdout)["token"]
    parts = synthesize("walk", seed=3, rate_hz=100.0).batch.split_seconds(1.0)
    bodies = [encode_batch(p, "msgpack", "<f8") for p in parts[:12]]
    port = _free_port()
    t0 = time.perf_counter()
    srv = subprocess.Popen([sys.executable, "-m", "uvicorn", "server.app:app_from_env", "--factory", "--host", "127.0.0.1",
                            "--port", str(port), "--log-level", "warning"], env=env)
    h = {"Authorization": f"Bearer {token}"}
    res: dict[str, Any] = {"numba_cache": "installed" if args.keep_cache else "empty (fresh install)"}
    try:
        c = httpx2.Client(base_url=f"http://127.0.0.1:{port}", timeout=args.timeout)
        while True:
            try:
                c.get("/healthz")
                break
            except httpx2.TransportError:
                if srv.poll() is not None:
                    raise RuntimeError(f"server exited with {srv.returncode}") from None
                time.sleep(0.05)
        res["port_answers_s"] = round(time.perf_counter() - t0, 2)
        sid = c.post("/v1/sessions", json={"device_kind": "foot"}, headers=h).json()["id"]

        def upload(seq: int) -> tuple[float, int, str | None]:
            body, ctype = bodies[seq]
            t = time.perf_counter()
            r = c.put(f"/v1/sessions/{sid}/batches/{seq}", content=body, headers={**h, "content-type": ctype})
            return time.perf_counter() - t, r.status_code, r.headers.get("retry-after")

        s, code, ra = upload(0)
        res["first_upload"] = {"answered_s": round(s, 3), "status": code, "retry_after": ra}
        deadline = time.monotonic() + args.timeout
        while c.get("/healthz").status_code != 200:
            if time.monotonic() > deadline:
                raise TimeoutError("not ready in time")
            time.sleep(0.25)
        res["ready_after_start_s"] = round(time.perf_counter() - t0, 1)
        first = 0 if code != 200 else 1
        lat = []
        for seq in range(first, len(bodies)):
            s, code, _ = upload(seq)
            if code != 200:
                raise RuntimeError(f"batch {seq}: HTTP {code} after readiness")
            lat.append(s)
        res["first_accepted_batch_s"] = round(lat[0], 3)
        res["later_batches_max_s"] = round(max(lat[1:]), 3) if len(lat) > 1 else None
        res["batches_after_ready"] = len(lat)
    finally:
        srv.terminate()
        try:
            srv.wait(timeout=30)
        except subprocess.TimeoutExpired:
            srv.kill()
            srv.wait()
        tmp.cleanup()
    res["cpus"] = os.cpu_count()
    res["loadavg_1_5_15_at_end"] = [round(x, 2) for x in os.getloadavg()]
    return res
