"""Gait Driven Inertial Navigation dataset (datasets/gdin/ABOUT.md): truth files, format C and pairing.

Layout::

    own*/SensorConnectData_NN.csv        sensor data, formats A/B (clients.importers.sensorconnect)
    llio_mat/SensorConnectData_NN_*.mat  sensor data, format C (imu_data N x 6 SI, timestamps [s])
    own*/SensorConnectData_NN.mat        ground truth: GCP_meters, GCP_stride_numbers, GCP_exist_and_correct
    stride_gcp/SensorConnectData_NN_*.csv  per-stride rows: strideIndex, timestamp [s], gcpX, gcpY [m]

Recordings are paired by experiment number NN. The stride table's ``strideIndex`` counts samples of a 200 Hz
series; for files at another rate (exp 42/43 at 250 Hz) the stride sample is found by its ``timestamp``.
Arrays other than ``imu_data``/``timestamps`` in format C files (pyshoeTrajectory, traj_wcf, gt ...) are the
dataset authors' estimates or unrelated leftovers and are never imported.

Truth caveats (measured 2026-11-22; the truth is imported as stored, never corrected):

- exp27: GCP_meters describe one 27 m x 1.8 m loop (57.6 m) walked in ``numberOfStrides`` = 62 strides, i.e.
  0.93 m per stride, whereas every other usable recording of the same walker implies 1.22-1.47 m per stride
  (truth path / numberOfStrides). Our ZUPT filter, which is 1-3 % short on the others, finds 1.13 m per stride
  inside a 26.6 m x 2.5 m box and 70.4 m in all: the stored path is most likely about 12 m short (more
  walking than the GCP loop), so exp27's distance error (+22 %) says nothing about the filter.
- own_obsolete (exp 06-28): the truth path is the polygon through the corner GCPs; a walker rounds corners,
  so the walked path is somewhat shorter than the truth path there (not measurable from these files).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import scipy.io as sio

from clients.importers._common import (
    ImporterError,
    check_finite,
    clean_stream,
    drop_untimed_rows,
    gap_notes,
    gyro_unit,
    is_hidden,
    make_batch,
    seconds_to_ns,
)
from clients.importers.sensorconnect import load_sensorconnect
from clients.importers.sensorconnect import sniff as sniff_sensorconnect
from clients.recording import Recording, RecordingMeta, Truth

__all__ = [
    "FORMAT",
    "GdinEntry",
    "sniff",
    "load",
    "load_llio_mat",
    "load_truth_mat",
    "load_stride_gcp",
    "find_gdin",
    "load_gdin",
    "experiment_number",
]

FORMAT = "gdin format C .mat (variables imu_data, timestamps); its SensorConnect CSVs and truth files in the gdin layout"

_EXP = re.compile(r"SensorConnectData_(\d+)")


def experiment_number(path: str | Path) -> int | None:
    """Experiment number NN from a ``SensorConnectData_NN...`` file name, else ``None``."""
    m = _EXP.search(Path(path).name)
    return int(m.group(1)) if m else None


def _mat_names(p: Path) -> set[str]:
    try:
        return {n for n, _, _ in sio.whosmat(p)}
    except Exception:  # noqa: BLE001 - not a MATLAB file
        return set()


def sniff(path: str | Path) -> bool:
    """True for a format C ``.mat`` (``imu_data`` and ``timestamps``)."""
    p = Path(path)
    return p.suffix.lower() == ".mat" and {"imu_data", "timestamps"} <= _mat_names(p)


def load(path: str | Path) -> Recording:
    """Load a gdin sensor file (format A, B or C), attaching its truth when the dataset layout is around it."""
    p = Path(path)
    exp = experiment_number(p)
    root = p.parent.parent
    if exp is not None:
        for e in find_gdin(root, recursive=False):  # the layout around this file only, never a deep scan
            if e.exp == exp and e.sensor_path.resolve() == p.resolve():
                return load_gdin(e)
    if sniff(p):
        return load_llio_mat(p)
    return load_sensorconnect(p)


def load_llio_mat(path: str | Path, name: str | None = None) -> Recording:
    """Read a format C file: ``imu_data`` (N x 6: acc [m/s^2], gyro [rad/s]) and ``timestamps`` (1 x N, [s]).

    Returns
    -------
    Recording
        No magnetometer, no unit conversion, ``truth`` ``None``.
    """
    p = Path(path)
    try:
        d = sio.loadmat(p, variable_names=["imu_data", "timestamps"])
    except Exception as exc:  # noqa: BLE001
        raise ImporterError(p, "file", f"not a readable MATLAB file ({exc})") from exc
    for key in ("imu_data", "timestamps"):
        if key not in d:
            raise ImporterError(p, key, "variable missing (not a gdin format C file)")
    imu = np.asarray(d["imu_data"], dtype=np.float64)
    ts = np.asarray(d["timestamps"], dtype=np.float64).reshape(-1)
    if imu.ndim != 2 or imu.shape[1] != 6:
        raise ImporterError(p, "imu_data", f"expected N x 6 (acc m/s^2, gyro rad/s), got shape {imu.shape}")
    if imu.shape[0] == 0:
        raise ImporterError(p, "imu_data", "no samples (empty)")
    if ts.size != imu.shape[0]:
        raise ImporterError(p, "timestamps", f"{ts.size} timestamps for {imu.shape[0]} imu_data rows")
    keep, notes = drop_untimed_rows(p, "timestamps", ts)
    imu, ts = imu[keep], ts[keep]
    t_all = seconds_to_ns(p, "timestamps", ts)
    acc_t, acc, n1 = clean_stream(p, "timestamps", [f"imu_data[:,{i}]" for i in range(3)], t_all, imu[:, :3])
    gyr_t, gyr, n2 = clean_stream(p, "timestamps", [f"imu_data[:,{i}]" for i in range(3, 6)], t_all, imu[:, 3:])
    notes += n1 + n2
    gyro_unit(p, "imu_data[:,3]", acc_t, acc, gyr_t, gyr, "rad/s", "the format (imu_data: acc m/s^2, gyro rad/s)")
    batch = make_batch(p, acc_t, acc, gyr_t, gyr)
    notes += gap_notes(p, batch)
    meta = RecordingMeta(
        source_format="gdin-llio-mat",
        rate_hz=float(batch.rate_hz("acc")),
        units_converted={},
        mount="foot (MicroStrain 3DM-GX5-25 on one shoe; body axes of the sensor)",
        notes=tuple(notes),
    )
    return Recording(name=name or p.stem, batch=batch, meta=meta, truth=None)


def load_truth_mat(path: str | Path) -> dict[str, Any]:
    """Read a gdin ground-truth ``.mat``.

    Returns
    -------
    dict
        ``gcp_m`` (K, 2) float [m] (cast from possibly integer storage), ``gcp_stride_numbers`` (K,) int or
        None (optional: only plots use it), ``gcp_exist_and_correct`` bool (True when the flag is absent),
        ``number_of_strides`` int or None, ``tile_edge_length_m`` float or None, ``closed_loop`` bool (first
        and last GCP coincide), ``truth_path_length_m`` float, ``truth_notes`` tuple of str (what was missing).
    """
    p = Path(path)
    try:
        d = sio.loadmat(p)
    except Exception as exc:  # noqa: BLE001
        raise ImporterError(p, "file", f"not a readable MATLAB file ({exc})") from exc
    if "GCP_meters" not in d:
        raise ImporterError(p, "GCP_meters", "variable missing (not a gdin ground-truth file)")
    gcp = np.asarray(d["GCP_meters"]).astype(np.float64)  # some files store integers: cast before differencing
    if gcp.ndim != 2 or gcp.shape[1] != 2 or gcp.shape[0] < 2:
        raise ImporterError(p, "GCP_meters", f"expected K x 2 (K >= 2) points [m], got shape {gcp.shape}")
    check_finite(p, ["GCP_meters x", "GCP_meters y"], gcp)
    notes: list[str] = []
    if "GCP_stride_numbers" in d:  # only plots use it: optional
        sn: np.ndarray | None = np.asarray(d["GCP_stride_numbers"]).astype(np.int64).reshape(-1)
        if sn.size != gcp.shape[0]:
            raise ImporterError(p, "GCP_stride_numbers", f"{sn.size} entries for {gcp.shape[0]} GCPs")
    else:
        sn = None
        notes.append("GCP_stride_numbers missing")
    if "GCP_exist_and_correct" in d:
        usable = bool(int(np.asarray(d["GCP_exist_and_correct"]).reshape(-1)[0]) != 0)
    else:  # the authors flag unusable points explicitly; without the flag they are taken as they are
        usable = True
        notes.append("GCP_exist_and_correct missing: ground-control points taken as usable")
    n_str = int(np.asarray(d["numberOfStrides"]).reshape(-1)[0]) if "numberOfStrides" in d else None
    tile = float(np.asarray(d["tile_edge_length"]).reshape(-1)[0]) if "tile_edge_length" in d else None
    seg = np.linalg.norm(np.diff(gcp, axis=0), axis=1)
    return {
        "gcp_m": gcp,
        "gcp_stride_numbers": sn,
        "gcp_exist_and_correct": usable,
        "number_of_strides": n_str,
        "tile_edge_length_m": tile,
        "closed_loop": bool(np.linalg.norm(gcp[-1] - gcp[0]) < 1e-6),
        "truth_path_length_m": float(seg.sum()),
        "truth_notes": tuple(notes),
    }


def load_stride_gcp(path: str | Path) -> dict[str, np.ndarray]:
    """Read a ``stride_gcp`` CSV (header ``strideIndex,timestamp,gcpX,gcpY``).

    Returns
    -------
    dict
        ``stride_index`` (S,) int64 (200 Hz sample numbers), ``t_s`` (S,) float [s], ``gcp_xy`` (S, 2) [m].
    """
    p = Path(path)
    with open(p, encoding="utf-8") as fh:
        header = [c.strip() for c in fh.readline().strip().split(",")]
    if header != ["strideIndex", "timestamp", "gcpX", "gcpY"]:
        raise ImporterError(p, "header", f"expected strideIndex,timestamp,gcpX,gcpY, got {','.join(header)}")
    a = np.atleast_2d(np.genfromtxt(p, delimiter=",", skip_header=1, dtype=np.float64))
    if a.size == 0:
        raise ImporterError(p, "rows", "no strides (empty file)")
    check_finite(p, header, a)
    if np.any(np.diff(a[:, 1]) <= 0):
        raise ImporterError(p, "timestamp", "stride timestamps are not strictly increasing")
    return {"stride_index": np.round(a[:, 0]).astype(np.int64), "t_s": a[:, 1].copy(), "gcp_xy": a[:, 2:4].copy()}


@dataclass(frozen=True)
class GdinEntry:
    """One gdin recording: its sensor file and the truth files paired by experiment number."""

    exp: int
    sensor_path: Path
    truth_path: Path | None
    stride_path: Path | None

    @property
    def name(self) -> str:
        return f"exp{self.exp:02d}"


def find_gdin(root: str | Path, recursive: bool = True) -> list[GdinEntry]:
    """Pair every gdin sensor file under ``root`` with its truth by experiment number (sorted by NN).

    Sensor files: ``<folder>/SensorConnectData_NN.csv`` (formats A/B) and ``llio_mat/SensorConnectData_NN_*.mat``
    (format C). Truth: ``<folder>/SensorConnectData_NN.mat`` (excluding llio_mat) and
    ``stride_gcp/SensorConnectData_NN_*.csv``. The folders may sit at any depth below ``root`` (the dataset
    repository keeps them under ``data/``); when one experiment's file of a kind appears at several depths the
    shallowest is used, at one depth the last in path order, and a CSV beats a format C copy of the same
    experiment. Extensions are matched in any case; hidden files and folders (dotfiles, macOS ``._*`` resource
    forks, a ``.Trash`` or ``.git`` below ``root``) are skipped. ``recursive=False``: only the folders directly below
    ``root`` (what pairing one sensor file with its truth needs).
    """
    r = Path(root)
    sensors: dict[int, Path] = {}
    truths: dict[int, Path] = {}
    strides: dict[int, Path] = {}
    candidates = r.rglob("SensorConnectData_*") if recursive else r.glob("*/SensorConnectData_*")
    found = [f for f in candidates if f.is_file() and f.parent != r and not is_hidden(f.relative_to(r))]
    for f in sorted(found, key=lambda f: (-len(f.relative_to(r).parts), str(f))):  # deepest first: shallow wins
        exp = experiment_number(f)
        if exp is None:
            continue
        folder = f.parent.name
        if folder == "stride_gcp" and f.suffix.lower() == ".csv":
            strides[exp] = f
        elif folder == "llio_mat" and f.suffix.lower() == ".mat":
            if exp not in sensors or sensors[exp].suffix.lower() == ".mat":
                sensors[exp] = f
        elif f.suffix.lower() == ".csv" and re.fullmatch(r"SensorConnectData_\d+", f.stem):
            sensors[exp] = f  # a CSV beats a format C copy of the same experiment (it has the magnetometer)
        elif f.suffix.lower() == ".mat" and re.fullmatch(r"SensorConnectData_\d+", f.stem):
            truths[exp] = f
    return [GdinEntry(e, sensors[e], truths.get(e), strides.get(e)) for e in sorted(sensors)]


def _stride_times(rec: Recording, table: dict[str, np.ndarray]) -> tuple[np.ndarray, str]:
    """Batch-clock times [ns] of the stride samples: by strideIndex for 200 Hz files, by timestamp otherwise."""
    t = rec.batch.acc_t_ns
    idx = table["stride_index"]
    by_index_ok = abs(rec.meta.rate_hz - 200.0) < 5.0 and idx.max() < t.size
    if by_index_ok:
        # the table's timestamps must agree with the file's clock at those samples (else it is not 200 Hz-indexed)
        by_index_ok = bool(np.all(np.abs(t[idx] * 1e-9 - table["t_s"]) < 0.5 / rec.meta.rate_hz + 1e-6))
    if by_index_ok:
        return t[idx].copy(), "strideIndex"
    target = np.round(table["t_s"] * 1e9).astype(np.int64)
    j = np.clip(np.searchsorted(t, target), 1, t.size - 1)
    j = np.where(np.abs(t[j - 1] - target) <= np.abs(t[j] - target), j - 1, j)
    return t[j].copy(), "timestamp"


def _strides_inside(rec: Recording, table: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], str | None]:
    """The stride table's rows whose ``timestamp`` [s] lies within the recording (one sample period of slack),
    and a note naming what was left out (``None`` when every stride is inside)."""
    t = rec.batch.acc_t_ns
    slack_s = 1.0 / rec.meta.rate_hz if rec.meta.rate_hz > 0 else 0.0
    t0_s, t1_s = float(t[0]) * 1e-9 - slack_s, float(t[-1]) * 1e-9 + slack_s
    inside = (table["t_s"] >= t0_s) & (table["t_s"] <= t1_s)
    if inside.all():
        return table, None
    note = (f"stride table: {int((~inside).sum())} of {inside.size} strides lie outside the recording "
            f"({t[0] * 1e-9:.2f}-{t[-1] * 1e-9:.2f} s; the table runs {table['t_s'][0]:.2f}-{table['t_s'][-1]:.2f} s): "
            "the sensor file is cut short; those strides are left out and the truth path does not match the recording")
    if not inside[0] and inside.any():  # strides are compared from the first one on: a cut start shifts them all
        inside[:] = False
        note += "; the first stride is missing too, so no stride is compared"
    return {k: v[inside] for k, v in table.items()}, note


def load_gdin(entry: GdinEntry) -> Recording:
    """Load a gdin recording with its truth.

    ``truth.extra`` keys: ``exp``, the keys of :func:`load_truth_mat` (when a truth .mat exists), and with a
    stride table ``stride_t_ns`` (S,) int64 [ns on the batch clock], ``stride_gcp_xy`` (S, 2) [m, authors'
    frame], ``stride_index`` (S,), ``stride_table_t_s`` (S,) [s], ``stride_mapping`` (``"strideIndex"`` or ``"timestamp"``).
    A stride table that runs past either end of the recording (a sensor file cut short) keeps only the strides
    inside it, adds a ``truth_notes`` entry and sets ``truth_covers_recording`` False (the truth path then
    describes more than was recorded).
    """
    if entry.sensor_path.suffix.lower() == ".mat":
        rec = load_llio_mat(entry.sensor_path, name=entry.name)
    elif sniff_sensorconnect(entry.sensor_path):
        rec = load_sensorconnect(entry.sensor_path, name=entry.name)
    else:
        try:  # says what is wrong with the header (missing Time / acc columns, empty file ...)
            load_sensorconnect(entry.sensor_path, name=entry.name)
        except ImporterError as exc:
            problem = f"not a gdin sensor file (format A, B or C): {exc.problem}"
            raise ImporterError(exc.path, exc.field, problem) from exc
        raise ImporterError(entry.sensor_path, "file", "not a gdin sensor file (format A, B or C)")
    extra: dict[str, Any] = {"exp": entry.exp}
    if entry.truth_path is not None:
        extra.update(load_truth_mat(entry.truth_path))
    if entry.stride_path is not None:
        table = load_stride_gcp(entry.stride_path)
        table, cut_note = _strides_inside(rec, table)
        if cut_note is not None:
            # the sensor file ends (or starts) inside the walk its truth describes: a stride past its end would
            # be placed on the last sample, and the truth path is longer than what was recorded
            extra["truth_notes"] = tuple(extra.get("truth_notes", ())) + (cut_note,)
            extra["truth_covers_recording"] = False
        t_ns, how = _stride_times(rec, table)
        extra.update(
            stride_t_ns=t_ns,
            stride_gcp_xy=table["gcp_xy"],
            stride_index=table["stride_index"],
            stride_table_t_s=table["t_s"],
            stride_mapping=how,
        )
    truth = Truth(extra=extra) if len(extra) > 1 else None
    return Recording(name=rec.name, batch=rec.batch, meta=rec.meta, truth=truth)
