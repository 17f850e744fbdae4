"""Evaluation harness with a scripted engine (known answers) and CLI smoke runs on a few real recordings."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from clients.cli import main
from clients.evaluation import harness
from clients.evaluation.harness import EngineRun
from clients.recording import Recording, RecordingMeta, Truth
from models.batch import SensorBatch

RATE = 100.0


def _rot(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def _batch(n: int) -> SensorBatch:
    t = np.arange(n) / RATE
    return SensorBatch.from_arrays(t, np.tile([0.0, 0.0, -9.81], (n, 1)), np.zeros((n, 3)))


def _gdin_recording(closed: bool) -> tuple[Recording, np.ndarray]:
    """A square walk of 8 strides (closed) or an L (open), one stride per second; returns (rec, gcp)."""
    side = [[1.0, 0.0]] * 2 + [[0.0, 1.0]] * 2 + ([[-1.0, 0.0]] * 2 + [[0.0, -1.0]] * 2 if closed else [[1.0, 0.0]] * 4)
    gcp = np.vstack([[0.0, 0.0], np.cumsum(np.array(side) * 1.5, axis=0)])
    n = int((len(gcp) + 1) * RATE)
    batch = _batch(n)
    stride_t = batch.acc_t_ns[(np.arange(len(gcp)) + 0.5).astype(int) * int(RATE)]
    extra = {
        "exp": 99,
        "gcp_m": gcp,
        "gcp_stride_numbers": np.arange(len(gcp)),
        "gcp_exist_and_correct": True,
        "number_of_strides": len(gcp) - 1,
        "closed_loop": closed,
        "truth_path_length_m": float(np.sum(np.linalg.norm(np.diff(gcp, axis=0), axis=1))),
        "stride_t_ns": stride_t,
    }
    rec = Recording("exp99", batch, RecordingMeta("synthetic", RATE), Truth(extra=extra))
    return rec, gcp


def _perfect_gdin_runner(rec: Recording, gcp: np.ndarray, theta: float, scale: float = 1.0):
    """An engine that reports the mirrored, rotated, shifted footprints: at stance k = footprint k."""
    ned = (gcp * np.array([1.0, -1.0]) * scale) @ _rot(theta).T + np.array([5.0, -3.0])
    t = rec.batch.acc_t_ns
    k = np.clip(np.searchsorted(rec.truth.extra["stride_t_ns"], t, side="right") - 1, 0, len(gcp) - 1)
    pos = np.column_stack([ned[k], np.zeros(t.size)])
    stances = np.column_stack([rec.truth.extra["stride_t_ns"], ned, np.zeros(len(gcp))])

    def run(batch: SensorBatch, mode: str, l0_m: float | None) -> EngineRun:
        assert mode == "zupt" and l0_m is None
        return EngineRun(t, pos, np.full(t.size, "walk"), stances, 1.0, RATE)

    return run


@pytest.mark.parametrize("theta", [0.0, 0.8, -2.5])
def test_gdin_metrics_zero_for_a_perfect_engine(theta: float) -> None:
    rec, gcp = _gdin_recording(closed=True)
    ev = harness.evaluate_gdin_recording(rec, _perfect_gdin_runner(rec, gcp, theta), "zupt")
    r = ev.row
    assert r["loop_closure_pct"] == pytest.approx(0.0, abs=1e-9)
    assert r["stride_mean_err_m"] == pytest.approx(0.0, abs=1e-9)
    assert r["stride_rmse_m"] == pytest.approx(0.0, abs=1e-9)
    assert r["distance_err_pct"] == pytest.approx(0.0, abs=1e-9)
    assert r["strides_detected"] == r["strides_truth"] == len(gcp) - 1
    assert r["gyro_on_fraction"] == 1.0 and r["mean_rate_hz"] == RATE


def test_gdin_metrics_scale_error_and_open_loop() -> None:
    rec, gcp = _gdin_recording(closed=False)
    ev = harness.evaluate_gdin_recording(rec, _perfect_gdin_runner(rec, gcp, 0.3, scale=1.1), "zupt")
    assert "loop_closure_pct" not in ev.row  # open path: no loop-closure truth
    assert ev.row["distance_err_pct"] == pytest.approx(10.0)
    assert ev.row["stride_mean_err_m"] > 0.0


def test_gdin_summary_leaves_out_flagged_ground_truth() -> None:
    rows = [
        {"name": "a", "distance_err_pct": 1.0, "gt_usable": True},
        {"name": "b", "distance_err_pct": 3.0, "gt_usable": True},
        {"name": "c", "distance_err_pct": 99.0, "gt_usable": False},
    ]
    s = harness.gdin_summary(rows)
    assert s["distance_err_pct"] == {"mean": 2.0, "median": 2.0, "n": 2}
    assert s["loop_closure_pct"]["n"] == 0


def test_vicon_armse_zero_for_a_perfect_engine() -> None:
    n = 800
    batch = _batch(n)
    s = np.linspace(0.0, 6.0, n)
    truth = np.column_stack([s, np.sin(s), 0.1 + 0.05 * np.abs(np.sin(9 * s))])  # z up
    rec = Recording("trial", batch, RecordingMeta("synthetic", RATE), Truth(t_ns=batch.acc_t_ns, positions=truth))
    ned = truth.copy()
    ned[:, :2] = truth[:, :2] @ _rot(1.2).T
    ned[:, 2] = -truth[:, 2]  # NED: down
    labels = np.array(["stand"] * 200 + ["walk"] * 500 + ["run"] * 50 + ["limp"] * 50)

    def run(b: SensorBatch, mode: str, l0_m: float | None) -> EngineRun:
        return EngineRun(b.acc_t_ns, ned, labels, np.zeros((0, 4)), 1.0, RATE)

    r = harness.evaluate_vicon_recording(rec, run).row
    assert r["armse_2d_m"] == 0.0 and r["armse_3d_m"] == 0.0 and r["samples"] == n
    assert r["behaviour"] == pytest.approx({"stand": 0.25, "walk": 0.625, "run": 0.0625, "other": 0.0625})


# ---------------------------------------------------------------------------------------------- returning users
def test_leave_one_out_chains_are_the_other_members_of_the_group_in_order() -> None:
    chains = harness.leave_one_out_chains({"a": ["e1", "e2", "e3"], "c": ["e7"]})
    assert chains == {"e1": ("e2", "e3"), "e2": ("e1", "e3"), "e3": ("e1", "e2"), "e7": ()}


def _recording_session(data: dict[str, str], calls: list[tuple[str, tuple[str, ...]]]):
    """A session whose profile is the list of (recording, data) it has seen, walked in order."""

    def session(name: str, profile: dict | None) -> tuple[dict, list]:
        seen = tuple((profile or {}).get("seen", ()))
        calls.append((name, tuple(n for n, _ in seen)))
        return {"seen": seen + ((name, data[name]),)}, [("calibration_done", {"behaviour": "walk"})]

    return session


def test_profile_chain_never_feeds_a_recording_into_its_own_profile() -> None:
    names = [f"e{i}" for i in range(6)]
    groups = {"a": names[:4], "b": names[4:]}
    data = {n: f"samples of {n}" for n in names}
    calls: list[tuple[str, tuple[str, ...]]] = []
    chain = harness.ProfileChain(_recording_session(data, calls))
    chains = harness.leave_one_out_chains(groups)
    got = {n: chain.after(chains[n]) for n in names}
    for n, (profile, sessions) in got.items():
        seen = [m for m, _ in profile["seen"]] if profile else []
        assert n not in seen and n not in [s.name for s in sessions]
        group = next(g for g in groups.values() if n in g)
        assert seen == [m for m in group if m != n]  # every other member, in group order, each session once
        info = harness.profile_info(profile, sessions, [])
        assert info["fed_by"] == seen and info["calibrated_in"] == ({"walk": seen[-1]} if seen else {})
    # prefixes are shared: e0 (e1 e2 e3) 3, e1 (e0 e2 e3) 3, e2 (e0 e1 | e3) 2, e3 (e0 e1 | e2) 1, e4 1, e5 1
    assert chain.sessions_run == len(calls) == 11
    # no data of a recording reaches its own profile: change e1's samples, e1's profile is the same,
    # the profiles built from e1 change
    data2 = dict(data, e1="other samples")
    chain2 = harness.ProfileChain(_recording_session(data2, []))
    assert chain2.after(chains["e1"])[0] == got["e1"][0]
    assert chain2.after(chains["e0"])[0] != got["e0"][0]


def test_profile_chain_seed_and_failed_session() -> None:
    def session(name: str, profile: dict | None) -> tuple[dict, list]:
        if name == "bad":
            raise RuntimeError("broken file")
        return {"n": (profile or {}).get("n", 0) + 1}, []

    chain = harness.ProfileChain(session)
    chain.seed("x", {"n": 100}, [("examination_failed", {}), ("calibration_done", {"behaviour": "run"})])
    profile, sessions = chain.after(("x", "bad", "y"))
    assert profile == {"n": 101} and chain.sessions_run == 1  # x seeded, bad skipped, y run
    assert [s.name for s in sessions] == ["x", "bad", "y"] and sessions[1].error is not None
    assert sessions[0].calibrated == ("run",) and sessions[0].events["examination_failed"] == 1


def _dump(profile: dict | None) -> str:
    return json.dumps(profile, sort_keys=True, default=lambda o: np.asarray(o).tolist())


def test_leave_one_out_with_the_engine_on_synthetic_walks() -> None:
    """The real engine: a recording's profile does not change when its own samples do (pdr mode)."""
    from clients.synth import Scenario, Segment, synthesize

    scn = Scenario("loo", (Segment("stand", 3.0), Segment("walk", 45.0, 90.0), Segment("stand", 3.0)))
    batches = {f"s{k}": synthesize(scn, seed=k).batch for k in range(3)}

    def chain_for(b: dict[str, SensorBatch]) -> harness.ProfileChain:
        def session(name: str, profile: dict | None) -> tuple[dict | None, tuple]:
            run = harness.run_engine(b[name], mode="pdr", profile=profile)
            return run.profile, run.events

        return harness.ProfileChain(session)

    chains = harness.leave_one_out_chains({"synth": list(batches)})
    p0, sessions = chain_for(batches).after(chains["s0"])
    assert [s.name for s in sessions] == ["s1", "s2"]
    assert p0 is not None and p0["behaviours"]["walk"]["calibrated"]
    assert harness.profile_info(p0, sessions, [])["behaviours"]["walk"]["n_steps"] > 0
    swapped = dict(batches, s0=synthesize(scn, seed=7).batch)
    chain2 = chain_for(swapped)
    assert _dump(chain2.after(chains["s0"])[0]) == _dump(p0)
    assert _dump(chain2.after(chains["s1"])[0]) != _dump(chain_for(batches).after(chains["s1"])[0])
    run = harness.run_engine(batches["s0"], mode="pdr", profile=p0)  # the engine takes it and hands one out
    assert run.profile is not None and "walk" in run.profile["behaviours"]


