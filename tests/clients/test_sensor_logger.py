"""Sensor Logger and phyphox importers (CSV folder/zip with z,y,x columns, JSON, unit and gravity handling)
and the Sensor Logger HTTP push endpoint (out-of-order and duplicated messages)."""

from __future__ import annotations

import json
import random
import zipfile
from pathlib import Path

import numpy as np
import pytest

from clients.importers import ImporterError, importer_for
from clients.importers import load as load_any
from clients.importers.phyphox import load_phyphox
from clients.importers.sensor_logger import load_sensor_logger
from models.batch import SensorBatch
from tests.server.conftest import app, auth, backend, client, make_user, settings  # noqa: F401 - fixtures

T_EPOCH = 1_698_000_000_000_000_000
G0 = 9.80665


def _phone_batch(seconds: float = 4.0, rate: float = 100.0, seed: int = 0) -> SensorBatch:
    rng = np.random.default_rng(seed)
    n = int(seconds * rate)
    t = T_EPOCH + np.arange(n, dtype=np.int64) * int(1e9 / rate) + rng.integers(0, 300_000, n)  # jitter
    t = np.sort(t)
    grav = np.array([0.3, 6.5, 7.3])  # |g| = 9.78, tilted phone; x, y, z distinct
    lin = rng.normal(0, 0.5, (n, 3))
    gyr = rng.normal(0, 0.3, (n, 3)) + [0.01, -0.02, 0.03]
    mag = np.array([12.0, -25.0, 33.0]) + rng.normal(0, 0.5, (n, 3))
    return SensorBatch(acc_t_ns=t, acc=grav + lin, gyr_t_ns=t + 1000, gyr=gyr, mag_t_ns=t[::2] + 5000, mag=mag[::2])


def _csv(t: np.ndarray, v: np.ndarray) -> str:
    lines = ["time,seconds_elapsed,z,y,x"]  # Sensor Logger's column order
    for ti, (x, y, z) in zip(t.tolist(), v.tolist()):
        lines.append(f"{ti},{(ti - T_EPOCH) / 1e9!r},{z!r},{y!r},{x!r}")
    return "\n".join(lines) + "\n"


def _export(b: SensorBatch, style: str, unit_g: bool = False) -> dict[str, str]:
    grav = np.array([0.3, 6.5, 7.3])
    scale = 1 / G0 if unit_g else 1.0
    files = {"Gyroscope": _csv(b.gyr_t_ns, b.gyr), "Magnetometer": _csv(b.mag_t_ns, b.mag),
             "Metadata": "version,device name,recording time,platform\n1,Pixel,2024,android\n"}
    if style == "total":
        files["TotalAcceleration"] = _csv(b.acc_t_ns, b.acc * scale)
        files["Accelerometer"] = _csv(b.acc_t_ns, (b.acc - grav) * scale)
    elif style == "user+gravity":
        files["Accelerometer"] = _csv(b.acc_t_ns, (b.acc - grav) * scale)
        files["Gravity"] = _csv(b.acc_t_ns, np.tile(grav, (len(b.acc), 1)) * scale)
    elif style == "raw-android":
        files["Accelerometer"] = _csv(b.acc_t_ns, b.acc * scale)
    elif style == "user-only":
        files["Accelerometer"] = _csv(b.acc_t_ns, (b.acc - grav) * scale)
    return files


def _write_folder(tmp: Path, files: dict[str, str]) -> Path:
    d = tmp / "export"
    d.mkdir()
    for k, v in files.items():
        (d / f"{k}.csv").write_text(v)
    return d


