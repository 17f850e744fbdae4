"""Importers on the damaged and unusual files real loggers write (sample policy of clients.importers._common).

Every file is generated in memory (tmp_path): the five formats of the evaluation data (gdin A/B/C, VICON,
gaitmap) with empty cells, unreadable time cells, a line cut mid-write, repeated and conflicting timestamps.
A few samples that cannot be used are dropped and noted; a file is refused only when it is unusable, and the
message names the file, the column and the problem.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import scipy.io as sio
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clients.importers import ImporterError, load
from clients.importers._common import G0, MAX_CONFLICT_FRACTION
from clients.importers.gaitmap import load_gaitmap
from clients.importers.gdin import load_llio_mat
from clients.importers.sensorconnect import load_sensorconnect
from clients.importers.vicon import load_vicon
from models.batch import SensorBatch

PREFIX = "inertial-6253.76535:"
N = 400

# ---------------------------------------------------------------------------------------------- writers
# Each writer takes a rows array (N, 1 + 6 [+ 3]): time [s], acc, gyr [, mag] in the file's own units, and
# writes the file; ``rows`` comes from _rows() so every format starts from the same still sensor.


def _rows(n: int = N, rate: float = 200.0, acc_unit: float = 1.0, mag: bool = True) -> np.ndarray:
    rng = np.random.default_rng(7)
    t = np.arange(n) / rate
    acc = (np.tile([0.0, 0.0, 1.0], (n, 1)) + 0.002 * rng.standard_normal((n, 3))) * acc_unit
    gyr = 0.01 * rng.standard_normal((n, 3))
    cols = [t[:, None], acc, gyr]
    if mag:
        cols.append(np.tile([0.2, 0.0, -0.4], (n, 1)) + 0.001 * rng.standard_normal((n, 3)))
    return np.hstack(cols)


def _csv(path: Path, header: list[str], rows: np.ndarray, cut_last: bool = False) -> Path:
    lines = [",".join(header)]
    lines += [",".join("" if not np.isfinite(v) else f"{v:.9g}" for v in r) for r in rows]
    if cut_last:
        lines[-1] = lines[-1][: len(lines[-1]) // 2]  # the logger stopped mid-write
    path.write_text("\n".join(lines) + "\n")
    return path


def write_a(path: Path, rows: np.ndarray, cut_last: bool = False) -> Path:
    names = ["Time"] + [PREFIX + f"scaled{s}{a}" for s in ("Accel", "Gyro", "Mag") for a in "XYZ"][: rows.shape[1] - 1]
    return _csv(path, names, rows, cut_last)


def write_b(path: Path, rows: np.ndarray, cut_last: bool = False) -> Path:
    names, cols = ["Time"], [rows[:, 0]]
    for k, c in enumerate(f"{s}{a}" for s in ("estCompensatedAccel", "estAngularRate") for a in "XYZ"):
        names += [PREFIX + c, PREFIX + c + ":valid"]
        cols += [rows[:, 1 + k] * (G0 if k < 3 else 1.0), np.ones(len(rows))]
    return _csv(path, names, np.column_stack(cols), cut_last)


def write_c(path: Path, rows: np.ndarray, cut_last: bool = False) -> Path:
    imu = np.column_stack([rows[:, 1:4] * G0, rows[:, 4:7]])
    sio.savemat(path, {"imu_data": imu, "timestamps": rows[:, 0][None, :]})
    return path


def write_vicon(path: Path, rows: np.ndarray, cut_last: bool = False) -> Path:
    n = len(rows)
    imu = np.column_stack([rows[:, 1:4] * -G0, rows[:, 4:7]])  # z down
    gt = np.column_stack([np.linspace(0.0, 1.0, n), np.zeros(n), np.full(n, 0.1)])
    sio.savemat(path, {"imu": imu, "ts": rows[:, 0][None, :], "gt": gt})
    return path


def write_gaitmap(path: Path, rows: np.ndarray, cut_last: bool = False) -> Path:
    data = np.column_stack([rows[:, 0], rows[:, 1:4] * G0, np.rad2deg(rows[:, 4:7])])
    return _csv(path, ["", "acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z"], data, cut_last)


FORMATS: dict[str, tuple[Callable[..., Path], str, bool]] = {  # writer, file name, has a magnetometer
    "A": (write_a, "SensorConnectData_90.csv", True),
    "B": (write_b, "SensorConnectData_91.csv", False),
    "C": (write_c, "SensorConnectData_92_LLIO.mat", False),
    "vicon": (write_vicon, "2099-01-01-00-00-00.mat", False),
    "gaitmap": (write_gaitmap, "walk_in_seconds.csv", False),
}
CSV_FORMATS = ("A", "B", "gaitmap")


def _write(tmp_path: Path, fmt: str, rows: np.ndarray | None = None, **kw: bool) -> Path:
    writer, name, mag = FORMATS[fmt]
    if rows is None:
        rows = _rows(mag=mag)
    return writer(tmp_path / name, rows, **kw)


def _notes(rec) -> str:
    return " | ".join(rec.meta.notes)


# ---------------------------------------------------------------------------------------------- non-finite samples
@pytest.mark.parametrize("fmt", list(FORMATS))
def test_empty_rows_are_dropped_not_the_recording(tmp_path: Path, fmt: str) -> None:
    rows = _rows(mag=FORMATS[fmt][2])
    rows[[50, 51, 300], 1:] = np.nan  # a logging glitch: the whole row empty but its time
    rec = load(_write(tmp_path, fmt, rows))
    assert len(rec.batch) == N - 3 and len(rec.batch.gyr_t_ns) == N - 3
    assert not np.isin(rec.batch.acc_t_ns, np.round(rows[[50, 51, 300], 0] * 1e9).astype(np.int64)).any()
    assert "non-finite" in _notes(rec) and "row 50" in _notes(rec)


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_a_missing_gyro_sample_leaves_the_accelerometer_sample(tmp_path: Path, fmt: str) -> None:
    rows = _rows(mag=FORMATS[fmt][2])
    rows[120, 4:7] = np.nan
    rec = load(_write(tmp_path, fmt, rows))
    assert len(rec.batch) == N and len(rec.batch.gyr_t_ns) == N - 1
    assert rec.batch.acc_t_ns[120] not in set(rec.batch.gyr_t_ns.tolist())


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_rows_without_a_time_are_dropped(tmp_path: Path, fmt: str) -> None:
    rows = _rows(mag=FORMATS[fmt][2])
    rows[[3, 200], 0] = np.nan
    rec = load(_write(tmp_path, fmt, rows))
    assert len(rec.batch) == N - 2
    assert "time is not finite" in _notes(rec)


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_a_file_mostly_without_times_is_refused_by_name(tmp_path: Path, fmt: str) -> None:
    rows = _rows(mag=FORMATS[fmt][2])
    rows[::3, 0] = np.nan
    with pytest.raises(ImporterError, match="no usable time") as ei:
        load(_write(tmp_path, fmt, rows))
    assert FORMATS[fmt][1] in str(ei.value)


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_a_stream_without_finite_values_is_refused_by_name(tmp_path: Path, fmt: str) -> None:
    rows = _rows(mag=FORMATS[fmt][2])
    rows[:, 4:7] = np.nan
    with pytest.raises(ImporterError, match="finite") as ei:
        load(_write(tmp_path, fmt, rows))
    assert FORMATS[fmt][1] in str(ei.value)


def test_format_a_magnetometer_at_half_rate(tmp_path: Path) -> None:
    """SensorConnect leaves a slower channel's cells empty on the rows it has no sample for."""
    rows = _rows()
    rows[1::2, 7:10] = np.nan
    rec = load_sensorconnect(write_a(tmp_path / "a.csv", rows))
    assert len(rec.batch) == N and len(rec.batch.mag_t_ns) == N // 2
    assert rec.batch.rate_hz("mag") == pytest.approx(100.0, rel=1e-3)


