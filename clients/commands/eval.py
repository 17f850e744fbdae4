"""``pednav eval vicon|gdin|gaitmap``: run the engine over public recordings and print DESIGN.md's metrics.

Forms (DESIGN.md "Evaluation contracts")::

    pednav eval vicon DIR [--mode {zupt,pdr,auto}] --json
    pednav eval gdin DIR --mode {zupt,pdr,auto} [--l0 METERS] [--conventional] [--profile leave-one-out] --json
    pednav eval recordings DIR [--mode {auto,pdr}] --json

``pednav eval ipin DIR --json`` (GetSensorData logfiles with POSI landmarks, :mod:`clients.evaluation.ipin`;
``--mode {auto,always-on}``, ``--placement``) and ``pednav eval phone-watch --json`` (synthetic, 000 eq. 70).
Beyond the contracts: ``pednav eval gaitmap [DIR] [--mode M] --json`` (datasets/gaitmap-mocap: stride lengths
of both feet against optical motion capture, :func:`clients.evaluation.harness.evaluate_gaitmap_recording`),
``pednav eval plot DOC.json [DOC.json ...] --out FILE.png`` (energy against accuracy, per recording and mode, from
saved ``--json`` documents of ``--mode auto|pdr`` runs).

Energy (``--mode auto|pdr``): every recording is also replayed through the always-on baseline (``zupt``) in the
same run, once; each row gains ``energy_ratio``, ``gyro_on_fraction``, ``accuracy_ratio``, ``accuracy_metric``
and ``energy`` (:func:`clients.evaluation.energy_ratio.compare`), the summary the ``{"mean", "median", "worst",
"n"}`` of the three ratios, the document the profile, the computation costs and the baseline it charged
(``--power-profile NAME``, default the foot device :data:`energy.power.DEFAULT_PROFILE`). With ``--plot OUT_DIR``
the energy/accuracy plot of the run is ``OUT_DIR/energy-accuracy-<dataset>-<mode>.png`` beside the per-recording
PNGs. ``--mode zupt`` (the default) prints exactly the documents of the contracts.

``pednav eval recordings DIR``: every file under DIR (and every folder an importer reads as one recording),
without truth (:mod:`clients.evaluation.recordings`). A file that cannot be imported or replayed is one line on
stderr and a row with ``"error"``; exit status 0 when at least one recording ran, 1 when none did (nothing
importable, or every one failed), 2 when DIR is not a folder or an option is wrong.

``pednav eval behaviour [ROOT] [--rate-hz HZ ...] --json``: the behaviour recogniser against labels derived from the
recordings' truth (:mod:`clients.evaluation.behaviour`). ``eval recordings`` takes ``--columns``/``--units`` (the
CSVs of DIR read with the stated columns and units, :mod:`clients.importers.generic_csv`).

Common options: ``--plot OUT_DIR`` (one PNG per recording), ``--limit N`` and ``--match TEXT`` (repeatable:
keep recordings whose name contains TEXT) for quick CI smoke runs, ``--batch-seconds S``. A progress bar
goes to stderr. Exit status 0 when every selected recording was evaluated, 1 when any failed (the failure is
listed in its row as ``"error"`` and logged as one line naming the file and the problem, with a traceback only
for unexpected errors; the JSON document is still printed) or when the folder holds no recording at all.
A gdin recording without ground truth is not a failure: it is listed with the figures that need no truth and
a note, and left out of the summary.

``--profile leave-one-out`` (pdr/auto): the returning-user protocol of :mod:`clients.evaluation.harness`.
Each recording starts from the profile the engine handed out after walking the other selected recordings of
its sensor/format group in experiment order; ``recordings``/``summary`` are then the returning user's, each
row gets ``profile`` (what fed it, what the engine did with it) and ``new_user`` (the same metrics as a new
user, from the same run), and the document gets ``new_user_summary``.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path
from typing import Any

__all__ = ["register"]

log = logging.getLogger(__name__)


def _data_folder(args: argparse.Namespace, command: str, dataset: str) -> Path | None:
    """The folder ``pednav eval COMMAND`` reads: ``--dir``, else ``PEDNAV_DATA/<dataset>``; None after saying in
    one line that it is missing."""
    from clients.datasets import dataset_dir

    directory = Path(args.dir) if args.dir else dataset_dir(dataset)
    if directory is None or not directory.is_dir():
        print(f"pednav eval {command}: data folder not found ({args.dir or 'PEDNAV_DATA/' + dataset})", file=sys.stderr)
        return None
    return directory


def _log_failure(what: Any, exc: Exception) -> None:
    """One line for a file that cannot be used (``ImporterError``: the message names file, field and problem);
    the traceback only for unexpected errors."""
    from clients.importers import ImporterError

    if isinstance(exc, ImporterError):
        log.error("%s", exc)
    else:
        log.exception("%s failed", what)


def _nothing_found(dataset: str, directory: Path, match: Any) -> None:
    how = f" matching {match}" if match else ""
    print(f"pednav eval {dataset}: no recording{how} found in {directory}", file=sys.stderr)


def _progress(items: list[Any], desc: str) -> Any:
    """A progress bar over the recordings (on a terminal). The kernels are compiled or loaded first, announced
    (:func:`clients.warmup.warm_up` on a short synthetic walk), so the bar's estimate is not the first run's
    compilation spread over the recordings."""
    from tqdm import tqdm

    if sys.stderr.isatty():
        from clients.synth import synthesize
        from clients.warmup import warm_up

        b = synthesize("walk", seed=0).batch
        warm_up([b.time_slice(None, int(b.t_start_ns) + 30 * 10**9)])
    return tqdm(items, desc=desc, unit="rec", file=sys.stderr, disable=None, leave=False)


def _accounting(args: argparse.Namespace, command: str) -> Any:
    """The energy accounting of a ``--mode auto|pdr`` run (None for ``zupt``); ``ValueError`` for an option that
    does not apply or an unknown profile (the caller prints it as one line)."""
    if args.mode == "zupt":
        if args.power_profile is not None:
            raise ValueError(f"pednav eval {command}: --power-profile applies to --mode pdr/auto only (zupt is the baseline)")
        return None
    from clients.evaluation.energy_ratio import EnergyAccounting

    return EnergyAccounting.load(args.power_profile)


def _with_energy(accounting: Any, dataset: str, mode: str, ev: Any, ref: Any) -> Any:
    """Add the energy and accuracy fields against the baseline ``ref`` (the same recording evaluated in ``zupt``;
    None without ``accounting``) to ``ev.row``; the EngineRun leaves the plot dict and is returned."""
    run = ev.plot.pop("run", None)
    if accounting is not None:
        from clients.evaluation.energy_ratio import compare

        ev.row.update(compare(accounting, mode, run, ref.plot["run"], dataset, ev.row, ref.row))
    return run


def _energy_doc(doc: dict[str, Any], accounting: Any, rows: list[dict[str, Any]], summary_rows: list[dict[str, Any]],
                plot_dir: str | None) -> None:
    """Add the energy part to a ``--mode auto|pdr`` document (and its plot when ``plot_dir``)."""
    if accounting is None:
        return
    from clients.evaluation.energy_ratio import add_summary, metric_counts

    doc["summary"] = add_summary(doc["summary"], summary_rows)
    doc["accuracy_metrics"] = metric_counts(rows)
    doc.update(accounting.describe([doc["mode"]]))
    if plot_dir:
        from clients.evaluation.plots import plot_energy_accuracy

        plot_energy_accuracy(Path(plot_dir) / f"energy-accuracy-{doc['dataset']}-{doc['mode']}.png", [doc])


def _print_energy(doc: dict[str, Any], rows: list[dict[str, Any]], width: int) -> None:
    """The energy part of a ``--mode auto|pdr`` table."""
    if "energy_baseline" not in doc:
        return
    print(f"\nenergy and accuracy against the always-on ZUPT-KF (profile {doc['power_profile']['name']}):")
    print(f"{'':<{width}} {'energy':>7} {'gyro':>5} {'accuracy':>8}  metric")
    for r in rows:
        if "energy_ratio" in r:
            print(f"{r['name']:<{width}} {_fmt(r['energy_ratio'], '7.3f')} {_fmt(r['gyro_on_fraction'], '5.2f')} "
                  f"{_fmt(r['accuracy_ratio'], '8.2f')}  {r['accuracy_metric'] or '-'}")
    s = doc["summary"]
    for k in ("energy_ratio", "gyro_on_fraction", "accuracy_ratio"):
        print(f"  {k:<18} median {_fmt(s[k]['median'], '7.3f')}  worst {_fmt(s[k]['worst'], '7.3f')}  n={s[k]['n']}")


def _settings(items: list[str] | None) -> dict[str, Any]:
    """``--set section.field=value`` options as an :meth:`energy.config.EngineConfig.override` mapping (values
    parsed as JSON where they are, e.g. numbers and booleans; strings otherwise)."""
    out: dict[str, Any] = {}
    for item in items or []:
        key, sep, raw = item.partition("=")
        if not sep or not key:
            raise SystemExit(f"pednav eval: --set {item!r}: expected SECTION.FIELD=VALUE, e.g. scheduler.cross_track_pct=10")
        try:
            out[key.strip()] = json.loads(raw)
        except json.JSONDecodeError:
            out[key.strip()] = raw
    return out


def _runner(batch_seconds: float | None, conventional: bool = False, settings: dict[str, Any] | None = None) -> Any:
    from clients.evaluation.harness import run_engine
    from energy.config import EngineConfig

    try:
        EngineConfig().override(settings or {})  # a bad setting is refused here, by name, before any replay
    except (ValueError, TypeError) as exc:
        raise SystemExit(f"pednav eval: --set: {exc}") from None

    def run(batch: Any, mode: str, l0_m: float | None, profile: dict[str, Any] | None = None) -> Any:
        return run_engine(batch, mode=mode, l0_m=l0_m, batch_seconds=batch_seconds, conventional=conventional,
                          profile=profile, settings=settings)

    return run


def _fmt(v: Any, spec: str) -> str:
    """Format ``v`` with ``spec`` (e.g. ``"7.2f"``); ``None`` becomes a right-aligned ``-`` of the same width."""
    if v is None:
        width = "".join(ch for ch in spec.split(".")[0] if ch.isdigit())
        return "-".rjust(int(width) if width else 1)
    return format(v, spec)


def _evaluate_each(items: list[Any], desc: str, where: Any, evaluate: Any, plot: Any,
                   plot_dir: str | None) -> tuple[list[dict[str, Any]], int]:
    """Rows of ``evaluate(item)`` for every item (``where(item)``: the file to log and the row name of a failure,
    which is listed as ``"error"`` and does not hide the others), a plot each into ``plot_dir`` when given; and
    the number of failures."""
    rows: list[dict[str, Any]] = []
    failed = 0
    for it in _progress(items, desc):
        try:
            ev = evaluate(it)
        except Exception as exc:  # noqa: BLE001 - one broken recording must not hide the others
            path, name = where(it)
            _log_failure(path, exc)
            rows.append({"name": name, "error": f"{type(exc).__name__}: {exc}"})
            failed += 1
            continue
        rows.append(ev.row)
        if plot_dir:
            plot(plot_dir, ev.row, ev.plot)
    return rows, failed


def _print(doc: dict[str, Any], rows: list[dict[str, Any]], as_json: bool, width: int, header: str,
           line: Any) -> bool:
    """``doc`` as JSON, or a table: ``header`` and ``line(row)`` per row (a failed row: its name, padded to
    ``width``, and the error). True when the table was printed."""
    if as_json:
        print(json.dumps(doc, indent=2))
        return False
    print(header)
    for r in rows:
        print(f"{r['name']:<{width}} ERROR {r['error']}" if "error" in r else line(r))
    return True


def _run_vicon(args: argparse.Namespace) -> int:
    from clients.evaluation import harness

    directory = _data_folder(args, "vicon", "vicon")
    if directory is None:
        return 2
    try:
        accounting = _accounting(args, "vicon")
    except ValueError as exc:
        print(exc, file=sys.stderr)
        return 2
    files = harness.select(harness.vicon_files(directory), lambda f: f.stem, args.match, args.limit)
    if not files:
        _nothing_found("vicon", directory, args.match)
        if not args.json:
            return 1  # the line says it all; --json still prints its (empty) document
    runner = _runner(_batch(args), settings=_settings(getattr(args, "set", None)))
    from clients.evaluation.plots import plot_vicon

    def evaluate(f: Path) -> Any:
        rec = harness.load_vicon_trial(f)
        ev = harness.evaluate_vicon_recording(rec, runner, args.mode)
        ref = harness.evaluate_vicon_recording(rec, runner, "zupt") if accounting is not None else None
        _with_energy(accounting, "vicon", args.mode, ev, ref)
        return ev

    rows, failed = _evaluate_each(files, f"vicon {args.mode}", lambda f: (f, f.stem), evaluate, plot_vicon, args.plot)
    doc = {"dataset": "vicon", "mode": args.mode, "trials": rows, "summary": harness.vicon_summary(rows),
           "settings": _settings(args.set)}
    _energy_doc(doc, accounting, rows, [r for r in rows if "error" not in r], args.plot)

    def line(r: dict[str, Any]) -> str:
        b = r["behaviour"]
        return (f"{r['name']:<22} {r['armse_2d_m']:>9.3f} {r['armse_3d_m']:>9.3f} {r['samples']:>7d} "
                f"{b['stand']:>6.2f} {b['walk']:>6.2f} {b['run']:>6.2f} {b['other']:>6.2f}")

    if _print(doc, rows, args.json, 22, f"{'trial':<22} {'ARMSE2D m':>9} {'ARMSE3D m':>9} {'samples':>7} "
              f"{'stand':>6} {'walk':>6} {'run':>6} {'other':>6}", line):
        s = doc["summary"]
        print(f"\n{s['trials']} trials: mean 2-D ARMSE {_fmt(s['mean_armse_2d_m'], '.3f')} m, "
              f"median {_fmt(s['median_armse_2d_m'], '.3f')} m")
        _print_energy(doc, rows, 22)
    return 1 if failed or not files else 0


def _run_gdin(args: argparse.Namespace) -> int:
    from clients.evaluation import harness

    if (args.l0 is not None or args.conventional) and args.mode == "zupt":
        print("pednav eval gdin: --l0 and --conventional apply to --mode pdr/auto only", file=sys.stderr)
        return 2
    loo = args.profile == "leave-one-out"
    if loo and args.mode == "zupt":
        print("pednav eval gdin: --profile applies to --mode pdr/auto only (zupt keeps no calibration)", file=sys.stderr)
        return 2
    try:
        accounting = _accounting(args, "gdin")
    except ValueError as exc:
        print(exc, file=sys.stderr)
        return 2
    directory = _data_folder(args, "gdin", "gdin")
    if directory is None:
        return 2
    entries = harness.select(harness.gdin_entries(directory), lambda e: e.name, args.match, args.limit)
    if not entries:
        _nothing_found("gdin", directory, args.match)
        if not args.json:
            return 1  # the line says it all; --json still prints its (empty) document
    runner = _runner(_batch(args), args.conventional, _settings(getattr(args, "set", None)))
    rows: list[dict[str, Any]] = []
    failed = 0
    recs: dict[str, Any] = {}  # returning-user protocol: the recordings, kept for the profile sessions
    new_user: dict[str, Any] = {}  # and each one's new-user session: (profile handed out, events)
    refs: dict[str, Any] = {}  # --mode auto|pdr: each recording's baseline (zupt) evaluation, computed once
    for e in _progress(entries, f"gdin {args.mode}"):
        try:
            rec = harness.load_gdin_entry(e)
            ev = harness.evaluate_gdin_recording(rec, runner, args.mode, args.l0)
            if accounting is not None:
                refs[e.name] = harness.evaluate_gdin_recording(rec, runner, "zupt")
            run = _with_energy(accounting, "gdin", args.mode, ev, refs.get(e.name))
        except Exception as exc:  # noqa: BLE001 - one broken recording must not hide the others
            _log_failure(e.sensor_path, exc)
            rows.append({"name": e.name, "error": f"{type(exc).__name__}: {exc}"})
            failed += 1
            continue
        rows.append(ev.row)
        if loo:
            recs[e.name], new_user[e.name] = rec, (run.profile, run.events)
        elif args.plot and "gcp_xy" in ev.plot:
            from clients.evaluation.plots import plot_gdin

            plot_gdin(args.plot, ev.row, ev.plot)
    extra: dict[str, Any] = {}
    if loo:
        new_rows = rows
        rows, failed_loo, chains = _returning_users(args, recs, new_user, new_rows, runner, accounting, refs)
        failed += failed_loo
        extra = {
            "profile": args.profile,
            "profile_groups": chains,
            "new_user_summary": harness.gdin_summary(new_rows),
        }
        if accounting is not None:
            from clients.evaluation.energy_ratio import add_summary

            extra["new_user_summary"] = add_summary(extra["new_user_summary"], _usable(new_rows))
    excluded = [r["name"] for r in rows if not r.get("gt_usable", False)]
    doc = {
        "dataset": "gdin",
        "mode": args.mode,
        "settings": _settings(args.set),
        "l0_m": args.l0,
        "conventional": args.conventional,
        "recordings": rows,
        "excluded_from_summary": excluded,
        "summary": harness.gdin_summary(rows),
        **extra,
    }
    _energy_doc(doc, accounting, rows, _usable(rows), args.plot)
    if args.json:
        print(json.dumps(doc, indent=2))
    else:
        print(f"{'rec':<6} {'fmt':<16} {'loop%':>6} {'strMean':>7} {'strRMS':>7} {'dist%':>6} {'strides':>9} {'gyro':>5} {'Hz':>6}  note")
        for r in rows:
            if "error" in r:
                print(f"{r['name']:<6} ERROR {r['error']}")
                continue
            print(
                f"{r['name']:<6} {r['format']:<16} {_fmt(r.get('loop_closure_pct'), '6.2f')} "
                f"{_fmt(r.get('stride_mean_err_m'), '7.2f')} {_fmt(r.get('stride_rmse_m'), '7.2f')} "
                f"{_fmt(r['distance_err_pct'], '6.2f')} {r['strides_detected']:>4d}/{_fmt(r['strides_truth'], '<4d')} "
                f"{r['gyro_on_fraction']:>5.2f} {r['mean_rate_hz']:>6.1f}  {_gt_note(r)}"
            )
        print("\nsummary (usable ground truth only):")
        for k, s in doc["summary"].items():
            print(f"  {k:<18} mean {_fmt(s['mean'], '8.3f')}  median {_fmt(s['median'], '8.3f')}  n={s['n']}")
        if loo:
            print(f"\nreturning user ({args.profile}) vs new user, medians (usable ground truth only):")
            for k, s in doc["summary"].items():
                n = doc["new_user_summary"][k]
                print(f"  {k:<18} new {_fmt(n['median'], '8.3f')}  returning {_fmt(s['median'], '8.3f')}  n={s['n']}")
            for r in rows:
                pr = r.get("profile")
                if pr is not None:
                    ev = pr["events"]
                    print(f"  {r['name']:<6} fed by {len(pr['fed_by']):>2} sessions, walk calibrated in "
                          f"{pr['calibrated_in'].get('walk', '-'):<6} resumed {str(pr['resumed']):<5} "
                          f"exam passed/failed {ev['examination_passed']}/{ev['examination_failed']} "
                          f"calibrations {ev['calibration_done']}")
        _print_energy(doc, rows, 6)
    return 1 if failed or not entries else 0


def _gt_note(row: dict[str, Any]) -> str:
    if row["gt_usable"]:
        return ""
    if any("cut short" in n for n in row.get("notes", ())):
        return "sensor file cut short against its truth: not in summary"
    return "no ground truth: not in summary" if row.get("strides_truth") is None else "GT flagged unusable: not in summary"


_COMPARED = ("loop_closure_pct", "stride_mean_err_m", "stride_rmse_m", "distance_err_pct", "gyro_on_fraction",
             "mean_rate_hz", "pdr_distance_err_pct", "energy_ratio", "accuracy_ratio")


def _usable(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The gdin rows a summary is made of (usable ground truth, no error)."""
    return [r for r in rows if r.get("gt_usable", False) and "error" not in r]


