"""``pednav replay FILE``: stream a recording through the HTTP API or a local engine (same positions), at its
recorded rates or, with ``--rate-hz``, de-sampled as a sensor set to a lower rate would have delivered it."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

__all__ = ["register", "load_recording", "desampled", "replay_local", "replay_server"]


def load_recording(spec: str, mag_scale_ut: float | None = None, columns: str | None = None,  # type: ignore[no-untyped-def]
                   units: str | None = None):
    """A file of any importable format, or a synthetic scenario name (``clients.synth.scenario_names()``).

    ``mag_scale_ut``: the field [uT] a normalised magnetometer's 1.0 stands for (gaitmap/Xsens CSV files, whose
    magnetometer is otherwise left out); a ValueError for any other recording. ``columns`` and ``units`` (both or
    neither): any CSV read with the stated columns and units (:mod:`clients.importers.generic_csv`)."""
    if (columns is None) != (units is None):
        raise ValueError("--columns and --units go together: state the columns and the unit of each stream")
    if columns is not None and units is not None:
        if not Path(spec).is_file():
            raise FileNotFoundError(f"{spec}: no such file (--columns/--units read a CSV file)")
        from clients.importers.generic_csv import load_generic_csv

        return load_generic_csv(spec, columns, units)
    if Path(spec).exists():
        from clients.importers import importer_for, load

        if mag_scale_ut is None:
            return load(spec)
        m = importer_for(spec)
        if m is None or m.__name__ != "clients.importers.gaitmap":
            raise ValueError(f"{spec}: --mag-scale-ut applies to normalised-magnetometer files (gaitmap/Xsens CSV) only")
        return m.load_gaitmap(spec, mag_scale_ut=mag_scale_ut)
    from clients.synth import scenario_names, synthesize

    if spec in scenario_names():
        if mag_scale_ut is not None:
            raise ValueError(f"{spec}: --mag-scale-ut applies to normalised-magnetometer files only, not to synthetic scenarios")
        return synthesize(spec)
    raise FileNotFoundError(f"{spec}: no such file and not a synthetic scenario ({', '.join(scenario_names())})")


def _doc(rows: list[tuple[int, float, float, float, str, str, bool]], t0_ns: int) -> dict[str, Any]:
    n = len(rows)
    modes: dict[str, float] = {}
    for r in rows:
        modes[r[5]] = modes.get(r[5], 0) + 1
    return {
        "positions": [[(t - t0_ns) / 1e9, nn, e, d] for t, nn, e, d, _, _, _ in rows],
        "labels": [[b, m, bool(g)] for _, _, _, _, b, m, g in rows],
        "modes": {k: v / n for k, v in sorted(modes.items())} if n else {},
    }


def replay_local(rec, batch_seconds: float, mode: str = "auto") -> dict[str, Any]:  # type: ignore[no-untyped-def]
    """Device emulation through a local engine (no server)."""
    from energy.device import replay
    from energy.engine import Engine

    res = replay(Engine(mode=mode), rec.batch, batch_seconds)  # type: ignore[arg-type]
    rows = [(p.t_ns, p.north, p.east, p.down, p.behaviour, p.mode, p.gyro_on) for p in res.positions]
    return {**_doc(rows, int(rec.batch.t_start_ns)), "gyro_on_fraction": res.gyro_on_fraction}


def replay_server(rec, server: str, token: str, batch_seconds: float, device: str = "foot") -> dict[str, Any]:  # type: ignore[no-untyped-def]
    """The same device emulation, streamed through the HTTP API (lossless msgpack bodies)."""
    from clients.sdk import PednavClient
    from clients.simulators import simulator_for

    with PednavClient(server, token, encoding="msgpack", float_dtype="<f8") as api:
        res = simulator_for(device, rec, batch_seconds).run(api)
    rows = [(p["t_ns"], p["north"], p["east"], p["down"], p["behaviour"], p["mode"], p["gyro_on"]) for p in res.positions]
    return {**_doc(rows, int(rec.batch.t_start_ns)), "gyro_on_fraction": res.gyro_on_fraction, "session_id": res.session_id}


def desampled(rec, rate_hz: float):  # type: ignore[no-untyped-def]
    """``rec`` as a sensor set to ``rate_hz`` would have recorded it (:func:`energy.device.desample`:
    anti-aliased, each stream by the whole factor nearest to its rate / ``rate_hz``, none up-sampled), with a
    note of the rates it now has."""
    from dataclasses import replace

    from energy.device import desample
    from models.batch import STREAMS

    batch = desample(rec.batch, rate_hz)
    rates = []
    for name in STREAMS:
        if len(rec.batch.stream(name)[0]) > 1:
            old, new = rec.batch.rate_hz(name), batch.rate_hz(name)
            kept = abs(new - old) <= 1e-6 * old
            rates.append(f"{name} {old:.4g} Hz kept" if kept else f"{name} {old:.4g} -> {new:.4g} Hz")
    note = f"--rate-hz {rate_hz:g}: de-sampled (anti-aliasing FIR, whole decimation factors): {', '.join(rates)}"
    meta = replace(rec.meta, rate_hz=float(batch.rate_hz("acc")), notes=(*rec.meta.notes, note))
    return replace(rec, batch=batch, meta=meta)


def _run(args: argparse.Namespace) -> int:
    try:
        if args.mag_scale_ut is not None and not args.mag_scale_ut > 0:
            raise ValueError(f"--mag-scale-ut must be a positive field in uT, got {args.mag_scale_ut}")
        if args.rate_hz is not None and not args.rate_hz > 0:
            raise ValueError(f"--rate-hz must be a positive rate in Hz, got {args.rate_hz}")
        rec = load_recording(args.file, args.mag_scale_ut, args.columns, args.units)
    except (FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    if args.rate_hz is not None:
        rec = desampled(rec, args.rate_hz)
    if len(rec.batch.gyr_t_ns) == 0:
        # every engine mode starts on the ZUPT-KF, which integrates the gyroscope: without one the replay
        # would end with no position at all and look like a success
        print(f"error: {args.file}: the recording has no gyroscope samples; the engine needs a gyroscope to start "
              "(record or export the gyroscope too)", file=sys.stderr)
        return 1
    # a recording whose format says where it was worn (a foot dataset) is taken as it says; any other (a phone app,
    # a generic CSV, an x-io sensor) must show a foot's stance phases before it is navigated as a foot
    if args.device == "foot" and not args.skip_foot_check and not rec.meta.mount.startswith("foot"):
        import numpy as np

        from models.placement import check_foot

        b = rec.batch
        if np.array_equal(b.acc_t_ns, b.gyr_t_ns):
            verdict = check_foot((b.acc_t_ns - b.acc_t_ns[0]) / 1e9, b.acc, b.gyr)
            if verdict.looks_like_foot is False:
                print(f"error: {args.file}: {verdict.reason}; replay it with --device phone or --device watch, or pass "
                      "--skip-foot-check to navigate it as a foot anyway", file=sys.stderr)
                return 1
    if args.server:
        token = args.token or os.environ.get("PEDNAV_TOKEN")
        if not token:
            print("error: --token (or PEDNAV_TOKEN) is required with --server", file=sys.stderr)
            return 2
        doc = replay_server(rec, args.server, token, args.batch_seconds, args.device)
    else:
        doc = replay_local(rec, args.batch_seconds, args.mode)
    doc["notes"] = list(rec.meta.notes)  # what the importer repaired or left out
    if args.json:
        print(json.dumps(doc))
    else:
        for note in doc["notes"]:
            print(f"note: {note}", file=sys.stderr)
        print(f"{rec.name}: {len(doc['positions'])} positions, modes {doc['modes']}, gyro on {doc['gyro_on_fraction']:.0%}")
        if doc["positions"]:
            t, n, e, d = doc["positions"][-1]
            print(f"final position at t={t:.1f} s: north {n:.2f} m, east {e:.2f} m, down {d:.2f} m")
        if "session_id" in doc:
            print(f"session {doc['session_id']}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("replay", help="stream a recording through the API (--server) or a local engine")
    p.add_argument("file", help="recording file (any importable format) or synthetic scenario name")
    p.add_argument("--server", default=None, help="server URL, e.g. http://127.0.0.1:8000 (default: local engine)")
    p.add_argument("--token", default=None, help="bearer token (default PEDNAV_TOKEN)")
    p.add_argument("--batch-seconds", type=float, default=1.0, help="seconds per uploaded batch (default 1)")
    p.add_argument("--device", choices=("foot", "phone", "watch"), default="foot", help="device kind of the session")
    p.add_argument("--mode", choices=("auto", "zupt", "pdr"), default="auto",
                   help="local engine mode (the server uses its own configured mode)")
    p.add_argument("--mag-scale-ut", type=float, default=None, metavar="UT",
                   help="field [uT] that a normalised magnetometer's 1.0 stands for (gaitmap/Xsens CSV: the field "
                        "at their calibration site); without it such a magnetometer is left out")
    p.add_argument("--rate-hz", type=float, default=None, metavar="HZ",
                   help="replay the recording as a sensor set to HZ would have recorded it: every stream faster "
                        "than HZ is low-passed (anti-aliasing FIR) and decimated by the whole factor nearest to its "
                        "rate / HZ (200 Hz at --rate-hz 50: every 4th sample); slower streams are kept, nothing is "
                        "up-sampled; the rates used are in the notes (default: the recorded rates)")
    p.add_argument("--columns", default=None, metavar="SPEC",
                   help="read FILE as a CSV with these columns: 'time=COL,acc=COL:COL:COL[,gyr=...][,mag=...]', COL a "
                        "header name or #N (1-based); needs --units")
    p.add_argument("--units", default=None, metavar="SPEC",
                   help="units of the --columns streams: 'time=s|ms|us|ns,acc=m/s^2|g|mg,gyr=rad/s|deg/s,"
                        "mag=uT|nT|mT|G|mG'")
    p.add_argument("--skip-foot-check", action="store_true",
                   help="navigate as a foot even a recording of a phone app, x-io sensor or --columns CSV that shows "
                        "no stance phases at a stride's rhythm (models.placement: a phone or a wrist, or a foot that "
                        "did not walk); recordings of foot datasets are not checked")
    p.add_argument("--json", action="store_true", help="print one JSON document")
    p.set_defaults(func=_run)
