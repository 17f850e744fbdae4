"""``pednav demo``: the README's first command.

Starts the server on SQLite (temporary folder), creates a user, streams a simulated person (stand, walk,
run, turns) from a phone-paired foot sensor through the real HTTP API while printing live positions with a
progress bar, then prints a summary (distance, final error vs truth, time in each mode, gyroscope duty cycle,
energy vs an always-on ZUPT-KF baseline) and writes a PNG of the trajectory with mode/gyroscope timelines.
Needs no datasets.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import socket
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from clients.commands.energy import check_scenario

__all__ = ["register", "run_demo", "LocalServer"]


class LocalServer:
    """uvicorn serving :func:`server.app.create_app` on 127.0.0.1 in a background thread."""

    def __init__(self, database_url: str, port: int = 0) -> None:
        import uvicorn

        from server.app import create_app
        from server.settings import Settings

        self.settings = Settings(database_url=database_url)
        self.app = create_app(self.settings)
        if port == 0:
            with socket.socket() as s:
                s.bind(("127.0.0.1", 0))
                port = s.getsockname()[1]
        self.port = port
        self.server = uvicorn.Server(uvicorn.Config(self.app, host="127.0.0.1", port=port, log_level="error"))
        self.thread = threading.Thread(target=self.server.run, daemon=True)

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def __enter__(self) -> LocalServer:
        self.thread.start()
        deadline = time.monotonic() + 20
        while not self.server.started:
            if time.monotonic() > deadline or not self.thread.is_alive():
                raise RuntimeError("the demo server did not start")
            time.sleep(0.05)
        self._wait_ready(time.monotonic() + 300)
        return self

    def _wait_ready(self, deadline: float) -> None:
        """Wait for ``/healthz`` 200: the engines are loaded, so the first upload is not answered 503."""
        import urllib.error
        import urllib.request

        while True:
            try:
                with urllib.request.urlopen(self.url + "/healthz", timeout=5):
                    return
            except urllib.error.HTTPError as exc:
                if exc.code != 503:
                    raise
            if time.monotonic() > deadline or not self.thread.is_alive():
                raise RuntimeError("the demo server's engines did not get ready")
            time.sleep(0.1)

    def __exit__(self, *exc: object) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=10)
        self.app.state.db_engine.dispose()


def _energy(res: Any, rec: Any, profile_name: str) -> dict[str, Any]:
    """Energy of the streamed session vs the always-on baseline (ZUPT-KF at full rate, all sensors on),
    both accounted by :mod:`energy.power` with the same byte model."""
    from energy.device import replay
    from energy.engine import Engine
    from energy.power import REQUEST_OVERHEAD_BYTES, SAMPLE_BYTES, TIMESTAMP_BYTES, Interval, Timeline, account, load_profile

    prof = load_profile(profile_name)
    t_end = int(rec.batch.t_end_ns)
    intervals, samples = [], {}
    for i, (t0, c) in enumerate(res.configs):
        t1 = res.configs[i + 1][0] if i + 1 < len(res.configs) else t_end
        # what the device really did (a wake-on-motion gyroscope is charged from its wake only)
        spans = res.spans[i] if i < len(res.spans) else [(t0, t1, c["acc_rate_hz"], c["gyr_rate_hz"] if c["gyro_on"] else 0.0, c["mag_rate_hz"])]
        for a, b, acc_hz, gyr_hz, mag_hz in spans:
            a, b = max(a, t0), min(b, t1)
            if b > a:
                intervals.append(Interval(a / 1e9, b / 1e9, acc_hz, gyr_hz, mag_hz))
    batches: dict[str, int] = {}
    for r, b in zip(res.responses, res.stored):
        samples[r["mode"]] = samples.get(r["mode"], 0) + b["n_acc"]
        batches[r["mode"]] = batches.get(r["mode"], 0) + 1
    steps: dict[str, int] = {}
    for p in res.positions:
        steps[p["mode"]] = steps.get(p["mode"], 0) + 1
    nbytes = sum(res.samples_sent.values()) * (SAMPLE_BYTES + TIMESTAMP_BYTES) + len(res.responses) * REQUEST_OVERHEAD_BYTES
    # each engine charged its own measured costs (energy.power.ComputeCosts.for_engine)
    sched = account(Timeline(intervals, samples, steps, nbytes, len(res.responses), batches),
                    dataclasses.replace(prof, compute=prof.compute.for_engine("auto")))
    base_res = replay(Engine(mode="zupt"), rec.batch, 1.0)
    base = account(Timeline.from_replay(base_res, t_end), dataclasses.replace(prof, compute=prof.compute.for_engine("zupt")))
    return {"profile": prof.name, "scheduler_mj": sched.total_mj, "always_on_mj": base.total_mj,
            "ratio": sched.total_mj / base.total_mj if base.total_mj else float("nan"),
            "scheduler_components_mj": dict(sched.components_mj), "always_on_components_mj": dict(base.components_mj)}


def _plot(path: Path, res: Any, rec: Any, t0_ns: int, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pos = np.array([[p["t_ns"], p["north"], p["east"]] for p in res.positions]).reshape(-1, 3)
    modes = [p["mode"] for p in res.positions]
    fig = plt.figure(figsize=(9, 9))
    ax = fig.add_axes((0.1, 0.38, 0.8, 0.57))
    tru = rec.truth.positions if rec.truth is not None and rec.truth.positions is not None else None
    if tru is not None and len(pos):
        i0 = int(np.clip(np.searchsorted(rec.truth.t_ns, int(pos[0, 0])), 0, len(tru) - 1))
        ax.plot(tru[:, 1] - tru[i0, 1], tru[:, 0] - tru[i0, 0], color="0.6", lw=1, label="truth")
    colours = {"zupt": "tab:red", "pdr": "tab:blue", "idle": "tab:gray"}
    for m in sorted(set(modes)):
        sel = np.array([x == m for x in modes])
        ax.plot(pos[sel, 2], pos[sel, 1], "o", ms=3, color=colours.get(m, "k"), label=f"{m} positions")
    ax.plot(pos[:, 2], pos[:, 1], "-", lw=0.6, color="k", alpha=0.5)
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(loc="best", fontsize=8)
    ax.set_title(title)
    t = np.array([(c0 - t0_ns) / 1e9 for c0, _ in res.configs])
    # the sensors as the device ran them (wake-on-motion turns the gyroscope and the full rate on within a batch)
    sp = [s for batch in res.spans for s in batch]
    t_gyro = np.array([(s[0] - t0_ns) / 1e9 for s in sp]) if sp else t
    gyro = np.array([s[3] > 0 for s in sp], dtype=float) if sp else np.array([c["gyro_on"] for _, c in res.configs], dtype=float)
    rate = np.array([s[2] for s in sp]) if sp else np.array([c["acc_rate_hz"] for _, c in res.configs])
    mode_of = [r["mode"] for r in res.responses]
    ax2 = fig.add_axes((0.1, 0.2, 0.8, 0.1))
    names = ["idle", "zupt", "pdr"]
    ax2.step(t[: len(mode_of)], [names.index(m) if m in names else -1 for m in mode_of], where="post", color="tab:purple")
    ax2.set_yticks(range(len(names)), names)
    ax2.set_ylabel("mode")
    ax3 = fig.add_axes((0.1, 0.06, 0.8, 0.1), sharex=ax2)
    ax3.fill_between(t_gyro, 0, gyro, step="post", color="tab:red", alpha=0.4, label="gyroscope on")
    ax3b = ax3.twinx()
    ax3b.step(t_gyro, rate, where="post", color="tab:green", label="acc rate [Hz]")
    ax3.set_yticks([0, 1], ["off", "on"])
    ax3.set_ylabel("gyro")
    ax3b.set_ylabel("acc Hz")
    ax3.set_xlabel("time [s]")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run_demo(workdir: Path, plot_path: Path, scenario: str = "demo", seed: int = 0, quiet: bool = False) -> dict[str, Any]:
    """Run the demo; returns the summary dict (also used by tests)."""
    from tqdm import tqdm

    from clients.sdk import PednavClient
    from clients.simulators import FootSensorSimulator
    from clients.synth import synthesize
    from server import crud

    from clients.warmup import warm_up

    rec = synthesize(scenario, seed=seed)
    rec2 = synthesize(scenario, seed=seed + 1)  # the same person another day
    # compile (first run) or load the kernels now, announced, so the streaming bar below measures streaming
    warm_up([rec.batch, rec2.batch], show=not quiet)
    t0_ns = int(rec.batch.t_start_ns)
    with LocalServer(f"sqlite:///{workdir / 'pednav.db'}") as srv:
        with srv.app.state.sessionmaker() as db:
            _, token = crud.create_user(db, f"demo-{int(time.time())}")
            db.commit()
        if not quiet:
            print(f"server: {srv.url} (OpenAPI at {srv.url}/docs), database {workdir / 'pednav.db'}")
        with PednavClient(srv.url, token, float_dtype="<f4") as api:
            # the bar starts with the first answer (the first batch's round trip would skew the estimate of the rest)
            if not quiet:
                print("streaming the walk through the API ...", file=sys.stderr, flush=True)
            bars: list[Any] = []

            def progress(frac: float, new: list[dict[str, Any]]) -> None:
                if not bars:
                    bars.append(tqdm(total=100, initial=round(frac * 100, 1), unit="%", desc="streaming", disable=quiet,
                                     file=sys.stderr, bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f}% [{elapsed}<{remaining}] {postfix}"))
                bar = bars[0]
                bar.n = round(frac * 100, 1)
                if new:
                    p = new[-1]
                    bar.set_postfix_str(f"t={(p['t_ns'] - t0_ns) / 1e9:5.1f}s N={p['north']:7.2f} E={p['east']:7.2f} "
                                        f"{p['behaviour']}/{p['mode']} gyro={'on' if p['gyro_on'] else 'off'}")
                bar.refresh()

            start = {"latitude_deg": 43.6629, "longitude_deg": -79.3957, "altitude_m": 100.0}
            sim = FootSensorSimulator(rec, batch_seconds=None)
            res = sim.run(api, start=start, progress=progress)
            for bar in bars:
                bar.close()
            res.stored = api._json("GET", f"/v1/sessions/{res.session_id}/batches")  # type: ignore[attr-defined]
            geo = api.trajectory(res.session_id, "geojson")
            # the same person another day: closing the first session stored their calibration profile on the
            # server, which the new session uses (Gait-DR after one examination instead of an initialisation)
            if not quiet:
                print("second walk, same user (the server now has their calibration profile) ...", file=sys.stderr)
            res2 = FootSensorSimulator(rec2, batch_seconds=None).run(api, start=start)
            res2.stored = api._json("GET", f"/v1/sessions/{res2.session_id}/batches")  # type: ignore[attr-defined]
    pos = np.array([[p["t_ns"], p["north"], p["east"], p["down"]] for p in res.positions]).reshape(-1, 4)
    steps = np.linalg.norm(np.diff(pos[:, 1:3], axis=0), axis=1) if len(pos) > 1 else np.zeros(0)
    final_err = float("nan")
    if rec.truth is not None and rec.truth.positions is not None and len(pos):
        from energy.simulate import position_errors

        errs = position_errors(pos[:, 0].astype(np.int64), pos[:, 1:3], rec.truth.t_ns, rec.truth.positions[:, :2])
        final_err = errs["final_m"]
        truth_len = float(np.sum(np.linalg.norm(np.diff(rec.truth.positions[:, :2], axis=0), axis=1)))
    else:
        truth_len = float("nan")
    mode_time: dict[str, float] = {}
    for (c0, _), r, i in zip(res.configs, res.responses, range(len(res.responses))):
        c1 = res.configs[i + 1][0] if i + 1 < len(res.configs) else int(rec.batch.t_end_ns)
        mode_time[r["mode"]] = mode_time.get(r["mode"], 0.0) + (c1 - c0) / 1e9
    energy = _energy(res, rec, "foot-lsm9ds1")
    energy2 = _energy(res2, rec2, "foot-lsm9ds1")
    plot2 = plot_path.with_name(f"{plot_path.stem}-second-walk{plot_path.suffix}")
    _plot(plot_path, res, rec, t0_ns, "pednav demo: foot sensor streamed through the REST API (first walk)")
    _plot(plot2, res2, rec2, int(rec2.batch.t_start_ns),
          "pednav demo: the same person again, on the calibration profile the server stored")
    summary = {
        "session_id": res.session_id,
        "duration_s": res.duration_s,
        "positions": len(pos),
        "distance_m": float(steps.sum()),
        "truth_distance_m": truth_len,
        "final_error_m": final_err,
        "time_in_mode_s": {k: round(v, 1) for k, v in sorted(mode_time.items())},
        "gyro_duty_cycle": res.gyro_on_fraction,
        "bytes_uploaded": res.bytes_sent,
        "energy": energy,
        "geojson_points": len(geo["features"][0]["geometry"]["coordinates"]),
        "plot": str(plot_path),
        "returning_user": {
            "session_id": res2.session_id,
            "final_error_m": _final_error(res2, rec2),
            "gyro_duty_cycle": res2.gyro_on_fraction,
            "energy": energy2,
            "plot": str(plot2),
        },
    }
    return summary


def _final_error(res: Any, rec: Any) -> float:
    """Horizontal error of the last position against the synthetic truth [m]."""
    from energy.simulate import position_errors

    pos = np.array([[p["t_ns"], p["north"], p["east"]] for p in res.positions]).reshape(-1, 3)
    if not len(pos) or rec.truth is None or rec.truth.positions is None:
        return float("nan")
    return float(position_errors(pos[:, 0].astype(np.int64), pos[:, 1:3], rec.truth.t_ns, rec.truth.positions[:, :2])["final_m"])


def _print_summary(s: dict[str, Any]) -> None:
    e = s["energy"]
    print()
    print("summary")
    print(f"  distance walked/run      {s['distance_m']:8.1f} m   (truth {s['truth_distance_m']:.1f} m)")
    print(f"  final error vs truth     {s['final_error_m']:8.2f} m")
    print("  time in each mode        " + ", ".join(f"{k} {v:.0f} s" for k, v in s["time_in_mode_s"].items()))
    print(f"  gyroscope duty cycle     {s['gyro_duty_cycle']:8.0%}")
    print(f"  energy ({e['profile']})  {e['scheduler_mj']:.0f} mJ vs always-on {e['always_on_mj']:.0f} mJ "
          f"= {e['ratio']:.0%}")
    print(f"  uploaded                 {s['bytes_uploaded'] / 1024:8.1f} KiB in {s['duration_s']:.0f} s")
    r = s["returning_user"]
    print(f"  same user, second walk   gyroscope {r['gyro_duty_cycle']:.0%}, energy {r['energy']['ratio']:.0%} of always-on, "
          f"final error {r['final_error_m']:.2f} m (calibration profile from the first walk)")
    print(f"  plot                     {s['plot']}")
    print(f"  plot, second walk        {s['returning_user']['plot']}")


def _run(args: argparse.Namespace) -> int:
    check_scenario(args.scenario)
    if not args.json:
        print(f"pednav demo: a simulated person (scenario {args.scenario!r}) streamed through a local server "
              "and back", file=sys.stderr, flush=True)
    plot = Path(args.plot).resolve()
    with tempfile.TemporaryDirectory(prefix="pednav-demo-") as tmp:
        workdir = Path(args.dir).resolve() if args.dir else Path(tmp)
        workdir.mkdir(parents=True, exist_ok=True)
        summary = run_demo(workdir, plot, args.scenario, args.seed, quiet=args.json)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        _print_summary(summary)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="start a local server and stream a simulated walk/run through it")
    p.add_argument("--scenario", default="demo", help="synthetic scenario (default: demo = stand, walk, run, turns)")
    p.add_argument("--seed", type=int, default=0, help="seed of the synthetic person")
    p.add_argument("--dir", default=None, help="keep the SQLite database here (default: a temporary folder)")
    p.add_argument("--plot", default="pednav-demo.png", help="PNG written here (default ./pednav-demo.png)")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON document")
    p.set_defaults(func=_run)
