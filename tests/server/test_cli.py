"""CLI contracts (DESIGN.md "Service contracts"): admin create-user, replay over HTTP == local, export, demo."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np
import pytest

from clients.cli import main


def _run(capsys: pytest.CaptureFixture[str], argv: list[str]) -> tuple[int, str]:
    rc = main(argv)
    return rc, capsys.readouterr().out


@pytest.fixture(scope="module")
def live_server(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    """A real uvicorn server (default settings: engines in a helper process) on a fresh SQLite file."""
    from clients.commands.demo import LocalServer

    db = tmp_path_factory.mktemp("cli") / "pednav.db"
    with LocalServer(f"sqlite:///{db}") as srv:
        yield srv, f"sqlite:///{db}"
        if srv.app.state.host.pool is not None:
            srv.app.state.host.pool.shutdown()


def test_admin_create_user_json(capsys, live_server) -> None:  # type: ignore[no-untyped-def]
    srv, url = live_server
    rc, out = _run(capsys, ["admin", "create-user", "carol", "--json", "--database-url", url])
    doc = json.loads(out)
    assert rc == 0 and {"user_id", "token"} <= set(doc) and doc["token"].startswith("pn_")
    assert doc["expires_at"] is not None  # default lifetime PEDNAV_TOKEN_TTL_S (30 days)
    assert main(["admin", "create-user", "carol", "--json", "--database-url", url]) == 1  # exists
    capsys.readouterr()


def test_replay_over_http_equals_local_and_export(capsys, live_server, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    srv, url = live_server
    _, out = _run(capsys, ["admin", "create-user", "dave", "--json", "--database-url", url])
    token = json.loads(out)["token"]
    rc1, local = _run(capsys, ["replay", "walk", "--json"])
    rc2, remote = _run(capsys, ["replay", "walk", "--server", srv.url, "--token", token, "--batch-seconds", "1", "--json"])
    assert rc1 == rc2 == 0
    a, b = json.loads(local), json.loads(remote)
    assert "session_id" in b and "session_id" not in a
    pa, pb = np.array(a["positions"]), np.array(b["positions"])
    assert pa.shape == pb.shape and pa.shape[0] > 5 and pa.shape[1] == 4
    assert np.max(np.abs(pa - pb)) <= 1e-9
    assert a["labels"] == b["labels"] and a["modes"] == b["modes"] and len(a["labels"]) == len(a["positions"])
    rc, text = _run(capsys, ["export", str(b["session_id"]), "--server", srv.url, "--token", token, "--format", "csv"])
    rows = list(csv.DictReader(io.StringIO(text)))
    assert rc == 0 and len(rows) == len(pb)
    assert np.allclose([[float(r["north"]), float(r["east"])] for r in rows], pb[:, 1:3], atol=1e-9)
    assert main(["export", str(b["session_id"]), "--server", srv.url, "--token", "wrong"]) == 1
    capsys.readouterr()


def test_anchored_replay_over_http_equals_local(capsys, live_server, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """--anchor: the server geo-references the session it stores, the local replay its engine's output, with the
    same function; positions and latitude/longitude agree to 1e-9. The synthetic walk has a magnetometer: once
    its compass is calibrated the engine announces magnetic north's azimuth in its frame (``north_reference``),
    so both turn the track onto magnetic north and then by the declination."""
    north = "magnetic"
    import math

    import xmlschema

    from models.geo import to_true_north
    from models.track_export import read_gpx

    srv, url = live_server
    _, out = _run(capsys, ["admin", "create-user", f"geo-{north}", "--json", "--database-url", url])
    token = json.loads(out)["token"]
    anchor = ["--anchor", "33.6405,-117.8443,15", "--anchor-date", "2026-12-03"]
    gpx = tmp_path / "walk.gpx"
    rc1, local = _run(capsys, ["replay", "walk", *anchor, "--export", str(gpx), "--json"])
    rc2, remote = _run(capsys, ["replay", "walk", "--server", srv.url, "--token", token, *anchor, "--json"])
    assert rc1 == rc2 == 0
    a, b = json.loads(local), json.loads(remote)
    assert a["north"] == b["north"] == ("true" if north else "initial-heading")
    assert a["declination_deg"] == b["declination_deg"]
    assert (a["declination_deg"] > 10.5) == (north is not None)
    pa, pb = np.array(a["positions"]), np.array(b["positions"])
    assert pa.shape == pb.shape and pa.shape[0] > 5 and np.max(np.abs(pa - pb)) <= 1e-9
    ga, gb = np.array(a["geodetic"]), np.array(b["geodetic"])
    assert np.max(np.abs(ga[:, :2] - gb[:, :2])) <= 1e-12 and np.max(np.abs(ga[:, 2] - gb[:, 2])) <= 1e-9
    assert ga[0, 0] == pytest.approx(33.6405 + pa[0, 1] / 111_000, abs=1e-5)
    xmlschema.XMLSchema(str(Path(__file__).parents[1] / "models" / "data" / "gpx11_subset.xsd")).validate(gpx.read_text())
    np.testing.assert_allclose(read_gpx(gpx.read_text())[:, :2], ga[:, :2], atol=1e-9)
    rc, text = _run(capsys, ["export", str(b["session_id"]), "--server", srv.url, "--token", token, "--format", "kml"])
    assert rc == 0 and "<coordinates>" in text
    _, plain = _run(capsys, ["replay", "walk", "--json"])
    pu = np.array(json.loads(plain)["positions"])
    assert json.loads(plain)["north"] == ("magnetic" if north else "initial-heading")
    n, e, _ = to_true_north(pu[:, 1], pu[:, 2], np.zeros(len(pu)), math.radians(a["declination_deg"]))
    np.testing.assert_allclose(np.column_stack([n, e]), pa[:, 1:3], atol=1e-9)  # one turn about the origin


def test_replay_unknown_input(capsys) -> None:  # type: ignore[no-untyped-def]
    assert main(["replay", "no-such-file-or-scenario", "--json"]) == 1
    assert "not a synthetic scenario" in capsys.readouterr().err


def test_demo_runs_and_writes_plot(capsys, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    plot = tmp_path / "demo.png"
    rc, out = _run(capsys, ["demo", "--json", "--plot", str(plot), "--dir", str(tmp_path / "db")])
    s = json.loads(out)
    assert rc == 0 and plot.stat().st_size > 10_000
    assert s["positions"] > 20 and s["distance_m"] > 0 and np.isfinite(s["final_error_m"])
    assert set(s["time_in_mode_s"]) <= {"zupt", "pdr", "idle"} and 0 < s["gyro_duty_cycle"] < 1
    assert s["energy"]["scheduler_mj"] > 0 and s["energy"]["always_on_mj"] > 0
    assert s["geojson_points"] == s["positions"]
    back = s["returning_user"]  # the second walk starts from the profile the first one stored on the server
    assert back["session_id"] != s["session_id"] and np.isfinite(back["final_error_m"])
    assert back["gyro_duty_cycle"] < s["gyro_duty_cycle"]
    assert Path(back["plot"]).stat().st_size > 10_000 and Path(back["plot"]).parent == plot.parent


def _xsens_csv(path: Path, n: int = 400) -> Path:
    """A gaitmap/Xsens-style CSV (time column [s], acc [m/s^2], gyr [deg/s], normalised magnetometer): a still
    foot in a field of 0.9 normalised units."""
    rows = [",acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z,mag_x,mag_y,mag_z"]
    rows += [f"{k / 100:.2f},0,0,9.81,0,0,0,0.4,0,0.806" for k in range(n)]
    path.write_text("\n".join(rows) + "\n")
    return path


def test_replay_takes_a_normalised_magnetometer_only_with_its_scale(capsys, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    from clients.commands.replay import load_recording

    f = _xsens_csv(tmp_path / "still.csv")
    assert load_recording(str(f)).batch.mag.size == 0  # scale unknown: left out
    mag = load_recording(str(f), 50.0).batch.mag
    assert np.linalg.norm(mag, axis=1) == pytest.approx(0.9 * 50.0, rel=1e-3)
    rc, out = _run(capsys, ["replay", str(f), "--mag-scale-ut", "50", "--json"])
    assert rc == 0 and json.loads(out)["positions"]
    for argv, said in ((["replay", "walk", "--mag-scale-ut", "50"], "not to synthetic scenarios"),
                       (["replay", str(f), "--mag-scale-ut", "0"], "must be a positive field")):
        assert main(argv) == 1
        err = capsys.readouterr().err
        assert "--mag-scale-ut" in err and said in err, err