def _returning_users(args: argparse.Namespace, recs: dict[str, Any], new_user: dict[str, Any],
                     new_rows: list[dict[str, Any]], runner: Any, accounting: Any = None,
                     refs: dict[str, Any] | None = None) -> tuple[list[dict[str, Any]], int, dict[str, list[str]]]:
    """Leave-one-out returning users: every recording evaluated again, starting from the profile of the other
    recordings of its sensor/format group (walked in experiment order, each session starting from the previous
    session's profile); with ``accounting`` against the baseline evaluations ``refs`` of the new-user pass.
    Returns the rows, the number of failures and the groups (format -> names)."""
    from clients.evaluation import harness

    groups: dict[str, list[str]] = {}
    for name, rec in recs.items():  # entries come sorted by experiment number
        groups.setdefault(rec.meta.source_format, []).append(name)

    def session(name: str, profile: dict[str, Any] | None) -> tuple[dict[str, Any] | None, Any]:
        run = runner(recs[name].batch, args.mode, args.l0, profile=profile)
        return run.profile, run.events

    chain = harness.ProfileChain(session)
    for name, (profile_out, events) in new_user.items():
        chain.seed(name, profile_out, events)  # the new-user pass above is each chain's first session
    chains = harness.leave_one_out_chains(groups)
    by_name = {r["name"]: r for r in new_rows}
    rows: list[dict[str, Any]] = []
    failed = 0
    for r0 in _progress(new_rows, f"gdin {args.mode} returning"):
        name = r0["name"]
        if name not in recs:
            rows.append(r0)  # failed as a new user already
            continue
        try:
            profile, sessions = chain.after(chains[name])
            if name in [s.name for s in sessions]:
                raise RuntimeError(f"{name} would feed its own profile")
            ev = harness.evaluate_gdin_recording(recs[name], runner, args.mode, args.l0, profile=profile)
            run = _with_energy(accounting, "gdin", args.mode, ev, (refs or {}).get(name))
        except Exception as exc:  # noqa: BLE001 - one broken recording must not hide the others
            _log_failure(f"{name} (returning user)", exc)
            rows.append({"name": name, "error": f"{type(exc).__name__}: {exc}"})
            failed += 1
            continue
        ev.row["profile"] = harness.profile_info(profile, sessions, run.events)
        ev.row["new_user"] = {k: by_name[name].get(k) for k in _COMPARED if k in by_name[name]}
        ev.row["new_user"]["events"] = harness.event_counts(new_user[name][1])
        rows.append(ev.row)
        if args.plot and "gcp_xy" in ev.plot:
            from clients.evaluation.plots import plot_gdin

            plot_gdin(args.plot, ev.row, ev.plot)
    log.info("returning-user protocol: %d profile sessions run", chain.sessions_run)
    return rows, failed, groups