@pytest.mark.parametrize("style", ["total", "user+gravity", "raw-android"])
@pytest.mark.parametrize("container", ["folder", "csv", "zip", "json"])
def test_sensor_logger_export_round_trip(tmp_path: Path, style: str, container: str) -> None:
    b = _phone_batch()
    files = _export(b, style)
    if container in ("folder", "csv"):
        d = _write_folder(tmp_path, files)
        path = d if container == "folder" else d / "Gyroscope.csv"
    elif container == "zip":
        path = tmp_path / "export.zip"
        with zipfile.ZipFile(path, "w") as zf:
            for k, v in files.items():
                zf.writestr(f"rec_2024/{k}.csv", v)
    else:
        recs = []
        for k, text in files.items():
            if k == "Metadata":
                continue
            for line in text.splitlines()[1:]:
                t, el, z, y, x = line.split(",")
                recs.append({"sensor": k, "time": t, "seconds_elapsed": el, "z": z, "y": y, "x": x})
        random.Random(0).shuffle(recs)  # the JSON export is not guaranteed sorted
        path = tmp_path / "export.json"
        path.write_text(json.dumps(recs))
    rec = load_any(path) if container != "folder" else load_sensor_logger(path)
    assert rec.meta.source_format == "sensor-logger" and rec.meta.mount == "phone"
    assert np.array_equal(rec.batch.acc_t_ns, b.acc_t_ns)
    assert np.allclose(rec.batch.acc, b.acc, atol=1e-12)  # x, y, z back in x, y, z order
    assert np.array_equal(rec.batch.gyr, b.gyr) and np.array_equal(rec.batch.mag_t_ns, b.mag_t_ns)
    assert any("accelerometer:" in n for n in rec.meta.notes)


def _ios_export(b: SensorBatch, standardised: bool) -> dict[str, str]:
    """An iOS export: Accelerometer (user acceleration) and Gravity, no TotalAcceleration; without
    standardisation CoreMotion's sign, the negative of Android's on every axis (awesome-sensor-logger
    COORDINATES.md); the gyroscope agrees on both platforms."""
    grav = np.array([0.3, 6.5, 7.3])
    sign = 1.0 if standardised else -1.0
    return {"Accelerometer": _csv(b.acc_t_ns, sign * (b.acc - grav)),
            "Gravity": _csv(b.acc_t_ns, sign * np.tile(grav, (len(b.acc), 1))),
            "Gyroscope": _csv(b.gyr_t_ns, b.gyr), "Magnetometer": _csv(b.mag_t_ns, b.mag),
            "Metadata": ("version,device name,recording epoch time,recording time,recording timezone,platform,"
                         "appVersion,device id,sensors,sampleRateMs,standardisation,platform version\n"
                         f"3,iPhone 15,1698000000000,2024-01-01_10-00-00,UTC,ios,1.40,abc,Accelerometer|Gravity,"
                         f"10|10,{str(standardised).lower()},17.2\n")}


@pytest.mark.parametrize("standardised", [False, True])
@pytest.mark.parametrize("container", ["folder", "zip", "json"])
def test_sensor_logger_ios_export_is_read_with_its_platform_convention(tmp_path: Path, standardised: bool,
                                                                       container: str) -> None:
    b = _phone_batch(seed=3)
    files = _ios_export(b, standardised)
    if container == "folder":
        path = _write_folder(tmp_path, files)
    elif container == "zip":
        path = tmp_path / "ios.zip"
        with zipfile.ZipFile(path, "w") as zf:
            for k, v in files.items():
                zf.writestr(f"rec/{k}.csv", v)
    else:
        recs: list[dict[str, str]] = [{"sensor": "Metadata", "platform": "ios",
                                       "standardisation": str(standardised).lower()}]
        for k, text in files.items():
            if k == "Metadata":
                continue
            for line in text.splitlines()[1:]:
                t, el, z, y, x = line.split(",")
                recs.append({"sensor": k, "time": t, "seconds_elapsed": el, "z": z, "y": y, "x": x})
        path = tmp_path / "ios.json"
        path.write_text(json.dumps(recs))
    rec = load_any(path)
    assert np.allclose(rec.batch.acc, b.acc, atol=1e-9)  # specific force: +9.8 up at rest, as Android reads it
    assert np.array_equal(rec.batch.gyr, b.gyr)
    if standardised:
        assert not any(k == "acc axes" for k in rec.meta.units_converted)
    else:
        assert "x -1" in rec.meta.units_converted["acc axes"]