def test_format_a_magnetometer_columns_all_empty(tmp_path: Path) -> None:
    rows = _rows()
    rows[:, 7:10] = np.nan
    rec = load_sensorconnect(write_a(tmp_path / "a.csv", rows))
    assert rec.batch.mag.shape == (0, 3) and "stream left out" in _notes(rec)
    assert "mag" not in rec.meta.units_converted


def test_vicon_occluded_marker_leaves_those_truth_samples_out(tmp_path: Path) -> None:
    p = write_vicon(tmp_path / "v.mat", _rows(mag=False))
    d = sio.loadmat(p)
    d["gt"][100:140] = np.nan  # marker occluded for 0.2 s
    d["gt"][0] = np.nan
    sio.savemat(p, {k: v for k, v in d.items() if not k.startswith("__")})
    rec = load_vicon(p)
    assert len(rec.batch) == N
    assert rec.truth.positions.shape == (N - 41, 3) and rec.truth.t_ns.shape == (N - 41,)
    assert np.all(np.isfinite(rec.truth.positions)) and "gt x" in _notes(rec)


# ---------------------------------------------------------------------------------------------- timestamps
@pytest.mark.parametrize("fmt", list(FORMATS))
def test_conflicting_duplicated_timestamp_drops_both_samples(tmp_path: Path, fmt: str) -> None:
    rows = _rows(mag=FORMATS[fmt][2])
    rows[41, 0] = rows[40, 0]  # the clock stalled for one sample: same time, another sample
    rec = load(_write(tmp_path, fmt, rows))
    assert len(rec.batch) == N - 2
    assert np.all(np.diff(rec.batch.acc_t_ns) > 0)
    assert "cannot tell which is right" in _notes(rec)


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_a_clock_too_coarse_for_the_rate_is_refused(tmp_path: Path, fmt: str) -> None:
    rows = _rows(mag=FORMATS[fmt][2])
    k = int(MAX_CONFLICT_FRACTION * N) + 2
    rows[1 : 2 * k : 2, 0] = rows[0 : 2 * k - 1 : 2, 0]
    with pytest.raises(ImporterError, match="too coarse"):
        load(_write(tmp_path, fmt, rows))


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_exact_duplicates_and_backwards_time_keep_their_policy(tmp_path: Path, fmt: str) -> None:
    rows = _rows(mag=FORMATS[fmt][2])
    rec = load(_write(tmp_path, fmt, np.insert(rows, 50, rows[49], axis=0)))
    assert len(rec.batch) == N and "exact duplicate" in _notes(rec)
    rows[40, 0] = 0.1
    with pytest.raises(ImporterError, match="backwards"):
        load(_write(tmp_path, fmt, rows))


