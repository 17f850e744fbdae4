"""Energy measured on replays: the accounting of what the device did, the eval fields on real recordings,
``pednav eval recordings`` on a folder with an unimportable file, ``pednav eval plot``."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from clients.cli import main
from clients.evaluation.energy_ratio import EnergyAccounting, compare, gyro_intervals
from clients.evaluation.harness import run_engine
from clients.importers._common import G0
from clients.synth import synthesize
from energy.device import replay
from energy.engine import Engine
from energy.power import DEFAULT_PROFILE, Timeline
from tests.clients.test_importers import A_COLS, PREFIX


@pytest.fixture(scope="module")
def walk() -> Any:
    """The synthetic walk (5 s standing, 60 s walking with two turns, 5 s standing), 200 Hz."""
    return synthesize("walk", seed=1)


def _json(capsys: pytest.CaptureFixture[str], argv: list[str], code: int = 0) -> dict[str, Any]:
    assert main(argv) == code
    return json.loads(capsys.readouterr().out)


# ---------------------------------------------------------------------------------------------- accounting
class GyroForcedOff:
    """An engine whose device is told, from ``after_s`` into the recording on, to keep the gyroscope off and
    sample the accelerometer and magnetometer at 25 Hz (Gait-DR's rates), whatever the engine asks for."""

    def __init__(self, engine: Engine, t0_ns: int, after_s: float) -> None:
        self.engine = engine
        self.switch_ns = t0_ns + int(after_s * 1e9)
        self.fed_to_ns = t0_ns

    @property
    def sensor_config(self) -> Any:
        c = self.engine.sensor_config
        if self.fed_to_ns < self.switch_ns:
            return c
        return dataclasses.replace(c, gyro_on=False, gyro_wake_on_motion=False, gyr_rate_hz=0.0, acc_rate_hz=25.0,
                                   mag_rate_hz=25.0)

    @property
    def trace(self) -> Any:
        return self.engine.trace

    def feed(self, batch: Any) -> Any:
        if len(batch):
            self.fed_to_ns = int(batch.acc_t_ns[-1])
        return self.engine.feed(batch)

    def flush(self) -> Any:
        return self.engine.flush()


def test_a_gyroscope_forced_off_most_of_the_time_costs_well_below_the_baseline(walk: Any) -> None:
    acc = EnergyAccounting.load()
    t0, t_end = int(walk.batch.t_start_ns), int(walk.batch.t_end_ns)
    forced = replay(GyroForcedOff(Engine(mode="auto"), t0, after_s=10.0), walk.batch)  # type: ignore[arg-type]
    base = replay(Engine(mode="zupt"), walk.batch)
    e = acc.report(Timeline.from_replay(forced, t_end), "auto")
    b = acc.report(Timeline.from_replay(base, t_end), "zupt")
    assert 0.10 < forced.gyro_on_fraction < 0.20  # the first 10 s (and the batch that reached them) of 70 s
    assert e.total_mj / b.total_mj < 0.35
    # the gyroscope is charged for exactly the time it was on, at the profile's current
    gyr = acc.profile.sensors["gyr"]
    on_s = forced.gyro_on_fraction * (t_end + 1 - t0) / 1e9
    assert e.components_mj["gyr"] == pytest.approx(on_s * gyr.current(200.0) * acc.profile.supply_v / 1e3
                                                   + (70.0 - on_s) * gyr.off_current_ua * acc.profile.supply_v / 1e3,
                                                   rel=1e-3)
    assert b.components_mj["gyr"] == pytest.approx(70.0 * gyr.current(200.0) * acc.profile.supply_v / 1e3, rel=1e-3)
    # the accelerometer ran at 25 Hz once the gyroscope was off: fewer samples, cheaper per second
    assert forced.samples_sent["acc"] < 0.3 * base.samples_sent["acc"]
    assert e.components_mj["acc"] < b.components_mj["acc"] and e.components_mj["radio"] < b.components_mj["radio"]


@pytest.mark.parametrize("batch_seconds", [0.5, 2.5])
def test_baseline_accounting_does_not_depend_on_the_upload_length(walk: Any, batch_seconds: float) -> None:
    """The always-on device's sensors and computation (its engine has no per-batch cost) are the same however
    the recording is cut into uploads; only the radio's per-request part changes, by exactly the requests."""
    acc = EnergyAccounting.load()
    t_end = int(walk.batch.t_end_ns)
    one = replay(Engine(mode="zupt"), walk.batch, batch_seconds=1.0)
    other = replay(Engine(mode="zupt"), walk.batch, batch_seconds=batch_seconds)
    e1 = acc.report(Timeline.from_replay(one, t_end), "zupt")
    e2 = acc.report(Timeline.from_replay(other, t_end), "zupt")
    assert acc.costs("zupt")[0].us_per_batch.get("zupt", 0.0) == 0.0
    for k in ("acc", "gyr", "mag", "compute"):
        assert e2.components_mj[k] == pytest.approx(e1.components_mj[k], rel=1e-9), k
    radio = acc.profile.radio
    per_request = (64 * radio.uj_per_byte + radio.uj_per_request) / 1e3
    assert other.batches != one.batches
    assert e2.components_mj["radio"] - e1.components_mj["radio"] == pytest.approx(
        (other.batches - one.batches) * per_request, rel=1e-9)


def test_compare_charges_each_engine_its_own_costs_and_reads_the_timelines(walk: Any) -> None:
    acc = EnergyAccounting.load()
    assert acc.profile.name == DEFAULT_PROFILE
    assert acc.costs("zupt")[1] == "engines.zupt" and acc.costs("auto")[1] == "engines.auto"
    assert acc.costs("pdr")[1] == "engines.auto"  # no table of its own: the scheduler's
    piece = walk.batch.time_slice(int(walk.batch.t_start_ns), int(walk.batch.t_start_ns) + int(30e9))
    run, ref = run_engine(piece, "auto"), run_engine(piece, "zupt")
    out = compare(acc, "auto", run, ref, "vicon", {"armse_2d_m": 0.2}, {"armse_2d_m": 0.1})
    assert out["accuracy_ratio"] == pytest.approx(2.0) and out["accuracy_metric"] == "armse_2d_m"
    assert out["energy_ratio"] == pytest.approx(out["energy"]["total_mj"] / out["energy"]["baseline_total_mj"])
    assert out["gyro_on_fraction"] == run.gyro_on_fraction
    on = gyro_intervals(run.timeline, run.t_start_ns)
    assert sum(b - a for a, b in on) == pytest.approx(run.gyro_on_fraction * 30.0, abs=0.01)
    assert all(a < b for a, b in on) and all(b1 < a2 for (_, b1), (a2, _) in zip(on, on[1:]))
    assert compare(acc, "auto", run, ref)["accuracy_ratio"] is None  # no truth
    with pytest.raises(ValueError, match="no such profile"):
        EnergyAccounting.load("no-such-device")


# ---------------------------------------------------------------------------------------------- real recordings
def test_eval_gdin_auto_reports_energy_against_zupt(gdin_dir: Path, tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    doc = _json(capsys, ["eval", "gdin", str(gdin_dir), "--mode", "auto", "--match", "exp34", "--match", "exp17",
                         "--json", "--plot", str(tmp_path)])
    rows = {r["name"]: r for r in doc["recordings"]}
    assert rows["exp34"]["accuracy_metric"] == "stride_mean_err_m" and rows["exp17"]["accuracy_metric"] == "loop_closure_pct"
    for r in rows.values():
        assert 0.05 < r["energy_ratio"] < 1.5 and 0.0 <= r["gyro_on_fraction"] <= 1.0
        assert 0.0 < r["accuracy_ratio"] < 100.0
        zref = r["energy"]["zupt_reference"][r["accuracy_metric"]]
        assert r["accuracy_ratio"] == pytest.approx(r[r["accuracy_metric"]] / zref)
        assert r["energy"]["total_mj"] > 0 and r["energy"]["baseline_total_mj"] > 0
    for k in ("energy_ratio", "gyro_on_fraction", "accuracy_ratio"):
        s = doc["summary"][k]
        assert s["n"] == 2 and s["worst"] == max(r[k] for r in rows.values()) and s["median"] <= s["worst"]
    assert doc["power_profile"]["name"] == DEFAULT_PROFILE and doc["compute_costs"]["tables"]["auto"] == "engines.auto"
    assert (tmp_path / "energy-accuracy-gdin-auto.png").stat().st_size > 10_000
    # the plot again, from the saved document
    saved = tmp_path / "auto.json"
    saved.write_text(json.dumps(doc))
    assert main(["eval", "plot", str(saved), "--out", str(tmp_path / "again.png")]) == 0
    assert (tmp_path / "again.png").stat().st_size > 10_000


def test_eval_vicon_mode_option(vicon_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    trial = "2017-11-22-11-48-35"
    zupt = _json(capsys, ["eval", "vicon", str(vicon_dir), "--match", trial, "--json"])
    assert zupt["mode"] == "zupt" and "energy_ratio" not in zupt["trials"][0]  # the contract's form, unchanged
    assert set(zupt["summary"]) == {"mean_armse_2d_m", "median_armse_2d_m", "trials", "mean_armse_3d_m",
                                    "median_armse_3d_m"}
    pdr = _json(capsys, ["eval", "vicon", str(vicon_dir), "--match", trial, "--mode", "pdr", "--power-profile",
                         "foot-lsm9ds1", "--json"])
    r = pdr["trials"][0]
    assert pdr["mode"] == "pdr" and pdr["power_profile"]["name"] == "foot-lsm9ds1"
    assert r["accuracy_metric"] == "armse_2d_m"
    assert r["accuracy_ratio"] == pytest.approx(r["armse_2d_m"] / zupt["trials"][0]["armse_2d_m"])
    assert 0.0 < r["energy_ratio"] < 1.5 and 0.0 <= r["gyro_on_fraction"] <= 1.0
    assert main(["eval", "vicon", str(vicon_dir), "--power-profile", "foot-004"]) == 2  # zupt is the baseline
    assert main(["eval", "vicon", str(vicon_dir), "--mode", "auto", "--power-profile", "no-such-device"]) == 2


# ---------------------------------------------------------------------------------------------- eval recordings
def _write_sensorconnect(path: Path, rec: Any) -> Path:
    """``rec`` exported as a MicroStrain SensorConnect CSV (gdin format A: g, rad/s, gauss)."""
    b = rec.batch
    t = (b.acc_t_ns - b.acc_t_ns[0]) / 1e9
    gyr = np.column_stack([np.interp(b.acc_t_ns, b.gyr_t_ns, b.gyr[:, k]) for k in range(3)])
    mag = np.column_stack([np.interp(b.acc_t_ns, b.mag_t_ns, b.mag[:, k]) for k in range(3)])
    rows = np.column_stack([t, b.acc / G0, gyr, mag / 100.0, np.zeros((len(t), 3))])
    header = "Time," + ",".join(PREFIX + c for c in A_COLS)
    np.savetxt(path, rows, delimiter=",", header=header, comments="", fmt="%.9g")
    return path


def test_eval_recordings_on_a_folder_with_an_unimportable_file(walk: Any, tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / "mine"
    (folder / "day2").mkdir(parents=True)
    _write_sensorconnect(folder / "day2" / "walk.csv", walk)
    (folder / "notes.csv").write_text("shopping list\nmilk\n")
    (folder / ".hidden.csv").write_text("never looked at\n")
    assert main(["eval", "recordings", str(folder), "--json", "--plot", str(tmp_path / "png")]) == 0
    out, err = capsys.readouterr()
    doc = json.loads(out)
    rows = {r["name"]: r for r in doc["recordings"]}
    assert set(rows) == {"day2/walk.csv", "notes.csv"}
    bad = rows["notes.csv"]
    assert "no importer recognises" in bad["error"] and "Traceback" not in err
    assert [line for line in err.splitlines() if "notes.csv" in line] == [f"pednav eval recordings: skipped notes.csv: {bad['error']}"]
    r = rows["day2/walk.csv"]
    assert r["format"] == "sensorconnect-a" and r["duration_s"] == pytest.approx(70.0, abs=0.01)
    assert 0.0 < r["energy_ratio"] < 1.0  # the scheduler turned the gyroscope off for part of the walk
    assert sum(r["modes"].values()) == pytest.approx(1.0) and sum(r["behaviour"].values()) == pytest.approx(1.0)
    assert r["behaviour"]["walk"] > 0.7 and r["accuracy_ratio"] is None
    on = r["gyro_timeline"]
    assert on and all(0.0 <= a < b <= 70.0 + 1e-6 for a, b in on)
    assert sum(b - a for a, b in on) == pytest.approx(r["gyro_on_fraction"] * 70.0, abs=0.01)
    assert r["events"].get("mode_switch", 0) >= 1 and 45 <= r["strides"] <= r["stances"]
    assert doc["summary"]["recordings"] == 1 and doc["summary"]["failed"] == 1
    assert doc["summary"]["energy_ratio"]["worst"] == r["energy_ratio"]
    assert (tmp_path / "png" / "day2__walk.csv.png").stat().st_size > 10_000
    # nothing replayable: exit 1; not a folder: exit 2; no accuracy to plot: exit 1
    (tmp_path / "only_bad").mkdir()
    (tmp_path / "only_bad" / "notes.csv").write_text("shopping list\n")
    assert main(["eval", "recordings", str(tmp_path / "only_bad")]) == 1
    assert main(["eval", "recordings", str(tmp_path / "nowhere")]) == 2
    saved = tmp_path / "recordings.json"
    saved.write_text(json.dumps(doc))
    capsys.readouterr()
    assert main(["eval", "plot", str(saved), "--out", str(tmp_path / "x.png")]) == 1
    assert "no recording has both" in capsys.readouterr().err
    assert main(["eval", "plot", str(folder / "notes.csv"), "--out", str(tmp_path / "x.png")]) == 2
