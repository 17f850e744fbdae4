"""Importers: unit conversions and bad-input errors on synthetic files; every real file of the datasets."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.io as sio
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clients.importers import ImporterError, list_recordings, load
from clients.importers._common import G0
from clients.importers.gaitmap import load_gaitmap
from clients.importers.gdin import find_gdin, load_gdin, load_llio_mat, load_truth_mat
from clients.importers.sensorconnect import load_sensorconnect
from clients.importers.vicon import load_vicon

PREFIX = "inertial-6253.76535:"
A_COLS = [f"scaled{s}{a}" for s in ("Accel", "Gyro", "Mag") for a in "XYZ"] + ["roll", "pitch", "yaw"]


# ---------------------------------------------------------------------------------------------- writers
def _rest_signals(n: int, rate: float = 200.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A sensor lying flat, z up: t [s], acc [g], gyr [rad/s], mag [gauss]."""
    rng = np.random.default_rng(3)
    t = np.arange(n) / rate
    acc = np.tile([0.0, 0.0, 1.0], (n, 1)) + 0.002 * rng.standard_normal((n, 3))
    gyr = 0.01 * rng.standard_normal((n, 3))
    mag = np.tile([0.2, 0.0, -0.4], (n, 1))
    return t, acc, gyr, mag


def write_format_a(path: Path, n: int = 400, acc_scale: float = 1.0, mutate=None) -> Path:
    t, acc, gyr, mag = _rest_signals(n)
    rows = np.column_stack([t, acc * acc_scale, gyr, mag, np.zeros((n, 3))])
    if mutate is not None:
        rows = mutate(rows)
    header = "Time," + ",".join(PREFIX + c for c in A_COLS)
    np.savetxt(path, rows, delimiter=",", header=header, comments="", fmt="%.9g")
    return path


def write_format_b(path: Path, n: int = 500, invalid_rows: tuple[int, ...] = ()) -> Path:
    rng = np.random.default_rng(4)
    t = np.arange(n) / 250.0
    acc = np.tile([0.0, 0.0, G0], (n, 1)) + 0.02 * rng.standard_normal((n, 3))
    gyr = 0.01 * rng.standard_normal((n, 3))
    cols, data = ["Time"], [t]
    for name, v in (("estCompensatedAccel", acc), ("estAngularRate", gyr)):
        for k, a in enumerate("XYZ"):
            flag = np.ones(n)
            flag[list(invalid_rows)] = 0
            cols += [PREFIX + f"{name}{a}", PREFIX + f"{name}{a}:valid"]
            data += [v[:, k], flag]
    np.savetxt(path, np.column_stack(data), delimiter=",", header=",".join(cols), comments="", fmt="%.9g")
    return path


def write_vicon(path: Path, n: int = 300, mutate=None) -> Path:
    rng = np.random.default_rng(5)
    ts = 0.005 + np.arange(n) / 200.0
    imu = np.column_stack([np.tile([0.0, 0.0, -9.81], (n, 1)), 0.01 * rng.standard_normal((n, 3))])
    gt = np.column_stack([np.linspace(0, 1, n), np.zeros(n), np.full(n, 0.1)])
    d = {"imu": imu, "ts": ts[None, :], "gt": gt, "zv_shoe_opt": np.ones((1, n))}
    if mutate is not None:
        mutate(d)
    sio.savemat(path, d)
    return path


# ---------------------------------------------------------------------------------------------- synthetic
def test_format_a_converts_g_and_gauss(tmp_path: Path) -> None:
    rec = load(write_format_a(tmp_path / "SensorConnectData_99.csv"))
    assert rec.meta.source_format == "sensorconnect-a"
    assert rec.meta.rate_hz == pytest.approx(200.0, rel=1e-3)
    assert set(rec.meta.units_converted) == {"acc", "mag"}
    assert np.median(np.linalg.norm(rec.batch.acc, axis=1)) == pytest.approx(G0, rel=1e-2)
    np.testing.assert_allclose(rec.batch.mag[0], [20.0, 0.0, -40.0], rtol=1e-6)
    assert rec.batch.acc_t_ns.dtype == np.int64 and rec.batch.acc_t_ns[1] == 5_000_000


def test_format_b_keeps_si_and_drops_invalid_rows(tmp_path: Path) -> None:
    rec = load_sensorconnect(write_format_b(tmp_path / "b.csv", invalid_rows=(10, 11, 12)))
    assert rec.meta.source_format == "sensorconnect-b"
    assert rec.meta.units_converted == {}
    assert len(rec.batch) == 497 and rec.batch.mag.shape == (0, 3)
    assert any("valid flag" in n for n in rec.meta.notes)
    assert rec.meta.rate_hz == pytest.approx(250.0, rel=1e-3)