# ---------------------------------------------------------------------------------------------- malformed lines
@pytest.mark.parametrize("fmt", CSV_FORMATS)
def test_a_last_line_cut_mid_write_is_skipped(tmp_path: Path, fmt: str) -> None:
    rec = load(_write(tmp_path, fmt, cut_last=True))
    assert len(rec.batch) == N - 1
    assert f"line {N + 1}" in _notes(rec)


@pytest.mark.parametrize("fmt", CSV_FORMATS)
def test_a_file_of_malformed_lines_is_refused(tmp_path: Path, fmt: str) -> None:
    p = _write(tmp_path, fmt)
    lines = p.read_text().splitlines()
    lines[1:] = [ln + ",1" if i % 4 == 0 else ln for i, ln in enumerate(lines[1:])]
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(ImporterError, match="fields"):
        load(p)


@pytest.mark.parametrize("fmt", CSV_FORMATS)
def test_crlf_line_ends_and_a_byte_order_mark(tmp_path: Path, fmt: str) -> None:
    p = _write(tmp_path, fmt)
    ref = load(p)
    p.write_bytes(b"\xef\xbb\xbf" + p.read_bytes().replace(b"\n", b"\r\n"))
    rec = load(p)
    np.testing.assert_array_equal(rec.batch.acc_t_ns, ref.batch.acc_t_ns)
    np.testing.assert_array_equal(rec.batch.gyr, ref.batch.gyr)


@pytest.mark.parametrize("prefix", ["inertial-6253.76535:", "inertial-1234.99999:", ""])
def test_format_a_columns_by_name_any_node_id_any_order(tmp_path: Path, prefix: str) -> None:
    rows = _rows()
    names = ["Time"] + [prefix + f"scaled{s}{a}" for s in ("Accel", "Gyro", "Mag") for a in "XYZ"]
    ref = load_sensorconnect(_csv(tmp_path / "ref.csv", names, rows))
    order = [3, 9, 0, 1, 5, 4, 2, 8, 7, 6]  # Time in the middle
    extra = np.column_stack([rows[:, order], np.full(N, 21.5)])
    rec = load(_csv(tmp_path / "SensorConnectData_93.csv", [names[i] for i in order] + [prefix + "temperature"], extra))
    np.testing.assert_array_equal(rec.batch.acc_t_ns, ref.batch.acc_t_ns)
    np.testing.assert_allclose(rec.batch.acc, ref.batch.acc)
    np.testing.assert_allclose(rec.batch.mag, ref.batch.mag)


# ---------------------------------------------------------------------------------------------- property
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cells=st.lists(st.tuples(st.integers(0, N - 1), st.integers(0, 9)), max_size=30))
def test_format_a_any_empty_cells_give_finite_increasing_streams(tmp_path: Path, cells: list[tuple[int, int]]) -> None:
    rows = _rows()
    for r, c in cells:
        rows[r, c] = np.nan
    rec = load_sensorconnect(write_a(tmp_path / "h.csv", rows))
    b = rec.batch
    bad_t = {r for r, c in cells if c == 0}
    for name, c0 in (("acc", 1), ("gyr", 4), ("mag", 7)):
        t, v = b.stream(name)
        lost = {r for r, c in cells if c0 <= c < c0 + 3} | bad_t
        assert len(t) == N - len(lost)
        assert np.all(np.isfinite(v)) and np.all(np.diff(t) > 0)


def test_llio_mat_with_nan_rows_keeps_the_rest(tmp_path: Path) -> None:
    rows = _rows(mag=False)
    rows[7] = np.nan  # time and values
    rec = load_llio_mat(write_c(tmp_path / "c.mat", rows))
    assert len(rec.batch) == N - 1


def test_gaitmap_index_with_a_dropped_sample_is_still_an_index(tmp_path: Path) -> None:
    n = 300
    rows = np.column_stack([np.arange(n), np.tile([0.0, 0.0, 9.81, 0.0, 0.0, 0.0], (n, 1))])
    rows = np.delete(rows, 100, axis=0)  # sample 100 lost: the index steps by 2 once
    p = tmp_path / "walk.csv"
    np.savetxt(p, rows, delimiter=",", header=",acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z", comments="")
    rec = load_gaitmap(p, rate_hz=200.0)
    assert rec.meta.rate_hz == pytest.approx(200.0)
    assert rec.batch.acc_t_ns[-1] == pytest.approx((n - 1) / 200.0 * 1e9)