def test_sensor_logger_without_metadata_says_the_platform_is_unknown(tmp_path: Path) -> None:
    b = _phone_batch(seed=4)
    files = _export(b, "user+gravity")
    del files["Metadata"]
    rec = load_sensor_logger(_write_folder(tmp_path, files))
    assert np.allclose(rec.batch.acc, b.acc, atol=1e-9)
    assert any("platform unknown" in n and "Metadata.csv" in n for n in rec.meta.notes)


@pytest.mark.parametrize("style", ["total", "user+gravity"])
def test_sensor_logger_in_g_is_converted_and_reported(tmp_path: Path, style: str) -> None:
    b = _phone_batch(seed=1)
    rec = load_sensor_logger(_write_folder(tmp_path, _export(b, style, unit_g=True)))
    assert np.allclose(rec.batch.acc, b.acc, atol=1e-9)
    assert any("g -> m/s^2" in v for v in rec.meta.units_converted.values())


def test_sensor_logger_without_gravity_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ImporterError) as exc:
        load_sensor_logger(_write_folder(tmp_path, _export(_phone_batch(), "user-only")))
    assert exc.value.field == "Accelerometer" and "TotalAcceleration" in exc.value.problem


def test_sensor_logger_bad_header_and_values(tmp_path: Path) -> None:
    d = tmp_path / "e"
    d.mkdir()
    (d / "TotalAcceleration.csv").write_text("time,seconds_elapsed,z,y,x\n1,0.0,9.8,0,abc\n")
    with pytest.raises(ImporterError):
        load_sensor_logger(d)
    assert importer_for(tmp_path / "nothing.csv") is None


def _cut_last_line(text: str) -> str:
    lines = text.splitlines()
    lines[-1] = ",".join(lines[-1].split(",")[:2])  # the app stopped mid-write: time and seconds_elapsed only
    return "\n".join(lines) + "\n"


def _empty_cells(text: str, line: int) -> str:
    lines = text.splitlines()
    lines[line] = ",".join(lines[line].split(",")[:2] + ["", "", ""])
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(
    ("damage", "acc_n", "gyr_n", "words"),
    [
        ({"TotalAcceleration": _cut_last_line}, -1, 0, "line 401"),
        ({"Gyroscope": _cut_last_line}, 0, -1, "line 401"),
        ({"Gyroscope": lambda s: _empty_cells(s, 20)}, 0, -1, "non-finite"),
        ({"TotalAcceleration": lambda s: _empty_cells(s, 7)}, -1, 0, "non-finite"),
    ],
)
def test_sensor_logger_cut_line_and_empty_cells_lose_only_those_samples(
    tmp_path: Path, damage: dict, acc_n: int, gyr_n: int, words: str
) -> None:
    """Sample policy of clients.importers._common: a line cut mid-write or an empty cell drops that sample
    (noted), not the recording."""
    b = _phone_batch()
    files = _export(b, "total")
    for name, f in damage.items():
        files[name] = f(files[name])
    rec = load_sensor_logger(_write_folder(tmp_path, files))
    assert len(rec.batch.acc_t_ns) == len(b.acc_t_ns) + acc_n
    assert len(rec.batch.gyr_t_ns) == len(b.gyr_t_ns) + gyr_n
    assert words in " | ".join(rec.meta.notes)


def test_sensor_logger_a_file_of_malformed_lines_is_refused_by_name(tmp_path: Path) -> None:
    b = _phone_batch()
    files = _export(b, "total")
    lines = files["Gyroscope"].splitlines()
    files["Gyroscope"] = "\n".join(lines[:1] + [ln + ",1" if i % 3 == 0 else ln for i, ln in enumerate(lines[1:])])
    with pytest.raises(ImporterError, match="malformed") as ei:
        load_sensor_logger(_write_folder(tmp_path, files))
    assert "Gyroscope.csv" in str(ei.value)