def _set(row: int, col: int, value: float):
    def mutate(rows: np.ndarray) -> np.ndarray:
        rows = rows.copy()
        rows[row, col] = value
        return rows

    return mutate


# non-finite cells, conflicting duplicated timestamps, cut lines: tests/clients/test_importer_robustness.py
@pytest.mark.parametrize(
    ("mutate", "field", "words"),
    [
        (_set(40, 0, 0.1), "Time", "backwards"),
        (_set(40, 0, 1e6), "Time", "backwards"),
    ],
)
def test_format_a_bad_rows_name_column_and_problem(tmp_path: Path, mutate, field: str, words: str) -> None:
    with pytest.raises(ImporterError) as ei:
        load_sensorconnect(write_format_a(tmp_path / "bad.csv", mutate=mutate))
    assert ei.value.field == field
    assert words in str(ei.value) and "bad.csv" in str(ei.value)


def test_exact_duplicate_rows_are_dropped_with_a_note(tmp_path: Path) -> None:
    def dup(rows: np.ndarray) -> np.ndarray:
        return np.insert(rows, 50, rows[49], axis=0)

    rec = load_sensorconnect(write_format_a(tmp_path / "dup.csv", mutate=dup))
    assert len(rec.batch) == 400
    assert any("duplicate" in n for n in rec.meta.notes)
    assert np.all(np.diff(rec.batch.acc_t_ns) > 0)


def test_format_a_values_contradicting_the_header_units_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ImporterError, match="header says g"):
        load_sensorconnect(write_format_a(tmp_path / "ms2.csv", acc_scale=G0))


def test_gyro_in_deg_per_s_is_refused(tmp_path: Path) -> None:
    def deg(rows: np.ndarray) -> np.ndarray:
        rows = rows.copy()
        rows[:, 4:7] = 90.0  # a spinning sensor logged in deg/s
        return rows

    with pytest.raises(ImporterError, match="deg/s"):
        load_sensorconnect(write_format_a(tmp_path / "deg.csv", mutate=deg))


@pytest.mark.parametrize("content", ["", "Time,foo,bar\n0,1,2\n", "Time," + PREFIX + "scaledAccelX\n"])
def test_empty_or_unknown_csv_is_refused(tmp_path: Path, content: str) -> None:
    p = tmp_path / "x.csv"
    p.write_text(content)
    with pytest.raises(ImporterError):
        load(p)


def test_missing_column_is_named(tmp_path: Path) -> None:
    p = write_format_a(tmp_path / "m.csv")
    lines = p.read_text().splitlines()
    lines[0] = lines[0].replace("scaledGyroY", "scaledGyroQ")
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(ImporterError) as ei:
        load_sensorconnect(p)
    assert ei.value.field == "scaledGyroY"


def test_vicon_roundtrip_and_oracle_fields_not_imported(tmp_path: Path) -> None:
    rec = load(write_vicon(tmp_path / "2099-01-01-00-00-00.mat"))
    assert rec.meta.source_format == "vicon-mat"
    assert rec.truth is not None and rec.truth.positions.shape == (300, 3)
    np.testing.assert_array_equal(rec.truth.t_ns, rec.batch.acc_t_ns)
    assert "zv_shoe_opt" not in rec.truth.extra


@pytest.mark.parametrize(
    ("mutate", "field"),
    [
        (lambda d: d.update(imu=d["imu"][:, :5]), "imu"),
        (lambda d: d.pop("gt"), "gt"),
        (lambda d: d.update(ts=d["ts"][:, ::-1]), "ts"),
        (lambda d: d["imu"].__setitem__((slice(None), 4), np.nan), "imu[:,3] gyr_x"),
        (lambda d: d.update(imu=np.zeros((0, 6)), ts=np.zeros((1, 0)), gt=np.zeros((0, 3))), "imu"),
    ],
)
def test_vicon_bad_input(tmp_path: Path, mutate, field: str) -> None:
    with pytest.raises(ImporterError) as ei:
        load_vicon(write_vicon(tmp_path / "v.mat", mutate=mutate))
    assert ei.value.field == field


