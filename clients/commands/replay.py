"""``pednav replay FILE``: stream a recording through the HTTP API or a local engine (same positions), at its
recorded rates or, with ``--rate-hz``, de-sampled as a sensor set to a lower rate would have delivered it.

With ``--anchor LAT,LON[,ALT]`` the positions are geo-referenced by :func:`models.geo.georeference`, the function
the server applies when it serves an anchored session: locally to the engine's output, through the API by the
server (the session is started with the anchor and its trajectory read back), so both ways give the same
positions. ``--export FILE`` writes them as GeoJSON, GPX, KML or CSV (by the file's suffix)."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

__all__ = ["register", "load_recording", "desampled", "replay_local", "replay_local_track", "replay_server", "export_track"]

EXPORT_SUFFIXES = {".geojson": "geojson", ".gpx": "gpx", ".kml": "kml", ".csv": "csv"}


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
    from clients.phone_synth import PHONE_SCENARIOS, synthesize_phone
    from clients.synth import scenario_names, synthesize

    if spec in scenario_names() or spec in PHONE_SCENARIOS:
        if mag_scale_ut is not None:
            raise ValueError(f"{spec}: --mag-scale-ut applies to normalised-magnetometer files only, not to synthetic scenarios")
        return synthesize(spec) if spec in scenario_names() else synthesize_phone(spec)
    names = [*scenario_names(), *PHONE_SCENARIOS]
    raise FileNotFoundError(f"{spec}: no such file and not a synthetic scenario ({', '.join(names)})")


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


def replay_local(rec, batch_seconds: float, mode: str = "auto", anchor=None, spec=None) -> dict[str, Any]:  # type: ignore[no-untyped-def]
    """Device emulation through a local engine (no server); with ``anchor`` (:class:`models.geo.Anchor`) the
    positions geo-referenced as the server serves them; ``spec`` (:class:`energy.engines.EngineSpec`) picks the
    engine as a server session would (default: a foot sensor)."""
    return replay_local_track(rec, batch_seconds, mode, anchor, spec)[0]


def replay_local_track(rec, batch_seconds: float, mode: str = "auto", anchor=None, spec=None):  # type: ignore[no-untyped-def]
    """:func:`replay_local`'s document, its :class:`models.geo.GeoTrack` and :class:`models.track_export.TrackLabels`."""
    import numpy as np

    from energy.device import replay
    from energy.engines import new_engine
    from models.geo import engine_north, georeference, magnetic_north_of
    from models.track_export import TrackLabels

    engine = new_engine(mode, None, spec)
    res = replay(engine, rec.batch, batch_seconds)
    north_in = engine_north(getattr(type(engine), "NORTH_REFERENCE", None), res.samples_sent.get("mag", 0) > 0)
    col = {f: np.array([getattr(p, f) for p in res.positions], dtype=float) for f in ("north", "east", "down", "heading_rad")}
    az = magnetic_north_of((e.kind, e.detail) for u in res.updates for e in u.events)
    track = georeference(col["north"], col["east"], col["down"], col["heading_rad"], anchor, north_in, az)
    rows = [(p.t_ns, float(track.north[i]), float(track.east[i]), p.down, p.behaviour, p.mode, p.gyro_on)
            for i, p in enumerate(res.positions)]
    doc = {**_doc(rows, int(rec.batch.t_start_ns)), "gyro_on_fraction": res.gyro_on_fraction, **track.frame_dict()}
    if track.latitude_deg is not None:
        doc["geodetic"] = [[float(a), float(b), float(c)] for a, b, c in zip(track.latitude_deg, track.longitude_deg, track.altitude_m)]  # type: ignore[arg-type]
    ps = res.positions
    labels = TrackLabels([p.t_ns for p in ps], [p.behaviour for p in ps], [p.mode for p in ps],
                         [p.step_length_m for p in ps], [p.gyro_on for p in ps])
    return doc, track, labels