@pytest.mark.parametrize("optional", ["Magnetometer", "Gravity", "Gyroscope"])
def test_sensor_logger_header_only_optional_stream_is_left_out(tmp_path: Path, optional: str) -> None:
    """A sensor that delivered nothing (Sensor Logger still writes its header) leaves that stream out."""
    b = _phone_batch()
    files = _export(b, "total")
    files[optional] = "time,seconds_elapsed,z,y,x\n"
    rec = load_sensor_logger(_write_folder(tmp_path, files))
    assert np.allclose(rec.batch.acc, b.acc)
    assert f"{optional}: no samples" in " | ".join(rec.meta.notes)
    if optional != "Gravity":
        assert len(rec.batch.stream("mag" if optional == "Magnetometer" else "gyr")[0]) == 0


def test_sensor_logger_header_only_accelerometer_is_refused(tmp_path: Path) -> None:
    files = _export(_phone_batch(), "total")
    files["TotalAcceleration"] = files["Accelerometer"] = "time,seconds_elapsed,z,y,x\n"
    with pytest.raises(ImporterError, match="no accelerometer file with samples"):
        load_sensor_logger(_write_folder(tmp_path, files))


@pytest.mark.parametrize("sep", [",", ";"])
def test_phyphox_export(tmp_path: Path, sep: str) -> None:
    b = _phone_batch(seed=2)
    t0 = b.acc_t_ns[0]

    def table(head: str, t: np.ndarray, v: np.ndarray) -> str:
        cols = ['"Time (s)"'] + [f'"{head} {a} ({u})"' for a, u in zip("xyz", [UNITS[head]] * 3)]
        rows = [sep.join(cols)]
        for ti, row in zip(t.tolist(), v.tolist()):
            vals = [repr((ti - int(t0)) / 1e9)] + [repr(float(x)) for x in row]
            rows.append(sep.join(s.replace(".", ",") if sep == ";" else s for s in vals))
        return "\n".join(rows) + "\n"

    UNITS = {"Acceleration": "m/s^2", "Gyroscope": "rad/s", "Magnetic field": "µT"}
    path = tmp_path / "phyphox.zip"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("Accelerometer.csv", table("Acceleration", b.acc_t_ns, b.acc))
        zf.writestr("Gyroscope.csv", table("Gyroscope", b.gyr_t_ns, b.gyr))
        zf.writestr("Magnetometer.csv", table("Magnetic field", b.mag_t_ns, b.mag))
        zf.writestr("meta/time.csv", f"event,experiment time,system time\nSTART,0.0,{int(t0) / 1e9!r}\n")
    rec = load_any(path)
    assert rec.meta.source_format == "phyphox"
    assert np.allclose(rec.batch.acc, b.acc) and np.allclose(rec.batch.gyr, b.gyr) and len(rec.batch.mag) == len(b.mag)
    assert np.max(np.abs(rec.batch.acc_t_ns - b.acc_t_ns)) < 1000  # ns; epoch from meta/time.csv
    single = tmp_path / "Raw Data.csv"
    single.write_text(table("Acceleration", b.acc_t_ns, b.acc))
    assert np.allclose(load_phyphox(single).batch.acc, b.acc)
    lin = tmp_path / "lin.csv"
    lin.write_text(table("Acceleration", b.acc_t_ns, b.acc).replace("Acceleration", "Linear Acceleration"))
    with pytest.raises(ImporterError):
        load_phyphox(lin)


def _phyphox_table(head: str, unit: str, t_s: np.ndarray, v: np.ndarray, sep: str = ",", dec: str = ".") -> str:
    rows = [sep.join(['"Time (s)"'] + [f'"{head} {a} ({unit})"' for a in "xyz"])]
    rows += [sep.join(f"{x:.9E}".replace(".", dec) for x in (ti, *r)) for ti, r in zip(t_s.tolist(), v.tolist())]
    return "\n".join(rows) + "\n"