def test_positions_at_is_sample_and_hold() -> None:
    t = np.array([10, 20, 30], dtype=np.int64)
    p = np.arange(9, dtype=float).reshape(3, 3)
    got = harness.positions_at(t, p, np.array([5, 10, 25, 31]))
    np.testing.assert_array_equal(got, p[[0, 0, 1, 2]])


# ---------------------------------------------------------------------------------------------- CLI, real data
def _run_json(capsys: pytest.CaptureFixture[str], argv: list[str]) -> dict:
    code = main(argv)
    out = capsys.readouterr().out
    assert code == 0, out
    return json.loads(out)


def test_cli_eval_vicon_smoke(vicon_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    doc = _run_json(capsys, ["eval", "vicon", str(vicon_dir), "--limit", "2", "--json", "--plot", str(tmp_path)])
    assert len(doc["trials"]) == 2
    for t in doc["trials"]:
        assert {"name", "armse_2d_m", "armse_3d_m", "samples", "behaviour"} <= set(t)
        assert set(t["behaviour"]) == {"stand", "walk", "run", "other"}
        assert sum(t["behaviour"].values()) == pytest.approx(1.0)
        assert (tmp_path / f"{t['name']}.png").stat().st_size > 1000
    assert {"mean_armse_2d_m", "median_armse_2d_m", "trials"} <= set(doc["summary"])
    assert doc["summary"]["trials"] == 2


def test_cli_eval_gdin_smoke(gdin_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["eval", "gdin", str(gdin_dir), "--mode", "zupt", "--json", "--plot", str(tmp_path)]
    for name in ("exp17", "exp31", "exp42", "exp13"):  # closed loop, per-stride, 250 Hz format B, flagged GT
        argv += ["--match", name]
    doc = _run_json(capsys, argv)
    rows = {r["name"]: r for r in doc["recordings"]}
    assert set(rows) == {"exp13", "exp17", "exp31", "exp42"}
    base = {"name", "distance_err_pct", "strides_detected", "strides_truth", "gyro_on_fraction", "mean_rate_hz"}
    for r in rows.values():
        assert base <= set(r)
        assert (tmp_path / f"{r['name']}.png").exists()
    assert "loop_closure_pct" in rows["exp17"] and "stride_mean_err_m" not in rows["exp17"]
    assert {"stride_mean_err_m", "stride_rmse_m"} <= set(rows["exp31"]) and "loop_closure_pct" not in rows["exp31"]
    assert rows["exp42"]["mean_rate_hz"] == pytest.approx(250.0, rel=0.02)
    assert doc["excluded_from_summary"] == ["exp13"]
    for key in ("loop_closure_pct", "stride_mean_err_m", "stride_rmse_m", "distance_err_pct"):
        assert set(doc["summary"][key]) == {"mean", "median", "n"}
    assert doc["summary"]["distance_err_pct"]["n"] == 3
    assert doc["summary"]["loop_closure_pct"]["n"] == 1


def test_cli_eval_gdin_table_and_l0_rule(gdin_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["eval", "gdin", str(gdin_dir), "--mode", "zupt", "--match", "exp34"]) == 0
    out = capsys.readouterr().out
    assert "exp34" in out and "summary" in out
    assert main(["eval", "gdin", str(gdin_dir), "--mode", "zupt", "--l0", "10"]) == 2
    assert main(["eval", "gdin", str(gdin_dir), "--mode", "zupt", "--conventional"]) == 2
    assert main(["eval", "gdin", str(gdin_dir), "--mode", "zupt", "--profile", "leave-one-out"]) == 2


def test_cli_eval_gdin_leave_one_out(gdin_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    picks = ("exp17", "exp34", "exp35", "exp37", "exp41", "exp42")  # A x3, C x2 (no magnetometer), B x1
    argv = ["eval", "gdin", str(gdin_dir), "--mode", "pdr", "--json"]
    for name in picks:
        argv += ["--match", name]
    new = _run_json(capsys, argv)
    doc = _run_json(capsys, argv + ["--profile", "leave-one-out"])
    assert doc["profile"] == "leave-one-out" and "profile" not in new  # the default document is unchanged
    assert doc["profile_groups"] == {"sensorconnect-a": ["exp17", "exp34", "exp35"],
                                     "gdin-llio-mat": ["exp37", "exp41"], "sensorconnect-b": ["exp42"]}
    assert doc["new_user_summary"] == new["summary"]  # same build, same engine: the new-user figures
    new_rows = {r["name"]: r for r in new["recordings"]}
    base = {"name", "distance_err_pct", "strides_detected", "strides_truth", "gyro_on_fraction", "mean_rate_hz"}
    for r in doc["recordings"]:
        assert base <= set(r)
        pr = r["profile"]
        group = next(g for g in doc["profile_groups"].values() if r["name"] in g)
        assert pr["fed_by"] == [n for n in group if n != r["name"]]  # never itself
        assert r["name"] not in pr["calibrated_in"].values()
        assert set(pr["events"]) >= {"calibration_done", "examination_passed", "examination_failed"}
        for k, v in r["new_user"].items():
            if k != "events":
                assert v == new_rows[r["name"]][k]
    rows = {r["name"]: r for r in doc["recordings"]}
    assert rows["exp42"]["profile"]["fed_by"] == [] and rows["exp42"]["profile"]["behaviours"] == {}
    # a lone recording is a new user: same figures
    assert rows["exp42"]["distance_err_pct"] == new_rows["exp42"]["distance_err_pct"]
    for r in rows.values():
        assert set(r["profile"]["calibrated_in"].values()) <= set(r["profile"]["fed_by"])
    assert any(r["profile"]["behaviours"] for r in rows.values())  # some session calibrated something


def test_cli_eval_gaitmap_strides_against_motion_capture_and_stairs(gaitmap_dir: Path, tmp_path: Path,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """Both feet of the walk against the heel marker, and the flight of stairs both ways (measured 2026-12-02:
    stride length MAE 0.044 / 0.056 m, climb 4.24 / 4.46 m up and 4.57 / 4.10 m down; before the ZUPT-KF's
    mid-swing rule the ascent read 1.4 m)."""
    doc = _run_json(capsys, ["eval", "gaitmap", str(gaitmap_dir), "--json", "--plot", str(tmp_path)])
    rows = {r["name"]: r for r in doc["recordings"]}
    assert len(rows) == 6 and doc["summary"]["stride_length_mean_abs_err_m"]["n"] == 2
    for foot in ("left", "right"):
        walk = rows[f"imu_sample-{foot}"]
        assert walk["strides_compared"] >= 25
        assert walk["stride_length_mean_abs_err_m"] < 0.1 and walk["distance_err_pct"] < 5.0, walk
        up, down = rows[f"imu_sample_healthy_stair_up-{foot}"], rows[f"imu_sample_healthy_stair_down-{foot}"]
        assert not up["truth"] and up["climb_m"] > 3.5 and down["climb_m"] < -3.5, (up, down)
        assert (tmp_path / f"imu_sample-{foot}.png").stat().st_size > 1000


@pytest.mark.parametrize(("command", "dataset"), [("vicon", "vicon"), ("gdin", "gdin"), ("gaitmap", "gaitmap-mocap"),
                                                  ("ipin", "ipin2023-t3-phone")])
def test_a_missing_data_folder_is_one_line_and_exit_2(command: str, dataset: str, tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    """Without the data (no PEDNAV_DATA, or --dir not a folder) each dataset command says so in one line."""
    monkeypatch.setenv("PEDNAV_DATA", str(tmp_path / "absent"))
    assert main(["eval", command]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"pednav eval {command}: data folder not found (PEDNAV_DATA/{dataset})"]
    assert main(["eval", command, str(tmp_path / "nope")]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [f"pednav eval {command}: data folder not found ({tmp_path / 'nope'})"]


def test_ipin_logfiles_without_heading_sensors_are_one_line(ipin_dir: Path, tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    """Logfiles with the accelerometer only (no GYRO, no MAGN lines): no heading, so no steps are placed and the
    step constant cannot be fitted: one line saying so, exit 1, no traceback."""
    for trial in ("Trial27_repetition01", "Trial23_repetition01"):
        name = f"IPIN2023_T3_Training{trial}.txt"
        lines = (ipin_dir / name).read_text(errors="replace").splitlines(keepends=True)
        (tmp_path / name).write_text("".join(x for x in lines if not x.startswith(("GYRO", "MAGN"))))
    assert main(["eval", "ipin", str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("pednav eval ipin: IPIN2023_T3_Training") and "no heading" in err[0], err