# ---------------------------------------------------------------------------------------------- 6-axis format A
@pytest.mark.parametrize("mag_cols", [(), ("X", "Y")])
def test_format_a_without_magnetometer_columns_is_a_six_axis_recording(
    tmp_path: Path, mag_cols: tuple[str, ...]
) -> None:
    rows = _rows(mag=False)
    names = ["Time"] + [PREFIX + f"scaled{s}{a}" for s in ("Accel", "Gyro") for a in "XYZ"]
    names += [PREFIX + f"scaledMag{a}" for a in mag_cols]
    extra = np.column_stack([rows] + [np.full(N, 0.3)] * len(mag_cols))
    rows_out = np.column_stack([extra, np.zeros(N)])
    rec = load(_csv(tmp_path / "SensorConnectData_94.csv", names + [PREFIX + "roll"], rows_out))
    assert rec.meta.source_format == "sensorconnect-a" and len(rec.batch) == N
    assert rec.batch.mag.shape == (0, 3) and "mag" not in rec.meta.units_converted
    assert ("without magnetometer" if not mag_cols else "scaledMagZ missing") in _notes(rec)
    np.testing.assert_allclose(rec.batch.acc, rows[:, 1:4] * G0, rtol=1e-6)


# ---------------------------------------------------------------------------------------------- time units
@pytest.mark.parametrize("fmt", list(FORMATS))
@pytest.mark.parametrize(("scale", "unit"), [(1e3, "milliseconds"), (1e6, "microseconds"), (1e9, "nanoseconds")])
def test_times_in_another_unit_than_seconds_are_refused_not_rescaled(
    tmp_path: Path, fmt: str, scale: float, unit: str
) -> None:
    rows = _rows(mag=FORMATS[fmt][2])
    epoch = 1.7e18 if scale == 1e9 and fmt in ("C", "vicon") else 0.0  # an epoch clock where the file keeps 17 digits
    rows[:, 0] = np.round(rows[:, 0] * scale + epoch)
    with pytest.raises(ImporterError, match=unit) as ei:
        load(_write(tmp_path, fmt, rows))
    assert FORMATS[fmt][1] in str(ei.value)


@pytest.mark.parametrize("rate", [20.0, 100.0, 250.0, 400.0, 1000.0])
def test_plausible_rates_pass_the_time_unit_check(tmp_path: Path, rate: float) -> None:
    rec = load(write_a(tmp_path / "SensorConnectData_95.csv", _rows(rate=rate)))
    assert rec.meta.rate_hz == pytest.approx(rate, rel=1e-3)


# ---------------------------------------------------------------------------------------------- gdin truth
def _truth(path: Path, drop: tuple[str, ...] = (), **kw: np.ndarray) -> Path:
    d = {"GCP_meters": np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 2.0], [0.0, 0.0]]),
         "GCP_stride_numbers": np.array([[0, 2, 4, 6]]), "GCP_exist_and_correct": np.array([[1]], dtype=bool),
         "numberOfStrides": np.array([[6.0]]), "tile_edge_length": np.array([[0.6]]), "expID": np.array([[96.0]])}
    d.update(kw)
    sio.savemat(path, {k: v for k, v in d.items() if k not in drop})
    return path


@pytest.mark.parametrize(
    ("drop", "kw", "usable"),
    [
        (("GCP_stride_numbers",), {}, True),
        (("GCP_exist_and_correct",), {}, True),
        (("numberOfStrides", "tile_edge_length", "expID"), {}, True),
        ((), {"GCP_meters": np.array([[0, 0], [3, 0], [3, 2], [0, 0]], dtype=np.int16)}, True),
        ((), {"GCP_stride_numbers": np.array([[0], [2], [4], [6]], dtype=np.uint8)}, True),
        ((), {"GCP_exist_and_correct": np.array([[0.0]])}, False),
    ],
)
def test_gdin_truth_optional_fields_and_types(tmp_path: Path, drop: tuple[str, ...], kw: dict, usable: bool) -> None:
    from clients.importers.gdin import load_truth_mat

    x = load_truth_mat(_truth(tmp_path / "SensorConnectData_96.mat", drop, **kw))
    assert x["gcp_m"].dtype == np.float64 and x["closed_loop"]
    assert x["truth_path_length_m"] == pytest.approx(3.0 + 2.0 + np.hypot(3.0, 2.0))
    assert x["gcp_exist_and_correct"] is usable
    for k in drop:
        assert any(k in n for n in x["truth_notes"]) or k in ("numberOfStrides", "tile_edge_length", "expID")


def test_gdin_truth_without_ground_control_points_is_refused_by_name(tmp_path: Path) -> None:
    from clients.importers.gdin import load_truth_mat

    with pytest.raises(ImporterError, match="GCP_meters") as ei:
        load_truth_mat(_truth(tmp_path / "SensorConnectData_97.mat", ("GCP_meters",)))
    assert "SensorConnectData_97.mat" in str(ei.value)