def test_llio_mat_and_gdin_pairing(tmp_path: Path) -> None:
    root = tmp_path / "gdin"
    (root / "llio_mat").mkdir(parents=True)
    (root / "own").mkdir()
    (root / "stride_gcp").mkdir()
    n = 1000
    ts = np.arange(n) / 200.0
    imu = np.column_stack([np.tile([0, 0, 9.81], (n, 1)), np.zeros((n, 3))])
    sio.savemat(root / "llio_mat" / "SensorConnectData_77_LLIO.mat", {"imu_data": imu, "timestamps": ts[None, :]})
    gcp = np.array([[0, 0], [1, 0], [2, 0], [2, 1]], dtype=np.uint8)  # integers, as some files store them
    sio.savemat(
        root / "own" / "SensorConnectData_77.mat",
        {"GCP_meters": gcp, "GCP_stride_numbers": np.array([[0, 1, 2, 3]]), "GCP_exist_and_correct": np.array([[1]]),
         "numberOfStrides": np.array([[3]])},
    )
    table = np.column_stack([[100, 300, 500, 700], np.array([100, 300, 500, 700]) / 200.0, gcp.astype(float)])
    np.savetxt(root / "stride_gcp" / "SensorConnectData_77_strideIndex_timestamp_gcpX_gcpY.csv", table, delimiter=",",
               header="strideIndex,timestamp,gcpX,gcpY", comments="")
    entries = find_gdin(root)
    assert [e.exp for e in entries] == [77]
    rec = load_gdin(entries[0])
    x = rec.truth.extra
    assert x["gcp_m"].dtype == np.float64 and x["truth_path_length_m"] == pytest.approx(3.0)
    assert not x["closed_loop"] and x["stride_mapping"] == "strideIndex"
    np.testing.assert_array_equal(x["stride_t_ns"], rec.batch.acc_t_ns[[100, 300, 500, 700]])
    assert load(root / "llio_mat" / "SensorConnectData_77_LLIO.mat").truth is not None
    assert list_recordings(root) == [root / "llio_mat" / "SensorConnectData_77_LLIO.mat"]


def test_truth_file_is_not_a_recording(tmp_path: Path) -> None:
    p = tmp_path / "SensorConnectData_05.mat"
    sio.savemat(p, {"GCP_meters": np.zeros((2, 2)), "GCP_stride_numbers": np.zeros((1, 2)), "GCP_exist_and_correct": 1})
    with pytest.raises(ImporterError, match="no importer"):
        load(p)
    with pytest.raises(ImporterError, match="imu_data"):
        load_llio_mat(p)


def test_gaitmap_index_file_needs_a_known_rate(tmp_path: Path) -> None:
    p = tmp_path / "my_walk.csv"
    n = 100
    rows = np.column_stack([np.arange(n), np.tile([0, 0, 9.81, 0, 0, 0], (n, 1))])
    np.savetxt(p, rows, delimiter=",", header=",acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z", comments="")
    with pytest.raises(ImporterError, match="rate"):
        load_gaitmap(p)
    rec = load_gaitmap(p, rate_hz=100.0)
    assert rec.meta.rate_hz == pytest.approx(100.0)
    assert "gyr" in rec.meta.units_converted


# ---------------------------------------------------------------------------------------------- real data
def test_every_vicon_trial_imports(vicon_dir: Path) -> None:
    files = sorted(vicon_dir.glob("*.mat"))
    assert files
    for f in files:
        rec = load(f)
        assert rec.meta.source_format == "vicon-mat"
        assert 195 < rec.meta.rate_hz < 205
        assert rec.truth.positions.shape == (len(rec.batch), 3)
        # trials start at rest: |a| there is gravity in m/s^2
        assert np.median(np.linalg.norm(rec.batch.acc[:50], axis=1)) == pytest.approx(9.81, abs=0.3)


def test_every_gdin_recording_pairs_with_its_truth(gdin_dir: Path) -> None:
    entries = find_gdin(gdin_dir)
    assert len(entries) >= 20
    for e in entries:
        assert e.truth_path is not None, f"{e.name}: no truth .mat"
        rec = load_gdin(e)
        x = rec.truth.extra
        assert x["exp"] == e.exp and x["gcp_m"].dtype == np.float64
        med_a = float(np.median(np.linalg.norm(rec.batch.acc[:100], axis=1)))  # recordings start standing
        assert 9.5 < med_a < 10.1, f"{e.name}: median |a| at rest {med_a} m/s^2"
        if rec.batch.mag.shape[0]:
            med_m = float(np.median(np.linalg.norm(rec.batch.mag, axis=1)))
            assert 20.0 < med_m < 70.0, f"{e.name}: median |m| {med_m} uT"
        if "stride_t_ns" in x:
            assert len(x["stride_t_ns"]) == x["number_of_strides"] + 1
            assert np.all(np.diff(x["stride_t_ns"]) > 0)
            # the stride sample lies on the recording's clock where the table says (within one sample)
            gap = np.abs(x["stride_t_ns"] * 1e-9 - x["stride_table_t_s"])
            assert gap.max() <= 0.6 / rec.meta.rate_hz  # nearest sample (half a period, plus clock jitter)
            assert x["stride_mapping"] == ("timestamp" if rec.meta.rate_hz > 240 else "strideIndex")