def replay_server(rec, server: str, token: str, batch_seconds: float, device: str = "foot", anchor=None,  # type: ignore[no-untyped-def]
                  placement: str | None = "foot") -> dict[str, Any]:
    """The same device emulation, streamed through the HTTP API (lossless msgpack bodies); with ``anchor`` the
    session is started anchored; ``placement`` as the client states it (None: recognised by the server); the
    trajectory, geo-referenced by the server, is read back."""
    from clients.sdk import PednavClient
    from clients.simulators import simulator_for

    start = None if anchor is None else {
        "latitude_deg": anchor.latitude_deg, "longitude_deg": anchor.longitude_deg, "altitude_m": anchor.altitude_m,
        "anchor_date": anchor.date.isoformat()}
    with PednavClient(server, token, encoding="msgpack", float_dtype="<f8") as api:
        sim = simulator_for(device, rec, batch_seconds, placement)
        sim.placement = placement
        res = sim.run(api, start=start)
        traj = api.trajectory(res.session_id)
    pos = traj["positions"]  # as the server serves them: turned to magnetic north once the engine has found it
    rows = [(p["t_ns"], p["north"], p["east"], p["down"], p["behaviour"], p["mode"], p["gyro_on"]) for p in pos]
    doc = {**_doc(rows, int(rec.batch.t_start_ns)), "gyro_on_fraction": res.gyro_on_fraction,
           "session_id": res.session_id, **{k: traj[k] for k in ("north", "declination_deg", "dip_deg", "magnetic_model", "anchor") if k in traj}}
    if anchor is not None:
        doc["geodetic"] = [[p["latitude_deg"], p["longitude_deg"], p["altitude_m"]] for p in pos]
    return doc


def export_track(track, labels, path: str, name: str = "pednav replay") -> str:  # type: ignore[no-untyped-def]
    """Write a track (:func:`replay_local_track`) to ``path`` as GeoJSON, GPX, KML or CSV (by the suffix); returns
    the format. ``ValueError`` for an unknown suffix or a geographic format without an anchor."""
    import json as _json

    from models.track_export import to_csv, to_geojson, to_gpx, to_kml

    fmt = EXPORT_SUFFIXES.get(Path(path).suffix.lower())
    if fmt is None:
        raise ValueError(f"--export {path}: unknown suffix (use {', '.join(EXPORT_SUFFIXES)})")
    if fmt != "csv" and track.anchor is None:
        raise ValueError(f"--export {path}: {fmt} needs --anchor LAT,LON[,ALT]")
    if fmt == "geojson":
        text = _json.dumps(to_geojson(track, labels), allow_nan=False)
    elif fmt == "csv":
        text = to_csv(track, labels)
    else:
        text = (to_gpx if fmt == "gpx" else to_kml)(track, labels, name)
    Path(path).write_text(text, encoding="utf-8")
    return fmt


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


def _spec(args: argparse.Namespace, rec: Any, anchor: Any) -> Any:
    """The engine the session gets: device kind (given, else the recording's mount), placement (given, else the
    kind's own; a phone's recognised), the anchor (the WMM field the compass is weighed against)."""
    import datetime as dt

    from energy.engines import EngineSpec, check_spec

    device = args.device or (rec.meta.mount if rec.meta.mount in ("foot", "phone", "watch") else "foot")
    placement = {"recognise": None, None: None if device == "phone" else device}.get(args.placement, args.placement)
    check_spec(device, placement)
    where = None if anchor is None else (float(anchor.latitude_deg), float(anchor.longitude_deg), float(anchor.altitude_m))
    day = anchor.date if anchor is not None else dt.datetime.now(dt.timezone.utc).date()
    return EngineSpec(device, placement, where, day)