# ---------------------------------------------------------------------------------------------- gaitmap layouts
def test_gaitmap_without_index_column_says_so_instead_of_reading_acc_x_as_a_clock(tmp_path: Path) -> None:
    """A gaitmap DataFrame saved without its index: before, "acc_x: timestamps go backwards"."""
    rows = _rows(mag=False)
    data = np.column_stack([rows[:, 1:4] * G0, np.rad2deg(rows[:, 4:7])])
    p = _csv(tmp_path / "no_index.csv", ["acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z"], data)
    with pytest.raises(ImporterError, match="no sample index or time") as ei:
        load(p)
    assert ei.value.field == "acc_x" and "no_index.csv" in str(ei.value)
    rec = load_gaitmap(p, rate_hz=200.0)
    assert len(rec.batch) == N and rec.meta.rate_hz == pytest.approx(200.0)
    np.testing.assert_allclose(rec.batch.acc, rows[:, 1:4] * G0, rtol=1e-6)
    assert "consecutive samples" in _notes(rec)


def test_gaitmap_two_sensor_file_with_only_the_right_foot(tmp_path: Path) -> None:
    """load()/replay took the left foot and failed with "acc_x: column missing for left_sensor"."""
    from clients.importers.gaitmap import sensor_feet

    rows = _rows(mag=False)
    data = np.column_stack([np.arange(N), rows[:, 1:4] * G0, np.rad2deg(rows[:, 4:7])])
    p = tmp_path / "imu_sample.csv"  # a documented name: its rate (204.8 Hz) is known
    head = "sensor," + ",".join(["right_sensor"] * 6) + "\naxis,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z\n"
    p.write_text(head + "\n".join(",".join(f"{v:.9g}" for v in r) for r in data) + "\n")
    assert sensor_feet(p) == ("right",)
    rec = load(p)
    assert rec.name == "imu_sample-right" and len(rec.batch) == N
    np.testing.assert_allclose(rec.batch.gyr, rows[:, 4:7], rtol=1e-6, atol=1e-9)


def test_format_a_export_of_two_nodes_is_refused_not_mixed(tmp_path: Path) -> None:
    """SensorConnect can export several nodes into one CSV; the first node's columns were taken silently."""
    rows = _rows()
    names = ["Time"] + [f"inertial-{node}:scaled{s}{a}" for node in ("6253.76535", "6253.99999")
                        for s in ("Accel", "Gyro", "Mag") for a in "XYZ"]
    p = _csv(tmp_path / "SensorConnectData_89.csv", names, np.column_stack([rows, rows[:, 1:]]))
    with pytest.raises(ImporterError, match="several sensor nodes") as ei:
        load(p)
    assert ei.value.field == "scaledAccelX"


# ---------------------------------------------------------------------------------------------- hidden files
# The start of a real AppleDouble file (macOS writes one as ._NAME beside every file copied to a FAT/exFAT or
# network drive): magic 0x00051607, "Mac OS X", entry table; bytes that are not UTF-8 either.
APPLEDOUBLE = (b"\x00\x05\x16\x07\x00\x02\x00\x00Mac OS X        \x00\x02\x00\x00\x00\x09\x00\x00\x00\x32"
               b"\x00\x00\x0e\xb0\x00\x00\x00\x02\x00\x00\x0e\xe2\x00\x00\x01\x1e" + bytes(300))


def test_folder_scans_skip_dotfiles_and_macos_resource_forks(tmp_path: Path) -> None:
    """A dotfile or a hidden folder (.Trash, a ._NAME resource fork) is never a recording, whatever it holds."""
    from clients.importers import list_recordings
    from clients.importers.gdin import find_gdin

    root = tmp_path / "gdin"
    (root / "own").mkdir(parents=True)
    (root / ".Trash" / "own").mkdir(parents=True)
    good = write_a(root / "own" / "SensorConnectData_90.csv", _rows())
    (root / "own" / "._SensorConnectData_90.csv").write_bytes(APPLEDOUBLE)
    write_a(root / "own" / ".SensorConnectData_91.csv", _rows())  # readable, but hidden
    write_a(root / ".Trash" / "own" / "SensorConnectData_92.csv", _rows())
    assert list_recordings(root) == [good]
    assert [e.exp for e in find_gdin(root)] == [90]


def test_loading_a_resource_fork_says_what_it_is(tmp_path: Path) -> None:
    p = tmp_path / "._2099-01-01-00-00-00.mat"
    p.write_bytes(APPLEDOUBLE)
    with pytest.raises(ImporterError, match="AppleDouble") as ei:
        load(p)
    assert "2099-01-01-00-00-00.mat" in str(ei.value) and ei.value.field == "file"


def test_phyphox_zip_from_a_mac_ignores_its_macosx_folder(tmp_path: Path) -> None:
    """macOS's "Compress" adds __MACOSX/._NAME for every file; reading them as tables failed on their bytes."""
    import zipfile

    from clients.importers.phyphox import load_phyphox

    n = 400
    head = '"Time (s)","{0} x ({1})","{0} y ({1})","{0} z ({1})"'
    acc = [head.format("Acceleration", "m/s^2")] + [f"{k / 100:.2f},0.1,0.2,9.80" for k in range(n)]
    gyr = [head.format("Gyroscope", "rad/s")] + [f"{k / 100:.2f},0.01,0.0,0.0" for k in range(n)]
    p = tmp_path / "walk.zip"
    with zipfile.ZipFile(p, "w") as zf:
        zf.writestr("Accelerometer.csv", "\n".join(acc) + "\n")
        zf.writestr("Gyroscope.csv", "\n".join(gyr) + "\n")
        zf.writestr("__MACOSX/._Accelerometer.csv", APPLEDOUBLE)
        zf.writestr("__MACOSX/._Gyroscope.csv", APPLEDOUBLE)
    rec = load_phyphox(p)
    assert len(rec.batch) == n and len(rec.batch.gyr_t_ns) == n