def _phyphox_folder(tmp: Path, b: SensorBatch, sep: str = ",", dec: str = ".", time_csv: bool = True) -> Path:
    """An unpacked phyphox export: one table per sensor and meta/time.csv."""
    d = tmp / "phyphox-export"
    (d / "meta").mkdir(parents=True)
    t0 = T_EPOCH  # whole seconds: exact in the 10 significant digits phyphox writes
    for name, head, unit, (t, v) in (("Accelerometer", "Acceleration", "m/s^2", b.stream("acc")),
                                     ("Gyroscope", "Gyroscope", "rad/s", b.stream("gyr"))):
        (d / f"{name}.csv").write_text(_phyphox_table(head, unit, (t - t0) / 1e9, v, sep, dec))
    if time_csv:
        cells = [["event", "experiment time", "system time"], ["START", "0.000000000E+00", f"{t0 / 1e9:.9E}"]]
        (d / "meta" / "time.csv").write_text("\n".join(sep.join(f'"{c}"'.replace(".", dec) for c in r) for r in cells) + "\n")
    return d


@pytest.mark.parametrize(("sep", "dec"), [(",", "."), ("\t", "."), ("\t", ","), (";", ",")])
def test_phyphox_every_csv_flavour_of_the_app(tmp_path: Path, sep: str, dec: str) -> None:
    """phyphox exports CSV with comma, tab (decimal point or comma) or semicolon separators: same samples,
    and the same UTC start from meta/time.csv."""
    b = _phone_batch(seed=3)
    rec = load_any(_phyphox_folder(tmp_path, b, sep, dec))
    assert rec.meta.source_format == "phyphox"
    assert np.allclose(rec.batch.acc, b.acc, atol=1e-8) and np.allclose(rec.batch.gyr, b.gyr, atol=1e-8)
    assert np.max(np.abs(rec.batch.acc_t_ns - b.acc_t_ns)) < 10_000  # ns: the epoch was read
    assert not any("experiment start" in n for n in rec.meta.notes)


def test_phyphox_one_table_of_an_export_loads_the_export(tmp_path: Path) -> None:
    """Accelerometer.csv of an unpacked export must not lose the gyroscope table beside it."""
    b = _phone_batch(seed=4)
    d = _phyphox_folder(tmp_path, b)
    rec = load_any(d / "Accelerometer.csv")
    assert len(rec.batch.gyr_t_ns) == len(b.gyr_t_ns)
    assert any("whole export" in n for n in rec.meta.notes)


@pytest.mark.parametrize("damage", ["cut", "empty-cells", "gyro-header-only"])
def test_phyphox_damaged_tables_lose_only_the_damaged_samples(tmp_path: Path, damage: str) -> None:
    b = _phone_batch(seed=5)
    d = _phyphox_folder(tmp_path, b)
    name = "Gyroscope.csv" if damage == "gyro-header-only" else "Accelerometer.csv"
    lines = (d / name).read_text().splitlines()
    if damage == "cut":
        lines[-1] = lines[-1][:20]  # the export was cut mid-write
    elif damage == "empty-cells":
        lines[10] = lines[10].split(",")[0] + ",,,"
    else:
        lines = lines[:1]
    (d / name).write_text("\n".join(lines) + "\n")
    rec = load_phyphox(d)
    notes = " | ".join(rec.meta.notes)
    if damage == "gyro-header-only":
        assert len(rec.batch.gyr_t_ns) == 0 and "no samples (header only)" in notes
        assert len(rec.batch.acc_t_ns) == len(b.acc_t_ns)
    else:
        assert len(rec.batch.acc_t_ns) == len(b.acc_t_ns) - 1
        assert ("line 401" if damage == "cut" else "non-finite") in notes