def _anchor_date(args: argparse.Namespace, rec) -> Any:  # type: ignore[no-untyped-def]
    """--anchor-date, else the recording's UTC date when its sample times are UTC, else today (UTC)."""
    import datetime as dt

    from models.geo import date_of

    if args.anchor_date:
        try:
            return dt.date.fromisoformat(args.anchor_date)
        except ValueError:
            raise ValueError(f"--anchor-date {args.anchor_date!r}: expected YYYY-MM-DD") from None
    return date_of(int(rec.batch.t_start_ns or 0)) or dt.datetime.now(dt.timezone.utc).date()


def _run(args: argparse.Namespace) -> int:
    from models.geo import parse_anchor

    try:
        if args.mag_scale_ut is not None and not args.mag_scale_ut > 0:
            raise ValueError(f"--mag-scale-ut must be a positive field in uT, got {args.mag_scale_ut}")
        if args.rate_hz is not None and not args.rate_hz > 0:
            raise ValueError(f"--rate-hz must be a positive rate in Hz, got {args.rate_hz}")
        if not args.batch_seconds > 0:
            raise ValueError(f"--batch-seconds must be a positive duration in s, got {args.batch_seconds}")
        if args.export and Path(args.export).suffix.lower() not in EXPORT_SUFFIXES:
            raise ValueError(f"--export {args.export}: unknown suffix (use {', '.join(EXPORT_SUFFIXES)})")
        if args.export and args.server:
            raise ValueError("--export writes a local replay; with --server use 'pednav export SESSION --format F'")
        if args.anchor_date and not args.anchor:
            raise ValueError("--anchor-date needs --anchor LAT,LON[,ALT]")
        rec = load_recording(args.file, args.mag_scale_ut, args.columns, args.units)
        # --anchor, else where the recording says it started (a phone's first good location fix)
        anchor = parse_anchor(args.anchor, _anchor_date(args, rec), source="replay") if args.anchor else rec.meta.anchor
        if args.export and Path(args.export).suffix.lower() != ".csv" and anchor is None:
            raise ValueError(f"--export {args.export}: a geographic format needs --anchor LAT,LON[,ALT] (the "
                             "recording has no location fix to anchor it)")
    except (FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    if args.rate_hz is not None:
        rec = desampled(rec, args.rate_hz)
    try:
        spec = _spec(args, rec, anchor)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if spec.pipeline == "foot":
        from clients.recording import require_gyroscope

        try:
            require_gyroscope(rec, args.file)
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 1
    if spec.pipeline != "foot" and len(rec.batch.gyr_t_ns) == 0 and len(rec.batch.mag_t_ns) == 0:
        # step and heading: steps from the accelerometer, but the heading needs a gyroscope or a magnetometer
        print(f"error: {args.file}: the recording has no gyroscope samples and no magnetometer samples: nothing "
              "gives the walking heading (record or export either)", file=sys.stderr)
        return 1
    # a recording whose format says where it was worn (a foot dataset) is taken as it says; any other (a phone app,
    # a generic CSV, an x-io sensor) must show a foot's stance phases before it is navigated as a foot
    if spec.pipeline == "foot" and not args.skip_foot_check and not rec.meta.mount.startswith("foot"):
        import numpy as np

        from models.placement import check_foot

        b = rec.batch
        if np.array_equal(b.acc_t_ns, b.gyr_t_ns):
            verdict = check_foot((b.acc_t_ns - b.acc_t_ns[0]) / 1e9, b.acc, b.gyr)
            if verdict.looks_like_foot is False:
                print(f"error: {args.file}: {verdict.reason}; replay it with --device phone or --placement "
                      "phone-hand|phone-pocket|watch, or pass --skip-foot-check to navigate it as a foot anyway",
                      file=sys.stderr)
                return 1
    if args.server:
        token = args.token or os.environ.get("PEDNAV_TOKEN")
        if not token:
            print("error: --token (or PEDNAV_TOKEN) is required with --server", file=sys.stderr)
            return 2
        doc = replay_server(rec, args.server, token, args.batch_seconds, spec.device_kind, anchor, spec.placement)
    else:
        doc, track, labels = replay_local_track(rec, args.batch_seconds, args.mode, anchor, spec)
        if args.export:
            export_track(track, labels, args.export, f"pednav replay of {rec.name}")
    doc["notes"] = list(rec.meta.notes)  # what the importer repaired or left out
    if args.json:
        print(json.dumps(doc))
    else:
        for note in doc["notes"]:
            print(f"note: {note}", file=sys.stderr)
        print(f"{rec.name}: {len(doc['positions'])} positions, modes {doc['modes']}, gyro on {doc['gyro_on_fraction']:.0%}")
        print(f"north: {doc.get('north')}" + (f" (declination {doc['declination_deg']:.2f} deg applied)"
                                              if doc.get("north") == "true" else ""))
        if doc["positions"]:
            t, n, e, d = doc["positions"][-1]
            print(f"final position at t={t:.1f} s: north {n:.2f} m, east {e:.2f} m, down {d:.2f} m")
            if doc.get("geodetic"):
                la, lo, h = doc["geodetic"][-1]
                print(f"final position: {la:.7f}, {lo:.7f}, {h:.1f} m")
        if "session_id" in doc:
            print(f"session {doc['session_id']}")
        if args.export:
            print(f"wrote {args.export}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("replay", help="stream a recording through the API (--server) or a local engine",
                       description="Stream a recording (any importable format) or a synthetic scenario through the "
                                   "HTTP API or a local engine; its placement picks the engine (foot: ZUPT-KF / Gait-DR; phone in "
                                   "the hand or a pocket, watch: step and heading).")
    p.add_argument("file", help="recording file (any importable format) or synthetic scenario name")
    p.add_argument("--server", default=None, help="server URL, e.g. http://127.0.0.1:8000 (default: local engine)")
    p.add_argument("--token", default=None, help="bearer token (default PEDNAV_TOKEN)")
    p.add_argument("--batch-seconds", type=float, default=1.0, help="seconds per uploaded batch (default 1)")
    p.add_argument("--device", choices=("foot", "phone", "watch"), default=None,
                   help="device kind of the session (default: the recording's own, e.g. phone for a phone app's log; else foot)")
    p.add_argument("--placement", choices=("foot", "phone-hand", "phone-pocket", "watch", "recognise"), default=None,
                   help="where the device is carried: decides the engine (foot: ZUPT-KF/Gait-DR, the others step and "
                        "heading); default: the device kind's own, a phone's recognised")
    p.add_argument("--mode", choices=("auto", "zupt", "pdr"), default="auto",
                   help="local engine mode (the server uses its own configured mode); a phone's zupt = always on, "
                        "pdr/auto = energy-aware")
    p.add_argument("--mag-scale-ut", type=float, default=None, metavar="UT",
                   help="field [uT] that a normalised magnetometer's 1.0 stands for (gaitmap/Xsens CSV: the field "
                        "at their calibration site); without it such a magnetometer is left out")
    p.add_argument("--rate-hz", type=float, default=None, metavar="HZ",
                   help="replay the recording as a sensor set to HZ would have recorded it: every stream faster "
                        "than HZ is low-passed (anti-aliasing FIR) and decimated by the whole factor nearest to its "
                        "rate / HZ (200 Hz at --rate-hz 50: every 4th sample); slower streams are kept, nothing is "
                        "up-sampled; the rates used are in the notes (default: the recorded rates)")
    p.add_argument("--anchor", default=None, metavar="LAT,LON[,ALT]",
                   help="WGS-84 position [deg, deg, m] of the first stance: the output adds latitude/longitude "
                        "('geodetic') and, when the engine's north is magnetic, turns it to true north by the World "
                        "Magnetic Model's declination (as the server does for an anchored session)")
    p.add_argument("--anchor-date", default=None, metavar="YYYY-MM-DD",
                   help="date of the declination (default: the recording's UTC date, else today)")
    p.add_argument("--export", default=None, metavar="FILE",
                   help="write the local replay's track to FILE: .geojson, .gpx, .kml (need --anchor) or .csv")
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