def _run_gaitmap(args: argparse.Namespace) -> int:
    from clients.evaluation import harness
    from clients.importers.gaitmap import load_gaitmap

    directory = _data_folder(args, "gaitmap", "gaitmap-mocap")
    if directory is None:
        return 2
    try:
        accounting = _accounting(args, "gaitmap")
    except ValueError as exc:
        print(exc, file=sys.stderr)
        return 2
    items = harness.select(harness.gaitmap_recordings(directory), lambda it: f"{it[0].stem}-{it[1]}", args.match,
                           args.limit)
    if not items:
        _nothing_found("gaitmap", directory, args.match)
        if not args.json:
            return 1  # the line says it all; --json still prints its (empty) document
    runner = _runner(_batch(args), settings=_settings(getattr(args, "set", None)))
    from clients.evaluation.plots import plot_gaitmap

    def evaluate(it: tuple[Path, str]) -> Any:
        rec = load_gaitmap(it[0], foot=it[1])
        ev = harness.evaluate_gaitmap_recording(rec, runner, args.mode)
        ref = harness.evaluate_gaitmap_recording(rec, runner, "zupt") if accounting is not None else None
        _with_energy(accounting, "gaitmap", args.mode, ev, ref)
        return ev

    rows, failed = _evaluate_each(items, f"gaitmap {args.mode}", lambda it: (it[0], f"{it[0].stem}-{it[1]}"),
                                  evaluate, plot_gaitmap, args.plot)
    doc = {"dataset": "gaitmap", "mode": args.mode, "recordings": rows, "summary": harness.gaitmap_summary(rows),
           "settings": _settings(args.set)}
    _energy_doc(doc, accounting, rows, [r for r in rows if r.get("truth") and "error" not in r], args.plot)

    def line(r: dict[str, Any]) -> str:
        return (f"{r['name']:<40} {r['strides_detected']:>7d} {_fmt(r.get('stride_length_mean_abs_err_m'), '9.3f')} "
                f"{_fmt(r.get('stride_length_rmse_m'), '10.3f')} {_fmt(r.get('stride_height_rmse_m'), '9.3f')} "
                f"{_fmt(r.get('distance_err_pct'), '7.2f')} {r['climb_m']:>8.2f}")

    if _print(doc, rows, args.json, 40, f"{'recording':<40} {'strides':>7} {'len MAE m':>9} {'len RMSE m':>10} "
              f"{'dh RMSE m':>9} {'dist %':>7} {'climb m':>8}", line):
        _print_energy(doc, rows, 40)
    return 1 if failed or not items else 0