def test_gdin_formats_and_units(gdin_dir: Path) -> None:
    by_exp = {e.exp: e for e in find_gdin(gdin_dir)}
    a, b, c = load_gdin(by_exp[31]), load_gdin(by_exp[42]), load_gdin(by_exp[41])
    assert a.meta.source_format == "sensorconnect-a" and a.meta.units_converted["acc"].startswith("g ->")
    assert "gauss -> uT" in a.meta.units_converted["mag"]
    assert b.meta.source_format == "sensorconnect-b" and b.batch.mag.shape == (0, 3)
    assert 245 < b.meta.rate_hz < 255
    assert c.meta.source_format == "gdin-llio-mat" and c.batch.mag.shape == (0, 3)
    unusable = sorted(e for e, v in by_exp.items() if not load_truth_mat(v.truth_path)["gcp_exist_and_correct"])
    assert unusable == [6, 11, 13, 14, 16]


def test_gaitmap_files(gaitmap_dir: Path) -> None:
    rec = load(gaitmap_dir / "imu_sample.csv")
    assert rec.meta.rate_hz == pytest.approx(204.8, rel=1e-3)
    assert rec.truth is not None and rec.truth.positions.shape[1] == 3
    travel = np.ptp(rec.truth.positions[:, 0])
    assert 15.0 < travel < 25.0  # ABOUT.md: the heel travels ~20.3 m in x
    right = load_gaitmap(gaitmap_dir / "imu_sample.csv", foot="right")
    assert not np.allclose(right.batch.acc, rec.batch.acc)
    stairs = load(gaitmap_dir / "imu_sample_healthy_stair_up.csv")
    assert stairs.meta.rate_hz == pytest.approx(204.8, rel=1e-3)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    rate=st.sampled_from([50.0, 100.0, 200.0, 400.0]),
    n=st.integers(20, 300),
    tilt=st.floats(-1.5, 1.5),
    t0=st.floats(0.0, 1e4),
)
def test_format_a_round_trip(tmp_path: Path, rate: float, n: int, tilt: float, t0: float) -> None:
    """Whatever the rate, start time and attitude: SI values = file values x the vendor unit, times in ns."""
    rng = np.random.default_rng(n)
    t = t0 + np.arange(n) / rate
    acc_g = np.tile([np.sin(tilt), 0.0, np.cos(tilt)], (n, 1)) + 0.01 * rng.standard_normal((n, 3))
    gyr = 0.5 * rng.standard_normal((n, 3))
    mag_g = np.tile([0.25, -0.1, 0.35], (n, 1)) + 0.01 * rng.standard_normal((n, 3))
    rows = np.column_stack([t, acc_g, gyr, mag_g, np.zeros((n, 3))])
    p = tmp_path / f"rt_{rate}_{n}.csv"
    np.savetxt(p, rows, delimiter=",", header="Time," + ",".join(PREFIX + c for c in A_COLS), comments="", fmt="%.17g")
    rec = load_sensorconnect(p)
    np.testing.assert_array_equal(rec.batch.acc_t_ns, np.round(t * 1e9).astype(np.int64))
    np.testing.assert_allclose(rec.batch.acc, acc_g * G0, rtol=1e-12)
    np.testing.assert_allclose(rec.batch.gyr, gyr, rtol=1e-12)
    np.testing.assert_allclose(rec.batch.mag, mag_g * 100.0, rtol=1e-12)
    assert rec.meta.rate_hz == pytest.approx(rate, rel=1e-6)


def test_load_and_list_on_folders(tmp_path: Path) -> None:
    with pytest.raises(ImporterError, match="folder"):
        load(tmp_path)
    with pytest.raises(ImporterError, match="does not exist"):
        load(tmp_path / "missing.csv")
    nested = tmp_path / "a" / "b"
    nested.mkdir(parents=True)
    f = write_format_a(nested / "walk.csv")
    (tmp_path / "notes.csv").write_text("just,some\n1,2\n")
    assert list_recordings(tmp_path) == [f]
    assert list_recordings(tmp_path, recursive=False) == []
