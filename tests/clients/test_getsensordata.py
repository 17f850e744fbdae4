"""GetSensorData logfiles: a sample file written here round-trips through the importer; damaged files; the
IPIN 2023 dev trials when present."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pymap3d
import pytest

from clients.importers import ImporterError, importer_for, list_recordings, load
from clients.importers.getsensordata import SOURCE_FORMAT

_HEADER = """% LogFile created by the 'GetSensorData' App for Android.
% Date of creation: Wed Jun 14 10:46:42 GMT+02:00 2023
% Phone used for this logfile:
% Manufacturer:            \tsamsung
% Model:                   \tSM-A520F
% Android version Release: \t8.0.0
% Magnetometer data:  \t'MAGN;AppTimestamp(s);SensorTimestamp(s);Mag_X(uT);;Mag_Y(uT);Mag_Z(uT);Accuracy(integer)'
% POSI Reference:    \t\t'POSI;Timestamp(s);Counter;Latitude(degrees); Longitude(degrees);floor ID(0,1,2..4);Building ID(0,1,2..3);'
"""
OFFSET_S = 1234.5  # sensor clock - app clock
LAT0, LON0 = 49.461052766818, 11.111052038421


def _sample(seconds: float = 4.0, seed: int = 1) -> dict[str, np.ndarray]:
    """A phone held still-ish: accelerometer and magnetometer at 50 Hz, gyroscope at 100 Hz, with jitter."""
    rng = np.random.default_rng(seed)

    def times(rate: float) -> np.ndarray:
        t = np.arange(0.0, seconds, 1.0 / rate) + 0.3
        return np.round(t + rng.uniform(0, 0.2 / rate, t.size), 4)

    ta, tg, tm = times(50.0), times(100.0), times(50.0)
    acc = np.array([0.3, 8.2, 5.4]) + 0.4 * rng.standard_normal((ta.size, 3))
    gyr = 0.3 * rng.standard_normal((tg.size, 3))
    mag = np.array([-13.0, -22.0, -23.0]) + 0.3 * rng.standard_normal((tm.size, 3))
    return {"ta": ta, "acc": np.round(acc, 5), "tg": tg, "gyr": np.round(gyr, 5), "tm": tm, "mag": np.round(mag, 2)}


def _latency(t: np.ndarray) -> np.ndarray:
    """App timestamps: the sensor time on the app clock plus a delivery latency of 0-3 ms."""
    return np.round(t + 0.001 * (np.arange(t.size) % 4), 4)


def write_logfile(path: Path, s: dict[str, np.ndarray], empty_mag_column: bool = False, extra_lines: tuple[str, ...] = ()) -> Path:
    events: list[tuple[float, str]] = []
    for tag, tk, vk in (("ACCE", "ta", "acc"), ("GYRO", "tg", "gyr"), ("MAGN", "tm", "mag")):
        for app, t, v in zip(_latency(s[tk]), s[tk], s[vk]):
            sep = ";;" if tag == "MAGN" and empty_mag_column else ";"
            events.append((app, f"{tag};{app:.4f};{t + OFFSET_S:.4f};{v[0]:.5f}{sep}{v[1]:.5f};{v[2]:.5f};3"))
    for app, t in zip(_latency(s["ta"]), s["ta"]):
        events.append((app, f"AHRS;{app:.4f};{t + OFFSET_S:.4f};55.1;14.8;-80.2;0.42458308;-0.20798437;-0.52074391;3"))
    events.append((0.82, "GNSS;0.8202;1686732422.0000;49.461069;11.111083;376.000;149.400;8.0;0.1;24;15"))
    events.append((2.0, f"POSI;2.0000;1;{LAT0:.12f};{LON0:.12f};0;100"))
    events.append((3.5, "POSI;3.5000;2;49.461086542587;11.111208635507;0;100"))
    events.append((1.0, "PRES;1.0000;1235.5;968.43;0"))
    events.append((1.5, "WIFI;1.5000;1236.0;eduroam;00:11:22:33:44:55;2412;-71"))
    events.sort(key=lambda e: e[0])
    lines = [e[1] for e in events]
    for ln in extra_lines:
        lines.insert(len(lines) // 2, ln)
    path.write_text(_HEADER + "\n".join(lines) + "\n", encoding="latin-1")
    return path


@pytest.mark.parametrize("empty_mag_column", [False, True])
def test_round_trip(tmp_path: Path, empty_mag_column: bool) -> None:
    s = _sample()
    rec = load(write_logfile(tmp_path / "trial.txt", s, empty_mag_column))
    assert rec.meta.source_format == SOURCE_FORMAT and rec.meta.mount == "phone"
    assert rec.meta.units_converted == {}
    # the sensor times, moved onto the app clock by the median sensor - app offset (latency 0-3 ms: median 1.5 ms)
    offset = np.median(s["ta"] + OFFSET_S - _latency(s["ta"]))
    for name, tk in (("acc", "ta"), ("gyr", "tg"), ("mag", "tm")):
        t, v = rec.batch.stream(name)
        np.testing.assert_array_equal(t, np.round((s[tk] + OFFSET_S - offset) * 1e9).astype(np.int64))
        np.testing.assert_allclose(v, s[name], atol=1e-9)
    assert rec.batch.rate_hz("gyr") == pytest.approx(100.0, rel=0.05)
    assert any("SensorTimestamp" in n for n in rec.meta.notes)
    # landmarks: app times, local NED at the first one
    assert rec.truth is not None
    np.testing.assert_array_equal(rec.truth.t_ns, [2_000_000_000, 3_500_000_000])
    n, e, _ = pymap3d.geodetic2ned(49.461086542587, 11.111208635507, 0.0, LAT0, LON0, 0.0)
    np.testing.assert_allclose(rec.truth.positions[1, :2], [n, e], atol=1e-6)
    np.testing.assert_allclose(rec.truth.positions[0], 0.0, atol=1e-9)
    assert rec.truth.extra["origin_deg"] == pytest.approx((LAT0, LON0))
    np.testing.assert_array_equal(rec.truth.extra["counter"], [1, 2])
    # location fixes and the phone's own orientation are kept beside the streams
    gnss = rec.aux["gnss"]
    assert gnss["t_ns"][0] == 820_200_000 and gnss["latitude_deg"][0] == pytest.approx(49.461069)
    assert gnss["accuracy_m"][0] == 8.0 and gnss["sats_in_use"][0] == 15
    a = rec.meta.anchor  # the first good fix anchors the recording, dated by the fix's UTC time
    assert a is not None and a.source == "gnss" and a.latitude_deg == pytest.approx(49.461069)
    assert a.date.isoformat() == "2023-06-14" and a.accuracy_m == 8.0
    assert rec.aux["ahrs"]["quat_xyz"].shape == (s["ta"].size, 3)
    assert rec.aux["device"]["Model"] == "SM-A520F" and rec.aux["device"]["date"] == "2023-06-14"


def test_detected_by_content_and_listed(tmp_path: Path) -> None:
    p = write_logfile(tmp_path / "log.txt", _sample(2.0))
    m = importer_for(p)
    assert m is not None and m.__name__ == "clients.importers.getsensordata"
    (tmp_path / "notes.txt").write_text("shopping list\n")
    assert list_recordings(tmp_path) == [p]


def test_malformed_lines_are_skipped_and_noted(tmp_path: Path) -> None:
    p = write_logfile(tmp_path / "cut.txt", _sample(), extra_lines=("ACCE;1.1;1235.6;0.1;9.8", "GYRO;1.2;1235.7;x;0.0;0.0;3"))
    rec = load(p)
    notes = " ".join(rec.meta.notes)
    assert "ACCE: skipped 1 line" in notes and "GYRO: skipped 1 line" in notes


@pytest.mark.parametrize("problem", ["no_acc", "deg_s", "garbage"])
def test_refusals_name_the_field(tmp_path: Path, problem: str) -> None:
    s = _sample(6.0)
    if problem == "deg_s":
        # a phone swung while walking, its gyroscope written in deg/s under the rad/s header
        t = s["ta"]
        s["acc"] = s["acc"] + np.c_[np.zeros(t.size), 4.0 * np.sin(2 * np.pi * 1.8 * t), np.zeros(t.size)]
        s["gyr"] = np.degrees(2.0 * np.sin(2 * np.pi * 1.8 * s["tg"]))[:, None] * np.ones(3)
    p = write_logfile(tmp_path / "bad.txt", s)
    if problem == "no_acc":
        p.write_text("\n".join(ln for ln in p.read_text(encoding="latin-1").splitlines() if not ln.startswith("ACCE")),
                     encoding="latin-1")
    if problem == "garbage":
        lines = p.read_text(encoding="latin-1").splitlines()
        p.write_text("\n".join(ln.replace(";", ";?") if ln.startswith("GYRO") else ln for ln in lines), encoding="latin-1")
    with pytest.raises(ImporterError) as err:
        load(p)
    assert err.value.field == {"no_acc": "ACCE", "deg_s": "GYRO x", "garbage": "GYRO"}[problem]


def test_ipin_trials(ipin_dir: Path) -> None:
    files = list_recordings(ipin_dir)
    assert len(files) == 16
    rec = load(files[0])
    assert rec.truth is not None and len(rec.truth.t_ns) >= 10
    # the landmarks fall inside the recording, the walk returns to its first landmark
    assert rec.batch.t_start_ns < rec.truth.t_ns[0] < rec.truth.t_ns[-1] < rec.batch.t_end_ns
    np.testing.assert_allclose(rec.truth.positions[-1], rec.truth.positions[0], atol=0.01)
    assert 45.0 < rec.batch.rate_hz("acc") < 55.0 and len(rec.aux["gnss"]["t_ns"]) > 100
