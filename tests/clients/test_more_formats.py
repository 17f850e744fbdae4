"""x-io NGIMU / Gait-Tracking CSV, any CSV with stated columns and units, the message for a file no importer reads,
and recordings that do not look like a foot (issue 25). Every sample file is written by its test."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from clients.importers import ImporterError, importer_for, load
from clients.importers.generic_csv import load_generic_csv
from clients.synth import synthesize
from models.placement import check_foot

_XIO_HEAD = ("Time (s),Gyroscope X (deg/s),Gyroscope Y (deg/s),Gyroscope Z (deg/s),Accelerometer X (g),"
             "Accelerometer Y (g),Accelerometer Z (g)")
_NGIMU_TAIL = ",Magnetometer X (uT),Magnetometer Y (uT),Magnetometer Z (uT),Barometer (hPa)"


@pytest.fixture(scope="module")
def walk():  # type: ignore[no-untyped-def]
    """A synthetic foot walk at 100 Hz (30 s of it: 5 s standing, then walking)."""
    rec = synthesize("walk", rate_hz=100.0)
    return rec.batch.time_slice(None, int(rec.batch.acc_t_ns[0]) + 30 * 10**9)


def _write_xio(path: Path, b, ngimu: bool, duplicate_every: int = 0) -> None:  # type: ignore[no-untyped-def]
    t = (b.acc_t_ns - b.acc_t_ns[0]) / 1e9
    lines = [_XIO_HEAD + (_NGIMU_TAIL if ngimu else "")]
    for i in range(len(t)):
        g, a = np.degrees(b.gyr[i]).tolist(), (b.acc[i] / 9.80665).tolist()
        row = f"{t[i]:.9f},{g[0]!r},{g[1]!r},{g[2]!r},{a[0]!r},{a[1]!r},{a[2]!r}"
        if ngimu:
            m = b.mag[i].tolist()
            row += f",{m[0]!r},{m[1]!r},{m[2]!r},1004.6"
        lines.append(row)
        if duplicate_every and i % duplicate_every == 0:
            lines.append(row)  # the Gait-Tracking example files repeat some rows exactly
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("ngimu", [True, False], ids=["ngimu", "gait-tracking"])
def test_xio_csv_round_trips_in_si_units(tmp_path: Path, walk, ngimu: bool) -> None:  # type: ignore[no-untyped-def]
    p = tmp_path / ("sensors.csv" if ngimu else "short_walk.csv")
    _write_xio(p, walk, ngimu, duplicate_every=0 if ngimu else 50)
    assert importer_for(p).__name__ == "clients.importers.xio"  # not phyphox (whose time column reads the same)
    rec = load(p)
    np.testing.assert_array_equal(rec.batch.acc_t_ns - rec.batch.acc_t_ns[0], walk.acc_t_ns - walk.acc_t_ns[0])
    np.testing.assert_allclose(rec.batch.acc, walk.acc, atol=1e-9)
    np.testing.assert_allclose(rec.batch.gyr, walk.gyr, atol=1e-12)
    assert rec.meta.source_format == "xio-csv" and "deg/s -> rad/s" in rec.meta.units_converted["gyr"]
    assert "x 9.80665" in rec.meta.units_converted["acc"]
    if ngimu:
        np.testing.assert_allclose(rec.batch.mag, walk.mag, atol=1e-9)
        assert any("Barometer" in n for n in rec.meta.notes)
        device = tmp_path / "NGIMU - 0029CEC0"  # the GUI's session export: one folder per device
        device.mkdir()
        p.rename(device / "sensors.csv")
        assert load(device).name == "NGIMU - 0029CEC0"
    else:
        assert len(rec.batch.mag_t_ns) == 0 and any("exact duplicate" in n for n in rec.meta.notes)


def test_xio_csv_with_a_unit_it_does_not_know_is_refused_naming_the_column(tmp_path: Path, walk) -> None:  # type: ignore[no-untyped-def]
    p = tmp_path / "sensors.csv"
    _write_xio(p, walk, ngimu=False)
    p.write_text(p.read_text().replace("Accelerometer X (g)", "Accelerometer X (ft/s^2)", 1))
    with pytest.raises(ImporterError) as e:
        load(p)
    assert e.value.field == "acc_x" and "different units" in e.value.problem


# ----------------------------------------------------------------------------------------------- generic CSV
def _write_table(path: Path, b, header: bool) -> None:  # type: ignore[no-untyped-def]
    """Columns: time [ms from an arbitrary origin], gyr [deg/s], acc [g], mag [nT], something else."""
    rows = ["t_ms;gx;gy;gz;ax;ay;az;mx;my;mz;temp"] if header else []
    t_ms = 5_000.0 + (b.acc_t_ns - b.acc_t_ns[0]) / 1e6
    for i in range(len(t_ms)):
        g, a, m = np.degrees(b.gyr[i]), b.acc[i] / 9.80665, b.mag[i] * 1000.0
        rows.append(";".join(f"{float(v)!r}" for v in (t_ms[i], *g, *a, *m, 21.5)))
    path.write_text("\n".join(rows) + "\n")


@pytest.mark.parametrize("header", [True, False])
def test_a_csv_read_with_stated_columns_and_units_round_trips(tmp_path: Path, walk, header: bool) -> None:  # type: ignore[no-untyped-def]
    p = tmp_path / "log.csv"
    _write_table(p, walk, header)
    cols = ("time=t_ms,acc=ax:ay:az,gyr=gx:gy:gz,mag=mx:my:mz" if header
            else "time=#1,acc=#5:#6:#7,gyr=#2:#3:#4,mag=#8:#9:#10")
    rec = load_generic_csv(p, cols, "time=ms,acc=g,gyr=deg/s,mag=nT")
    np.testing.assert_array_equal(rec.batch.acc_t_ns, walk.acc_t_ns - walk.acc_t_ns[0])
    np.testing.assert_allclose(rec.batch.acc, walk.acc, atol=1e-9)
    np.testing.assert_allclose(rec.batch.gyr, walk.gyr, atol=1e-12)
    np.testing.assert_allclose(rec.batch.mag, walk.mag, atol=1e-9)
    assert set(rec.meta.units_converted) == {"acc", "gyr", "mag"}
    with pytest.raises(ImporterError):
        load(p)  # never chosen by content


@pytest.mark.parametrize("columns, units, field, words", [
    ("time=t_ms,acc=ax:ay:ax2", "time=ms,acc=g", "acc", ["'ax2' is not in the header", "t_ms, gx"]),
    ("time=t_ms,acc=ax:ay", "time=ms,acc=g", "acc", ["needs 3 column(s)"]),
    ("acc=ax:ay:az", "acc=g", "time", ["time and acc are required"]),
    ("time=t_ms,acc=ax:ay:az,baro=p", "time=ms,acc=g", "baro", ["unknown stream"]),
    ("time=t_ms,acc=ax:ay:az", "time=ms,acc=furlong/fortnight^2", "acc", ["unknown unit", "m/s^2, m/s2, g, mg"]),
    ("time=t_ms,acc=ax:ay:az,gyr=gx:gy:gz", "time=ms,acc=g", "gyr", ["missing", "rad/s, deg/s"]),
    ("time=t_ms,acc=ax:ay:az", "time=ms,acc=g,mag=uT", "mag", ["--columns does not name"]),
    ("time=#0,acc=ax:ay:az", "time=ms,acc=g", "time", ["does not exist: the file has 11 columns"]),
])
def test_a_wrong_column_or_unit_is_refused_naming_it(tmp_path: Path, walk, columns: str, units: str, field: str,  # type: ignore[no-untyped-def]
                                                   words: list[str]) -> None:
    p = tmp_path / "log.csv"
    _write_table(p, walk, header=True)
    with pytest.raises(ImporterError) as e:
        load_generic_csv(p, columns, units)
    assert e.value.field == field
    for w in words:
        assert w in str(e.value)


def test_a_stated_unit_the_data_contradict_is_refused(tmp_path: Path, walk) -> None:  # type: ignore[no-untyped-def]
    p = tmp_path / "log.csv"
    _write_table(p, walk, header=True)
    with pytest.raises(ImporterError, match="looks like g"):
        load_generic_csv(p, "time=t_ms,acc=ax:ay:az", "time=ms,acc=m/s^2")  # in g, said m/s^2
    with pytest.raises(ImporterError, match="says rad/s but the values are deg/s"):
        load_generic_csv(p, "time=t_ms,acc=ax:ay:az,gyr=gx:gy:gz", "time=ms,acc=g,gyr=rad/s")


# ---------------------------------------------------------------------------------------- files no importer reads
@pytest.mark.parametrize("content, said", [
    (b"stamp,ax,ay,az,wx,wy,wz\n0,1,2,3,4,5,6\n", ["7 field(s): 'stamp', 'ax'", "time-like 'stamp'",
                                                  "accelerometer-like 'ax', 'ay', 'az'", "gyroscope-like 'wx'"]),
    (b"foo;bar\n1;2\n", ["semicolon-separated", "no time or sensor column recognised"]),
    (bytes(range(256)) * 4, ["binary content"]),
    (b"", ["an empty file"]),
])
def test_a_file_no_importer_reads_says_what_it_is_and_which_formats_exist(tmp_path: Path, content: bytes,
                                                                        said: list[str]) -> None:
    p = tmp_path / "thing.csv"
    p.write_bytes(content)
    with pytest.raises(ImporterError) as e:
        load(p)
    msg = str(e.value)
    for s in said:
        assert s in msg
    for fmt in ("VICON .mat", "x-io NGIMU", "Sensor Logger", "phyphox", "gaitmap CSV", "--columns"):
        assert fmt in msg


# ------------------------------------------------------------------------------------------- not a foot
def _hand_held_phone(seconds: float = 60.0, rate: float = 100.0, seed: int = 0):  # type: ignore[no-untyped-def]
    """A phone carried in the hand by a walker: the body's bounce at 2 steps/s and sway at the stride, the hand's
    slow turning; never still the way a foot is once per stride."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, seconds, 1 / rate)
    walking = t > 5
    bounce = np.where(walking, 2.0 * np.sin(2 * np.pi * 2.0 * t) + 0.8 * np.sin(2 * np.pi * 1.0 * t + 0.3), 0.0)
    acc = np.stack([0.5 * np.sin(2 * np.pi * 1.0 * t) * walking, 6.5 + 0.4 * bounce, 7.3 + bounce], 1)
    acc += rng.normal(0, 0.05, acc.shape)
    smooth = np.cumsum(rng.normal(0, 0.05, (t.size, 3)), axis=0)
    gyr = 0.3 * np.sin(2 * np.pi * 2.0 * t)[:, None] * walking[:, None] + 0.2 * (smooth - smooth.mean(0)) / smooth.std(0)
    return t, acc, gyr


