"""A user's own recordings without truth: what the engine did with each, and what it cost.

``pednav eval recordings DIR`` takes every file under DIR (and every sub-folder an importer reads as one
recording, e.g. a Sensor Logger export) as a candidate (:func:`candidates`), imports it as ``pednav replay FILE``
does (:func:`clients.importers.load`), replays it through the engine in the evaluated mode and through the
always-on baseline (``zupt``), and reports per recording (:func:`evaluate_recording`):

- ``energy_ratio``, ``gyro_on_fraction`` and ``energy`` as :func:`clients.evaluation.energy_ratio.compare` (no
  truth: ``accuracy_ratio`` and ``accuracy_metric`` are None);
- ``modes``: fraction of the processed time in ``zupt``/``pdr``/``idle``; ``behaviour``: in
  ``stand``/``walk``/``run``/``other`` (time-weighted over the processed samples,
  :func:`clients.evaluation.harness.mode_fractions`, :func:`~clients.evaluation.harness.behaviour_fractions`);
- ``events``: how often the engine reported each event kind; ``gyro_timeline``: ``[[t_on_s, t_off_s], ...]``,
  the stretches the gyroscope was powered, from the recording's first sample;
- ``strides`` (strides that moved, :func:`energy.strides.count_moved`), ``stances``, ``path_m`` (horizontal path
  of the reported positions), ``duration_s``, ``format`` and the importer's ``notes``.

A candidate that cannot be imported or replayed becomes ``{"name", "file", "error"}`` with the reason.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from clients.evaluation import metrics
from clients.evaluation.energy_ratio import EnergyAccounting, add_summary, compare, gyro_intervals
from clients.evaluation.harness import Evaluated, Runner, behaviour_fractions, mode_fractions
from clients.importers._common import is_hidden
from clients.recording import Recording, require_gyroscope
from energy.strides import count_moved

__all__ = ["candidates", "evaluate_recording", "recordings_summary"]


def candidates(directory: str | Path) -> list[Path]:
    """Every non-hidden file under ``directory`` and every sub-folder an importer reads as one recording (not
    descended into), sorted; other sub-folders are descended into. Whether a file is a recording is for the
    importers to say (:func:`clients.importers.load`), so a file no importer recognises is a candidate too."""
    from clients.importers import importer_for

    d = Path(directory)
    out: list[Path] = []
    for f in sorted(d.iterdir()):
        if is_hidden(f.name):
            continue
        if f.is_dir():
            out += [f] if importer_for(f) is not None else candidates(f)
        elif f.is_file():
            out.append(f)
    return out


def evaluate_recording(rec: Recording, runner: Runner, mode: str, accounting: EnergyAccounting) -> Evaluated:
    """The row of one recording (module docstring); the plot dict holds what a timeline plot needs: ``t_s``,
    ``mode``, ``behaviour`` per processed sample and ``gyro_timeline`` (times from the recording's start [s])."""
    require_gyroscope(rec, rec.name)
    run = runner(rec.batch, mode, None)
    ref = runner(rec.batch, "zupt", None)
    st = run.stances
    t0 = int(rec.batch.t_start_ns or 0)
    gyro = gyro_intervals(run.timeline, t0) if run.timeline is not None else []
    row: dict[str, Any] = {
        "name": rec.name,
        "format": rec.meta.source_format,
        "mode": mode,
        "duration_s": (int(rec.batch.t_end_ns or 0) - t0) / 1e9,
        **compare(accounting, mode, run, ref),
        "modes": mode_fractions(run.t_ns, run.mode) if run.mode is not None else {},
        "behaviour": behaviour_fractions(run.t_ns, run.behaviour),
        "events": dict(sorted(Counter(kind for kind, _ in run.events).items())),
        "gyro_timeline": gyro,
        "strides": count_moved(st[:, 1:3]),
        "stances": int(st.shape[0]),
        "path_m": metrics.path_length_xy(st[:, 1:3]) if st.shape[0] >= 2 else 0.0,
    }
    if rec.meta.notes:
        row["notes"] = list(rec.meta.notes)
    plot = {"t_s": (np.asarray(run.t_ns, dtype=np.int64) - t0) / 1e9, "mode": run.mode, "behaviour": run.behaviour,
            "gyro_timeline": gyro, "duration_s": row["duration_s"]}
    return Evaluated(row, plot)


def recordings_summary(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """``recordings`` (replayed), ``failed``, and ``{"mean", "median", "worst", "n"}`` of ``energy_ratio``,
    ``gyro_on_fraction`` and ``accuracy_ratio`` (always ``n`` 0: no truth) over the replayed ones."""
    ok = [r for r in rows if "error" not in r]
    return add_summary({"recordings": len(ok), "failed": len(rows) - len(ok)}, ok)