# ---------------------------------------------------------------------------------------------- time gaps
@pytest.mark.parametrize("fmt", list(FORMATS))
def test_a_long_time_gap_is_noted_with_its_position_and_length(tmp_path: Path, fmt: str) -> None:
    """A logger that paused for 2 s: the samples are kept as recorded, and the note says where and how long."""
    rows = _rows(mag=FORMATS[fmt][2])
    rows[300:, 0] += 2.0  # nothing between t = 1.495 s and 3.5 s
    rec = load(_write(tmp_path, fmt, rows))
    assert len(rec.batch) == N
    gaps = [n for n in rec.meta.notes if "gap" in n]
    assert len(gaps) == 1, rec.meta.notes  # accelerometer and gyroscope (and magnetometer) share one note
    assert gaps[0].startswith("acc/gyr") and "1 time gap(s)" in gaps[0]
    assert "2.005 s from t = 1.495 s" in gaps[0] and "10 sample periods (0.05 s)" in gaps[0]


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_jitter_and_a_few_lost_samples_are_not_gaps(tmp_path: Path, fmt: str) -> None:
    rows = _rows(mag=FORMATS[fmt][2])
    rows[1:-1, 0] += np.random.default_rng(3).uniform(-0.002, 0.002, N - 2)  # +-0.4 sample periods
    rows = np.delete(rows, [100, 101, 102, 250], axis=0)  # a 4-period and a 2-period hole
    rec = load(_write(tmp_path, fmt, rows))
    assert not any("gap" in n for n in rec.meta.notes)


def test_gaps_of_the_magnetometer_alone_and_many_gaps_are_summarised(tmp_path: Path) -> None:
    from clients.importers._common import gap_notes
    from models.batch import SensorBatch

    t = np.arange(2000, dtype=np.int64) * 5_000_000
    for k in range(7):
        t[200 * (k + 1):] += 100_000_000  # seven 0.105-s gaps
    mag_t = np.arange(500, dtype=np.int64) * 20_000_000
    mag_t[250:] += 1_000_000_000  # the magnetometer alone stops for 1 s
    b = SensorBatch(acc_t_ns=t, acc=np.zeros((t.size, 3)), gyr_t_ns=t, gyr=np.zeros((t.size, 3)),
                    mag_t_ns=mag_t, mag=np.zeros((mag_t.size, 3)))
    notes = gap_notes("x.csv", b)
    assert len(notes) == 2
    assert notes[0].startswith("acc/gyr: 7 time gap(s)") and "and 2 more" in notes[0] and "longest 0.105 s" in notes[0]
    assert notes[1].startswith("mag: 1 time gap(s)") and "1.02 s from t = 4.980 s" in notes[1]


# ---------------------------------------------------------------------------------------------- spreadsheet flavours
def _flavour(path: Path, sep: str, dec: str, quote: bool) -> Path:
    """The same table as a spreadsheet saves it: another separator, decimal comma, quoted cells."""
    q = '"' if quote else ""
    lines = [sep.join(f"{q}{c.replace('.', dec) if i else c}{q}" for c in ln.split(","))
             for i, ln in enumerate(path.read_text().splitlines())]
    out = path.with_name("flavour_" + path.name)
    out.write_text("\n".join(lines) + "\n")
    return out


@pytest.mark.parametrize("fmt", CSV_FORMATS)
@pytest.mark.parametrize(("sep", "dec", "quote"),
                         [(";", ",", False), (";", ",", True), ("\t", ",", False), (",", ".", True), ("\t", ".", True)])
def test_spreadsheet_csv_flavours_read_like_the_original(tmp_path: Path, fmt: str, sep: str, dec: str,
                                                        quote: bool) -> None:
    """European exports (';' between fields, decimal comma) and quoted numbers were "no importer recognises
    this file" or "no row has a finite time"."""
    ref_path = _write(tmp_path, fmt)
    ref = load(ref_path)
    rec = load(_flavour(ref_path, sep, dec, quote))
    assert rec.meta.source_format == ref.meta.source_format
    np.testing.assert_array_equal(rec.batch.acc_t_ns, ref.batch.acc_t_ns)
    np.testing.assert_array_equal(rec.batch.acc, ref.batch.acc)
    np.testing.assert_array_equal(rec.batch.gyr, ref.batch.gyr)
    np.testing.assert_array_equal(rec.batch.mag, ref.batch.mag)