# ---------------------------------------------------------------- HTTP push
def _messages(b: SensorBatch, per_msg_s: float = 0.5) -> list[dict]:  # type: ignore[type-arg]
    items = []
    for name, tag in (("acc", "totalacceleration"), ("gyr", "gyroscope"), ("mag", "magnetometer")):
        t, v = b.stream(name)
        items += [{"name": tag, "time": int(ti), "values": {"x": x, "y": y, "z": z}} for ti, (x, y, z) in zip(t, v.tolist())]
    items.sort(key=lambda it: it["time"])
    t0 = items[0]["time"]
    groups: dict[int, list] = {}  # type: ignore[type-arg]
    for it in items:
        groups.setdefault(int((it["time"] - t0) // (per_msg_s * 1e9)), []).append(it)
    extra = [{"name": "location", "time": t0, "values": {"latitude": 1.0}}]
    return [{"messageId": k, "sessionId": "sl-1", "deviceId": "dev", "payload": g + (extra if k == 0 else [])}
            for k, g in sorted(groups.items())]


def _push_all(client, tok: str, msgs: list[dict], sl_id: str) -> list[dict]:  # type: ignore[no-untyped-def]  # noqa: F811
    out = []
    for m in msgs:
        r = client.post("/v1/sensorlogger", json={**m, "sessionId": sl_id}, params={"token": tok})
        assert r.status_code == 200, r.text
        out.append(r.json())
    r = client.post(f"/v1/sensorlogger/{sl_id}/flush", headers=auth(tok))
    assert r.status_code == 200
    sid = r.json()["session_id"]
    client.post(f"/v1/sessions/{sid}/close", headers=auth(tok))
    return client.get(f"/v1/sessions/{sid}/trajectory", headers=auth(tok)).json()["positions"], out  # type: ignore[return-value]


def test_sensor_logger_push_out_of_order_and_duplicated(client, make_user) -> None:  # type: ignore[no-untyped-def]  # noqa: F811
    from clients.synth import synthesize
    from energy.engine import Engine

    rec = synthesize("walk", seed=4, rate_hz=100.0)
    b = rec.batch.time_slice(None, rec.batch.t_start_ns + 30 * 10**9)
    b = SensorBatch(**{k: (v + T_EPOCH if k.endswith("_t_ns") else v) for k, v in b._kwargs().items()})
    msgs = _messages(b)
    _, tok = make_user()
    in_order, _ = _push_all(client, tok, msgs, "in-order")
    rng = random.Random(1)
    shuffled = list(msgs)
    for i in range(0, len(shuffled) - 1, 2):  # neighbours swapped: within the 2-s hold
        if rng.random() < 0.7:
            shuffled[i], shuffled[i + 1] = shuffled[i + 1], shuffled[i]
    shuffled += [msgs[3], msgs[10], msgs[0]]  # duplicates, late
    shuffled.insert(20, msgs[19])
    messy, answers = _push_all(client, tok, shuffled, "messy")
    assert sum(a["duplicate"] for a in answers) == 4
    assert answers[-1]["late_samples"] == 0
    from models.geo import magnetic_north_of, to_true_north

    eng = Engine(mode="auto")
    ups = [eng.feed(b), eng.flush()]
    local = [p for u in ups for p in u.positions]
    assert len(in_order) == len(local) > 3
    # the server serves the trajectory turned onto magnetic north once the engine has announced it
    az = magnetic_north_of((e.kind, e.detail) for u in ups for e in u.events) or 0.0
    n, e_, _ = to_true_north(np.array([p.north for p in local]), np.array([p.east for p in local]),
                             np.zeros(len(local)), -az)
    for got in (in_order, messy):
        g = np.array([[p["t_ns"], p["north"], p["east"], p["down"]] for p in got])
        ref = np.array([[p.t_ns, n[i], e_[i], p.down] for i, p in enumerate(local)])
        assert g.shape == ref.shape and np.array_equal(g[:, 0], ref[:, 0])
        assert np.max(np.abs(g[:, 1:] - ref[:, 1:])) <= 1e-9


def test_sensor_logger_push_refusals_and_isolation(client, make_user) -> None:  # type: ignore[no-untyped-def]  # noqa: F811
    _, a = make_user()
    _, b = make_user()
    msg = {"messageId": 1, "sessionId": "x", "deviceId": "d",
           "payload": [{"name": "accelerometer", "time": T_EPOCH, "values": {"x": 0.1, "y": 0.0, "z": 0.0}}]}
    assert client.post("/v1/sensorlogger", json=msg).status_code == 401
    r = client.post("/v1/sensorlogger", json={**msg, "payload": [{"name": "gyroscope", "time": T_EPOCH, "values": {"x": 1}}]},
                    headers=auth(a))
    assert r.status_code == 422 and "values.y" in r.json()["detail"]
    r = client.post("/v1/sensorlogger", json={"messageId": 1}, headers=auth(a))
    assert r.status_code == 422 and r.json()["field"] in ("sessionId", "payload")
    r = client.post("/v1/sensorlogger", json=msg, headers=auth(a))  # accelerometer without gravity: unusable
    assert r.status_code == 422 and r.json()["field"] == "payload.accelerometer" and "gravity" in r.json()["detail"]
    msg["payload"] = [{"name": "totalacceleration", "time": T_EPOCH, "values": {"x": 0.1, "y": 0.0, "z": 9.8}}]
    r = client.post("/v1/sensorlogger", json=msg, headers=auth(a))
    assert r.status_code == 200
    assert client.post("/v1/sensorlogger/x/flush", headers=auth(b)).status_code == 404
    sid = r.json()["session_id"]
    assert client.get(f"/v1/sessions/{sid}", headers=auth(b)).status_code == 404


@pytest.mark.parametrize("container", ["folder", "zip"])
def test_sensor_logger_location_anchors_the_recording(tmp_path: Path, container: str) -> None:
    """The export's Location.csv: the first fix with an accuracy of at most 25 m anchors the recording; a poor
    first fix and an unreadable row are passed over; without a good fix there is no anchor (and it says so)."""
    b = _phone_batch()
    files = _export(b, "total")
    t0 = int(b.acc_t_ns[0])
    files["Location"] = "\n".join([
        "time,seconds_elapsed,bearingAccuracy,speedAccuracy,verticalAccuracy,horizontalAccuracy,speed,bearing,altitude,longitude,latitude",
        f"{t0},0,0,0,10,65.0,0,0,30.0,-117.80,33.60",
        f"{t0 + 10**9},1,0,0,5,,0,0,31.0,-117.81,33.61",
        f"{t0 + 2 * 10**9},2,0,0,4,6.5,0,0,15.5,-117.8443,33.6405",
        f"{t0 + 3 * 10**9},3,0,0,3,3.0,0,0,16.0,-117.9,33.7"]) + "\n"
    if container == "folder":
        path = _write_folder(tmp_path, files)
    else:
        path = tmp_path / "export.zip"
        with zipfile.ZipFile(path, "w") as zf:
            for k, v in files.items():
                zf.writestr(f"rec/{k}.csv", v)
    rec = load_any(path)
    a = rec.meta.anchor
    assert a is not None and (a.latitude_deg, a.longitude_deg, a.altitude_m, a.accuracy_m) == (33.6405, -117.8443, 15.5, 6.5)
    assert a.source == "location" and any("location: 4 fixes" in n for n in rec.meta.notes)
    files["Location"] = files["Location"].replace(",6.5,", ",60.0,").replace(",3.0,", ",90.0,")
    (tmp_path / "poor").mkdir()
    for k, v in files.items():
        (tmp_path / "poor" / f"{k}.csv").write_text(v)
    rec = load_any(tmp_path / "poor")
    assert rec.meta.anchor is None and any("none accurate enough" in n for n in rec.meta.notes)