def _run_behaviour(args: argparse.Namespace) -> int:
    from clients.datasets import data_root
    from clients.evaluation import behaviour

    root = Path(args.dir) if args.dir else data_root()
    if root is None or not root.is_dir():
        print(f"pednav eval behaviour: data folder not found ({args.dir or 'PEDNAV_DATA'})", file=sys.stderr)
        return 2
    rates = [None] + [float(r) for r in (args.rate_hz or [])]
    if any(r is not None and not r > 0 for r in rates):
        print("pednav eval behaviour: --rate-hz must be a positive rate in Hz", file=sys.stderr)
        return 2
    doc = {"dataset": "behaviour", "labels": str(behaviour.LABEL_TABLE), **behaviour.evaluate(root, rates)}
    if not any(v["recordings"] for v in doc["rates"].values()):
        print(f"pednav eval behaviour: no labelled recording found under {root}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(doc))
        return 0
    for rate, v in doc["rates"].items():
        if args.confusion:
            print(f"{rate} Hz: labelled[recognised s: stand walk run other] | wrong s by context "
                  f"({'/'.join(behaviour.CONTEXTS)}) labelled>recognised")
            print("\n".join(behaviour.confusion_table(v["recordings"])))
        s = v["summary"]
        print(f"{rate:>9} Hz  walk/run share mean {_fmt(s['walk_run_share_mean'], '.3f')} worst "
              f"{_fmt(s['walk_run_share_worst'], '.3f')} ({s['worst_recording']}), other share "
              f"{_fmt(s['other_share_mean'], '.3f')}, stand left {_fmt(s['stand_left_median_abs_s'], '.2f')} s / "
              f"entered {_fmt(s['stand_entered_median_abs_s'], '.2f')} s (median |latency|, "
              f"{s['stand_boundaries']} boundaries, {s['stand_boundaries_missed']} missed)")
    return 0


def _run_recordings(args: argparse.Namespace) -> int:
    from clients.evaluation.recordings import candidates, evaluate_recording, recordings_summary
    from clients.importers import ImporterError, load

    directory = Path(args.dir)
    if not directory.is_dir():
        print(f"pednav eval recordings: {args.dir}: not a folder", file=sys.stderr)
        return 2
    if (args.columns is None) != (args.units is None):
        print("pednav eval recordings: --columns and --units go together", file=sys.stderr)
        return 2
    try:
        accounting = _accounting(args, "recordings")
    except ValueError as exc:
        print(exc, file=sys.stderr)
        return 2
    runner = _runner(_batch(args), settings=_settings(getattr(args, "set", None)))
    rows: list[dict[str, Any]] = []
    for f in _progress(candidates(directory), f"recordings {args.mode}"):
        name = str(f.relative_to(directory))
        try:
            if args.columns is not None and f.suffix.lower() == ".csv":
                from clients.importers.generic_csv import load_generic_csv

                rec = load_generic_csv(f, args.columns, args.units)
            else:
                rec = load(f)
            ev = evaluate_recording(rec, runner, args.mode, accounting)
        except Exception as exc:  # noqa: BLE001 - one line per file that cannot be used, never a traceback
            reason = str(exc) if isinstance(exc, (ImporterError, ValueError)) else f"{type(exc).__name__}: {exc}"
            print(f"pednav eval recordings: skipped {name}: {reason}", file=sys.stderr)
            rows.append({"name": name, "file": str(f), "error": reason})
            continue
        ev.row["name"], ev.row["file"] = name, str(f)
        rows.append(ev.row)
        if args.plot:
            from clients.evaluation.plots import plot_recording_timeline

            plot_recording_timeline(args.plot, ev.row, ev.plot)
    doc: dict[str, Any] = {"dataset": "recordings", "mode": args.mode, "directory": str(directory),
                           "recordings": rows, "summary": recordings_summary(rows)}
    doc.update(accounting.describe([args.mode]))
    ran = doc["summary"]["recordings"]
    if args.json:
        print(json.dumps(doc, indent=2))
    else:
        print(f"{'recording':<32} {'min':>6} {'energy':>7} {'gyro':>5} {'zupt':>5} {'pdr':>5} {'idle':>5} {'strides':>7}")
        for r in rows:
            if "error" in r:
                print(f"{r['name']:<32} ERROR {r['error']}")
                continue
            m = r["modes"]
            print(f"{r['name']:<32} {r['duration_s'] / 60:>6.1f} {_fmt(r['energy_ratio'], '7.3f')} "
                  f"{r['gyro_on_fraction']:>5.2f} {m.get('zupt', 0):>5.2f} {m.get('pdr', 0):>5.2f} "
                  f"{m.get('idle', 0):>5.2f} {r['strides']:>7d}")
        s = doc["summary"]
        print(f"\n{ran} recording(s) replayed, {s['failed']} skipped; profile {doc['power_profile']['name']}")
        for k in ("energy_ratio", "gyro_on_fraction"):
            print(f"  {k:<18} median {_fmt(s[k]['median'], '7.3f')}  worst {_fmt(s[k]['worst'], '7.3f')}")
    if not ran:
        print(f"pednav eval recordings: no recording in {directory} could be replayed", file=sys.stderr)
    return 0 if ran else 1


def _run_plot(args: argparse.Namespace) -> int:
    from clients.evaluation.plots import plot_energy_accuracy

    docs = []
    for f in args.docs:
        try:
            doc = json.loads(Path(f).read_text())
        except (OSError, ValueError) as exc:
            print(f"pednav eval plot: {f}: not a readable JSON document ({exc})", file=sys.stderr)
            return 2
        if not isinstance(doc, dict) or "mode" not in doc or not isinstance(doc.get("trials", doc.get("recordings")), list):
            print(f"pednav eval plot: {f}: not a document of pednav eval ... --json (no mode and rows)", file=sys.stderr)
            return 2
        docs.append(doc)
    try:
        n = plot_energy_accuracy(args.out, docs, curve=args.curve)
    except ValueError as exc:
        print(f"pednav eval plot: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {args.out} ({n} recordings)", file=sys.stderr)
    return 0


def _run_ipin(args: argparse.Namespace) -> int:
    from clients.evaluation.harness import select
    from clients.evaluation.ipin import evaluate_ipin
    from clients.importers import list_recordings, load

    directory = _data_folder(args, "ipin", "ipin2023-t3-phone")
    if directory is None:
        return 2
    files = select(list_recordings(directory), lambda f: f.stem, args.match, args.limit)
    recs, rows_failed = [], []
    for f in _progress(files, "ipin load"):
        try:
            rec = load(f)
            if rec.truth is None or rec.truth.t_ns is None or len(rec.truth.t_ns) < 2:
                raise ValueError(f"{f}: no landmarks (POSI lines): nothing to score")
            recs.append(rec)
        except Exception as exc:  # noqa: BLE001 - one broken recording must not hide the others
            _log_failure(f, exc)
            rows_failed.append({"name": f.stem, "error": f"{type(exc).__name__}: {exc}"})
    if len({r.name.rsplit("_repetition", 1)[0] for r in recs}) < 2:
        print(f"pednav eval ipin: {len(recs)} scorable recording(s) in {directory}; the leave-one-route-out step "
              "constant needs trials of at least two routes", file=sys.stderr)
        return 1
    placement = None if args.placement == "recognise" else args.placement
    import math

    bound = None if args.max_heading_std_deg is None else math.radians(args.max_heading_std_deg)
    duty = None
    if args.gyro_duty is not None:
        try:
            duty = tuple(float(x) for x in args.gyro_duty.split(","))
            if len(duty) not in (2, 3, 4):
                raise ValueError
            from energy.phone_engine import PhoneEngineConfig

            PhoneEngineConfig(gyro_duty_period_s=duty[0], gyro_duty_on_s=duty[1])
        except ValueError:
            print(f"pednav eval ipin: --gyro-duty wants P,ON[,ONLY[,SIGMA_DEG]] in seconds with 0 < ON < P, got {args.gyro_duty!r}",
                  file=sys.stderr)
            return 2
    walk_gyro = args.walk_gyro
    if walk_gyro is None and (bound is not None or duty is not None):
        walk_gyro = "on-demand"  # those options act where the gyroscope goes off walking
    try:
        doc = evaluate_ipin(recs, mode=args.mode, placement=placement, batch_seconds=args.batch_seconds,
                            max_heading_std_rad=bound, phases=max(1, int(args.phases)), calibration=args.calibration,
                            gyro_duty=duty, walk_gyro=walk_gyro)  # type: ignore[arg-type]
    except ValueError as exc:  # e.g. no steps on the other routes to fit the step constant on
        print(f"pednav eval ipin: {exc}", file=sys.stderr)
        return 1
    doc["trials"] += rows_failed

    def line(r: dict[str, Any]) -> str:
        return (f"{r['name']:<42} {r['mean_err_m']:>6.2f} {r['p75_err_m']:>6.2f} {r['final_err_m']:>6.2f} "
                f"{r['path_ratio']:>6.3f} {r['steps']:>5d} {r['energy_ratio']:>6.2f} {r['always_on']['mean_err_m']:>7.2f} "
                f"{r['baseline']['mean_err_m']:>7.2f}")

    if _print(doc, doc["trials"], args.json, 42, f"{'trial':<42} {'mean m':>6} {'p75 m':>6} {'final':>6} {'path':>6} "
              f"{'steps':>5} {'energy':>6} {'alw-on':>7} {'basel.':>7}", line):
        s = doc["summary"]
        print(f"\n{s['trials']} trials ({args.mode}): median mean error {_fmt(s['mean_err_m']['median'], '.2f')} m "
              f"(worst {_fmt(s['mean_err_m']['worst'], '.2f')}), median p75 {_fmt(s['p75_err_m']['median'], '.2f')} m, "
              f"median energy ratio {_fmt(s['energy_ratio']['median'], '.2f')} "
              f"({_fmt(s['energy_ratio_landmarks']['median'], '.2f')} between the landmarks); always-on "
              f"{_fmt(s['always_on']['mean_err_m']['median'], '.2f')} m, baseline {_fmt(s['baseline']['mean_err_m']['median'], '.2f')} m")
        pr = s["accuracy_ratio"]["paired"]
        if args.mode != "always-on" and pr["geomean"] is not None:
            print(f"error over always-on's, per trial: geometric mean {pr['geomean']:.2f} "
                  f"(90 % bootstrap interval over the trials {pr['ci90'][0]:.2f}-{pr['ci90'][1]:.2f})")
        if "phases" in doc:
            m = doc["phases"]["mean"]
            print(f"over {doc['phases']['phases']} batch phases: median mean error {m['mean_err_m']:.2f} m "
                  f"(worst {m['worst_mean_err_m']:.2f}), median p75 {m['p75_err_m']:.2f} m, energy ratio "
                  f"{m['energy_ratio']:.2f} ({m['energy_ratio_landmarks']:.2f} between the landmarks); always-on "
                  f"{m['always_on']['mean_err_m']:.2f} m; ratio of the medians {m['ratio_of_medians']:.2f}")
            pr = m["paired_ratio"]
            if args.mode != "always-on" and pr["geomean"] is not None:
                print(f"  per trial (its mean over the phases): geometric mean of the error ratios {pr['geomean']:.2f} "
                      f"(90 % interval {pr['ci90'][0]:.2f}-{pr['ci90'][1]:.2f})")
    return 1 if rows_failed else 0


def _run_phone_watch(args: argparse.Namespace) -> int:
    from clients.evaluation.phone_watch import evaluate_phone_watch

    if args.seeds < 1:
        print("pednav eval phone-watch: --seeds must be at least 1", file=sys.stderr)
        return 2
    doc = evaluate_phone_watch(range(args.seeds))
    if args.json:
        print(json.dumps(doc, indent=2))
        return 0
    print(f"{'seed':>4} {'phone m':>8} {'watch m':>8} {'fused m':>8} {'blended':>8}")
    for r in doc["recordings"]:
        print(f"{r['seed']:>4} {r['phone']['mean_err_m']:>8.2f} {r['watch']['mean_err_m']:>8.2f} "
              f"{r['fused']['mean_err_m']:>8.2f} {r['blended_fraction']:>8.2f}")
    s = doc["summary"]
    print(f"\nmedian mean error: phone {s['phone']['mean_err_m']:.2f} m, watch {s['watch']['mean_err_m']:.2f} m, "
          f"fused {s['fused']['mean_err_m']:.2f} m ({doc['dataset']})")
    return 0


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("dir", nargs="?", default=None, help="data folder (default: PEDNAV_DATA or ../shared/datasets)")
    p.add_argument("--json", action="store_true", help="print one JSON document")
    p.add_argument("--plot", metavar="OUT_DIR", default=None, help="write a trajectory-vs-truth PNG per recording")
    p.add_argument("--limit", type=int, default=None, metavar="N", help="evaluate at most N recordings")
    p.add_argument("--match", action="append", default=None, metavar="TEXT", help="only recordings whose name contains TEXT (repeatable)")
    p.add_argument("--batch-seconds", type=float, default=1.0, metavar="S", help="upload batch duration of the replay [s]")
    p.add_argument("--device-batching", action="store_true",
                   help="upload as long as the engine asks (SensorConfig.batch_s, as a device would) instead of "
                        "--batch-seconds")
    p.add_argument("--set", action="append", default=None, metavar="SECTION.FIELD=VALUE",
                   help="change one engine setting (repeatable), e.g. scheduler.cross_track_pct=10; "
                        "`pednav config` lists them")


def _batch(args: argparse.Namespace) -> float | None:
    return None if getattr(args, "device_batching", False) else args.batch_seconds


def _energy_options(p: argparse.ArgumentParser, modes: tuple[str, ...] = ("zupt", "pdr", "auto"),
                    default: str = "zupt") -> None:
    p.add_argument("--mode", choices=modes, default=default, help=f"engine mode (default {default}); pdr/auto also "
                   "report energy_ratio, gyro_on_fraction and accuracy_ratio against zupt on the same recording")
    p.add_argument("--power-profile", default=None, metavar="NAME",
                   help="device power profile charged with --mode pdr/auto (energy/profiles/NAME.json or a path; "
                        "default: the foot device energy simulate charges, foot-004)")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("eval", help="evaluate the engine on public datasets (VICON ARMSE, gdin loop/stride errors, "
                                    "gaitmap stride lengths against motion capture) and on your own recordings "
                                    "(energy, modes, gyroscope timeline)")
    esub = p.add_subparsers(dest="dataset", metavar="DATASET", required=True)
    pv = esub.add_parser("vicon", help="University of Toronto VICON trials: authors' ARMSE, behaviour fractions")
    _common(pv)
    _energy_options(pv)
    pv.set_defaults(func=_run_vicon)
    pg = esub.add_parser("gdin", help="gdin walks: loop closure, stride errors, distance error, energy figures")
    _common(pg)
    _energy_options(pg)
    pg.add_argument("--l0", type=float, default=None, metavar="METERS", help="ZUPT-KF initialisation distance before Gait-PDR (pdr/auto)")
    pg.add_argument("--conventional", action="store_true",
                    help="conventional PDR baseline (004 Table 6): generic step model, no heading-deviation compensation (pdr/auto)")
    pg.add_argument("--profile", choices=("none", "leave-one-out"), default="none",
                    help="per-user profile each recording starts with (pdr/auto): none = a new user (default); "
                         "leave-one-out = a returning user, profile from walking the other recordings of the same "
                         "sensor/format group in experiment order, never the recording itself")
    pg.set_defaults(func=_run_gdin)
    pm = esub.add_parser("gaitmap", help="gaitmap example walks and stairs (both feet): stride lengths against optical "
                                         "motion capture, height climbed")
    _common(pm)
    _energy_options(pm)
    pm.set_defaults(func=_run_gaitmap)
    pb = esub.add_parser("behaviour", help="stand/walk/run/other recognition (accelerometer only) against the labels "
                                           "derived from the recordings' truth (clients/evaluation/behaviour_labels.csv)")
    pb.add_argument("dir", nargs="?", default=None, help="datasets root (default: PEDNAV_DATA or ../shared/datasets)")
    pb.add_argument("--rate-hz", type=float, action="append", default=None, metavar="HZ",
                    help="also de-sampled to HZ (repeatable), as a sensor set to HZ would deliver it")
    pb.add_argument("--json", action="store_true", help="print one JSON document")
    pb.add_argument("--confusion", action="store_true",
                    help="print per recording the labelled x recognised seconds and where the wrong time lies "
                         "(first seconds of a gait, last before a stop, after a pace change or an unscored stretch, "
                         "steady gait); the JSON has it as each recording's confusion_s and missed_s")
    pb.set_defaults(func=_run_behaviour)
    pi = esub.add_parser("ipin", help="GetSensorData phone logfiles with surveyed landmarks (IPIN 2023 Track 3): "
                                      "landmark errors, path ratio, steps, energy against always-on")
    pi.add_argument("dir", nargs="?", default=None, help="folder of logfiles (default: PEDNAV_DATA/ipin2023-t3-phone)")
    pi.add_argument("--json", action="store_true", help="print one JSON document")
    pi.add_argument("--mode", choices=("auto", "always-on"), default="auto",
                    help="step-and-heading engine mode: auto = energy-aware (default), always-on = every sensor at its full rate")
    pi.add_argument("--placement", choices=("phone-hand", "phone-pocket", "recognise"), default="phone-hand",
                    help="placement given to the engine (default phone-hand: the dataset's phones are held in the hand); "
                         "recognise = let the engine recognise it")
    pi.add_argument("--limit", type=int, default=None, metavar="N", help="evaluate at most N recordings")
    pi.add_argument("--match", action="append", default=None, metavar="TEXT", help="only recordings whose name contains TEXT (repeatable)")
    pi.add_argument("--batch-seconds", type=float, default=1.0, metavar="S", help="upload batch duration of the replay [s]")
    pi.add_argument("--walk-gyro", choices=("on", "on-demand"), default=None,
                    help="auto: the gyroscope while walking, always on (the engine's default) or only while the heading "
                         "needs it (PhoneEngineConfig.walk_gyro; implied by --max-heading-std-deg and --gyro-duty)")
    pi.add_argument("--max-heading-std-deg", type=float, default=None, metavar="DEG",
                    help="auto, on demand: the heading standard deviation above which the gyroscope is asked for "
                         "(default: the engine's, 6 deg): the energy / accuracy trade-off")
    pi.add_argument("--gyro-duty", default=None, metavar="P,ON[,ONLY[,DEG]]",
                    help="auto: duty-cycle the gyroscope where it would be off walking, on for ON of every P seconds "
                         "(PhoneEngineConfig.gyro_duty_period_s / gyro_duty_on_s; default: off); a third field 1: "
                         "full only while the compass's noise is unknown (gyro_duty_only); a fourth: a filled step's "
                         "added turn noise in degrees (gyro_duty_sigma_rad)")
    pi.add_argument("--phases", type=int, default=1, metavar="N",
                    help="also replay with the upload batches' boundaries moved by k/N of a batch (k = 1 .. N-1) and "
                         "report each phase's medians and their mean (an energy-aware engine switches sensors at batch "
                         "boundaries); default 1: phase 0 only")
    pi.add_argument("--calibration", choices=("population", "returning-user"), default="population",
                    help="the step length constant: population = fitted on the other routes (default); returning-user "
                         "= the population's, calibrated by the engine on the user's other walk of the route as a "
                         "known distance (a profile calibrated by POST /v1/sessions/{id}/distance)")
    pi.set_defaults(func=_run_ipin)
    pw = esub.add_parser("phone-watch", help="a phone's and a watch's steps fused (000 eq. 70) on synthetic walks "
                                             "(no public recording has both)")
    pw.add_argument("--json", action="store_true", help="print one JSON document")
    pw.add_argument("--seeds", type=int, default=6, help="synthetic walks (seeds 0..N-1)")
    pw.set_defaults(func=_run_phone_watch)
    pr = esub.add_parser("recordings", help="your own recordings without truth (any importable format): energy "
                                            "against the always-on ZUPT-KF, modes, behaviours, events, gyroscope timeline")
    pr.add_argument("dir", help="folder of recordings (every file and importable sub-folder in it and below)")
    pr.add_argument("--json", action="store_true", help="print one JSON document")
    pr.add_argument("--plot", metavar="OUT_DIR", default=None,
                    help="write a mode/gyroscope/behaviour timeline PNG per recording")
    pr.add_argument("--batch-seconds", type=float, default=1.0, metavar="S", help="upload batch duration of the replay [s]")
    pr.add_argument("--device-batching", action="store_true", help="upload as long as the engine asks")
    pr.add_argument("--set", action="append", default=None, metavar="SECTION.FIELD=VALUE",
                    help="change one engine setting (repeatable)")
    pr.add_argument("--columns", default=None, metavar="SPEC",
                    help="read every CSV in DIR with these columns (as pednav replay --columns); needs --units")
    pr.add_argument("--units", default=None, metavar="SPEC", help="units of the --columns streams (as pednav replay --units)")
    _energy_options(pr, ("auto", "pdr"), "auto")
    pr.set_defaults(func=_run_recordings)
    pp = esub.add_parser("plot", help="energy against accuracy per recording and mode, from saved --json documents "
                                      "of eval vicon/gdin/gaitmap --mode auto|pdr")
    pp.add_argument("docs", nargs="+", metavar="DOC.json", help="saved JSON documents (one series each)")
    pp.add_argument("--out", required=True, metavar="FILE.png", help="PNG to write")
    pp.add_argument("--curve", action="store_true",
                    help="join the documents' medians in the order given (a sweep of one --set value)")
    pp.set_defaults(func=_run_plot)