def test_semicolon_csv_keeps_the_sample_policy(tmp_path: Path) -> None:
    rows = _rows()
    rows[50, 4:7] = np.nan
    p = _flavour(write_a(tmp_path / "SensorConnectData_90.csv", rows, cut_last=True), ";", ",", True)
    rec = load(p)
    assert len(rec.batch) == N - 1 and len(rec.batch.gyr_t_ns) == N - 2
    assert f"line {N + 1}" in _notes(rec) and "non-finite" in _notes(rec)


def test_quoted_decimal_commas_in_a_comma_separated_file_are_refused_by_column(tmp_path: Path) -> None:
    """"0,005" between commas is a decimal comma or a thousands separator: refused, not guessed."""
    p = write_a(tmp_path / "SensorConnectData_90.csv", _rows())
    lines = p.read_text().splitlines()
    lines[1:] = [",".join(f'"{c.replace(".", ",")}"' for c in ln.split(",")) for ln in lines[1:]]
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(ImporterError, match="decimal comma or a thousands separator") as ei:
        load(p)
    assert ei.value.field == PREFIX + "scaledAccelX" and "line 2" in str(ei.value)  # its time 0 has no comma
    assert "SensorConnectData_90.csv" in str(ei.value)


def test_vicon_file_without_truth_loads_for_replay_and_is_refused_for_evaluation(tmp_path: Path) -> None:
    """Before: "no importer recognises this file" (load) for the IMU log without its Vicon capture."""
    p = write_vicon(tmp_path / "2099-01-01-00-00-00.mat", _rows(mag=False))
    d = sio.loadmat(p)
    sio.savemat(p, {k: v for k, v in d.items() if k in ("imu", "ts")})
    rec = load(p)
    assert rec.meta.source_format == "vicon-mat" and len(rec.batch) == N and rec.truth is None
    assert "no Vicon ground truth" in _notes(rec)
    with pytest.raises(ImporterError, match="not evaluated") as ei:
        load_vicon(p)
    assert ei.value.field == "gt"


def test_an_unknown_table_is_refused_with_its_first_line(tmp_path: Path) -> None:
    p = tmp_path / "walk.csv"
    p.write_text("zeit;beschleunigung\n0,0;9,81\n")
    with pytest.raises(ImporterError, match="no importer recognises this file: a semicolon-separated table whose "
                                            "first line has 2 field\\(s\\): 'zeit', 'beschleunigung'"):
        load(p)


# ---------------------------------------------------------------------------------------------- gyroscope units
@pytest.fixture(scope="module")
def walk() -> SensorBatch:
    """20 s of a synthetic foot sensor walking at 200 Hz (acc [m/s^2], gyr [rad/s]; |w| peaks at 6.5 rad/s)."""
    from clients.synth import synthesize

    b = synthesize("walk", seed=1, rate_hz=200.0).batch
    return b.time_slice(b.t_start_ns, b.t_start_ns + 20 * 10**9)


def _gaitmap_walk(path: Path, b: SensorBatch, gyr_scale: float, gyr_unit: str = "", acc_scale: float = 1.0,
                  acc_unit: str = "") -> Path:
    def names(kind: str, unit: str) -> list[str]:
        return [f"{kind}_{a}" + (f" [{unit}]" if unit else "") for a in "xyz"]

    rows = np.column_stack([(b.acc_t_ns - b.acc_t_ns[0]) / 1e9, b.acc * acc_scale, b.gyr * gyr_scale])
    return _csv(path, [""] + names("acc", acc_unit) + names("gyr", gyr_unit), rows)


def test_gaitmap_gyroscope_in_rad_s_is_not_divided_by_57(tmp_path: Path, walk: SensorBatch) -> None:
    """A gaitmap-style CSV written in rad/s: it was read as deg/s and the foot turned 57 times too slowly."""
    rec = load(_gaitmap_walk(tmp_path / "walk_rad.csv", walk, 1.0))
    np.testing.assert_allclose(rec.batch.gyr, walk.gyr, rtol=1e-6, atol=1e-9)
    assert rec.meta.units_converted["gyr"].startswith("rad/s, used as is")
    assert "not the format's deg/s" in _notes(rec) and "= 6.49" in _notes(rec)


def test_gaitmap_gyroscope_in_deg_s_is_converted_without_a_note(tmp_path: Path, walk: SensorBatch) -> None:
    rec = load(_gaitmap_walk(tmp_path / "walk_deg.csv", walk, 180.0 / np.pi))
    np.testing.assert_allclose(rec.batch.gyr, walk.gyr, rtol=1e-6, atol=1e-9)
    how = rec.meta.units_converted["gyr"]
    assert how.startswith("deg/s -> rad/s") and "motion agrees" in how
    assert "gyroscope" not in _notes(rec)


@pytest.mark.parametrize(("gyr_unit", "gyr_scale"), [("rad/s", 1.0), ("deg/s", 180.0 / np.pi), ("°/s", 180.0 / np.pi),
                                                     ("DPS", 180.0 / np.pi)])