def test_a_foot_walk_looks_like_a_foot_and_a_hand_held_phone_does_not(walk) -> None:  # type: ignore[no-untyped-def]
    rec = synthesize("walk", rate_hz=100.0)
    b = rec.batch
    assert check_foot((b.acc_t_ns - b.acc_t_ns[0]) / 1e9, b.acc, b.gyr).looks_like_foot is True
    verdict = check_foot(*_hand_held_phone())
    assert verdict.looks_like_foot is False and "does not look like a foot" in verdict.reason
    t, acc, gyr = _hand_held_phone(seconds=15.0)
    assert check_foot(t, acc, gyr).looks_like_foot is None  # 10 s of walking: too little to tell


def test_replay_refuses_to_navigate_a_phone_as_a_foot(tmp_path: Path) -> None:
    t, acc, gyr = _hand_held_phone()
    p = tmp_path / "phone.csv"
    p.write_text("t,ax,ay,az,gx,gy,gz\n" + "\n".join(",".join(f"{float(v)!r}" for v in (ti, *a, *g))
                                                      for ti, a, g in zip(t, acc, gyr)) + "\n")
    args = [sys.executable, "-m", "clients.cli", "replay", str(p), "--columns", "time=t,acc=ax:ay:az,gyr=gx:gy:gz",
            "--units", "time=s,acc=m/s^2,gyr=rad/s", "--json"]
    r = subprocess.run(args, capture_output=True, text=True, timeout=300)
    assert r.returncode == 1 and "does not look like a foot" in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    r = subprocess.run(args + ["--skip-foot-check"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr


@pytest.mark.parametrize("name", ["2017-11-22-11-22-03", "2017-11-27-11-18-11", "2017-12-15-18-03-05"])
def test_real_walking_and_running_feet_look_like_feet(vicon_dir: Path, name: str) -> None:
    b = load(vicon_dir / f"{name}.mat").batch
    assert check_foot((b.acc_t_ns - b.acc_t_ns[0]) / 1e9, b.acc, b.gyr).looks_like_foot is True


def test_real_hand_held_phones_do_not_look_like_feet() -> None:
    """IPIN 2023 track 3 (datasets/ipin2023-t3-phone): GetSensorData logfiles of a phone held in the hand. Their
    ACCE and GYRO lines are read here directly (the app's importer is another module's)."""
    from clients.datasets import dataset_dir

    d = dataset_dir("ipin2023-t3-phone")
    if d is None:
        pytest.skip("dataset 'ipin2023-t3-phone' not found: set PEDNAV_DATA or place ../shared/datasets beside the project")
    files = sorted((d / "logfiles").glob("*.txt"))[:4]
    for f in files:
        rows: dict[str, list[list[float]]] = {"ACCE": [], "GYRO": []}
        for line in f.read_text(encoding="latin-1").splitlines():
            kind = line[:4]
            if kind in rows:
                parts = line.split(";")
                rows[kind].append([float(parts[2]), float(parts[3]), float(parts[4]), float(parts[5])])
        a, g = np.array(rows["ACCE"]), np.array(rows["GYRO"])
        t, keep = np.unique(a[:, 0], return_index=True)
        gi = np.stack([np.interp(t, g[:, 0], g[:, k]) for k in (1, 2, 3)], axis=1)
        assert check_foot(t - t[0], a[keep, 1:], gi).looks_like_foot is False, f.name