@pytest.mark.parametrize(("acc_unit", "acc_scale"), [("", 1.0), ("m/s^2", 1.0), ("g", 1.0 / G0)])
def test_gaitmap_units_stated_in_the_header(tmp_path: Path, walk: SensorBatch, gyr_unit: str, gyr_scale: float,
                                            acc_unit: str, acc_scale: float) -> None:
    rec = load(_gaitmap_walk(tmp_path / "walk.csv", walk, gyr_scale, gyr_unit, acc_scale, acc_unit))
    np.testing.assert_allclose(rec.batch.gyr, walk.gyr, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(rec.batch.acc, walk.acc, rtol=1e-6, atol=1e-9)
    assert "stated by the header" in rec.meta.units_converted["gyr"]
    assert ("acc" in rec.meta.units_converted) == (acc_unit == "g")


def test_gaitmap_header_unit_the_data_contradict_is_refused(tmp_path: Path, walk: SensorBatch) -> None:
    with pytest.raises(ImporterError, match="the header says deg/s but the values are rad/s") as ei:
        load(_gaitmap_walk(tmp_path / "walk.csv", walk, 1.0, "deg/s"))
    assert ei.value.field == "gyr_x" and "walk.csv" in str(ei.value)


@pytest.mark.parametrize(("units", "words"), [(("rad/s", "rad/s", "deg/s"), "different units"),
                                              (("rad/s", "rad/s", ""), "different units"),
                                              (("rpm", "rpm", "rpm"), "'rpm' not understood")])
def test_gaitmap_header_units_that_cannot_be_read_are_refused(tmp_path: Path, walk: SensorBatch,
                                                              units: tuple[str, ...],
                                                              words: str) -> None:
    p = _gaitmap_walk(tmp_path / "walk.csv", walk, 1.0, "rad/s")
    lines = p.read_text().splitlines()
    lines[0] = ",".join(["", "acc_x", "acc_y", "acc_z"] + [f"gyr_{a}" + (f" [{u}]" if u else "")
                                                           for a, u in zip("xyz", units)])
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(ImporterError, match=words) as ei:
        load_gaitmap(p)
    assert ei.value.field.startswith("gyr_x")


def test_gaitmap_gyroscope_that_fits_neither_unit_is_refused(tmp_path: Path, walk: SensorBatch) -> None:
    """p99 |w| of 36 while walking: 36 rad/s is a sprint, 36 deg/s a foot that hardly turns. Not guessed."""
    with pytest.raises(ImporterError, match="fit neither rad/s nor deg/s") as ei:
        load(_gaitmap_walk(tmp_path / "walk.csv", walk, 5.5))
    assert ei.value.field == "gyr_x" and "gyr_x [deg/s]" in str(ei.value)


def test_gaitmap_still_recording_keeps_deg_s_and_says_it_was_not_checked(tmp_path: Path) -> None:
    rec = load(_write(tmp_path, "gaitmap"))
    np.testing.assert_allclose(rec.batch.gyr, _rows(mag=False)[:, 4:7], rtol=1e-6, atol=1e-9)
    assert "not checked: too little motion" in _notes(rec)


@pytest.mark.parametrize("fmt", ["A", "B", "C", "vicon"])
def test_rad_s_formats_refuse_a_walk_logged_in_deg_s_naming_the_column(tmp_path: Path, walk: SensorBatch,
                                                                         fmt: str) -> None:
    t = (walk.acc_t_ns - walk.acc_t_ns[0]) / 1e9
    cols = [t[:, None], walk.acc / G0, np.rad2deg(walk.gyr)]
    if FORMATS[fmt][2]:
        cols.append(np.tile([0.2, 0.0, -0.4], (t.size, 1)))
    with pytest.raises(ImporterError, match="says rad/s but the values are deg/s") as ei:
        load(_write(tmp_path, fmt, np.hstack(cols)))
    assert ei.value.field in ("scaledGyroX", "estAngularRateX", "imu_data[:,3]", "imu[:,3] gyr_x")


@pytest.mark.parametrize("fmt", ["A", "B", "C", "vicon"])
def test_rad_s_formats_accept_the_walk_in_rad_s(tmp_path: Path, walk: SensorBatch, fmt: str) -> None:
    t = (walk.acc_t_ns - walk.acc_t_ns[0]) / 1e9
    cols = [t[:, None], walk.acc / G0, walk.gyr]
    if FORMATS[fmt][2]:
        cols.append(np.tile([0.2, 0.0, -0.4], (t.size, 1)))
    rec = load(_write(tmp_path, fmt, np.hstack(cols)))
    np.testing.assert_allclose(rec.batch.gyr, walk.gyr, rtol=1e-6, atol=1e-8)


def test_gaitmap_magnetometer_stated_in_ut_is_imported_without_a_scale(tmp_path: Path, walk: SensorBatch) -> None:
    p = _gaitmap_walk(tmp_path / "walk.csv", walk, 180.0 / np.pi)
    lines = p.read_text().splitlines()
    lines[0] += ",mag_x [uT],mag_y [uT],mag_z [uT]"
    lines[1:] = [ln + ",20.5,0,-40" for ln in lines[1:]]
    p.write_text("\n".join(lines) + "\n")
    rec = load(p)
    np.testing.assert_allclose(rec.batch.mag[0], [20.5, 0.0, -40.0])
    assert rec.meta.units_converted["mag"].startswith("uT (stated)")
