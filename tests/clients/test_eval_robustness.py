"""`pednav eval` on folders as they come: recordings without truth, unrelated files, other layouts.

What the harness must do on an unseen folder: evaluate every recording it can, list the ones it cannot with
one clear line naming the file and the problem (no traceback for a bad file), and never report success for a
folder without any recording. Synthetic files where the engine's figures do not matter; real gdin files
(copied into tmp_path) where the layout does.
"""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

import numpy as np
import pytest
import scipy.io as sio

from clients.cli import main
from clients.evaluation import harness
from clients.evaluation.harness import EngineRun
from clients.recording import Recording, RecordingMeta, Truth
from models.batch import SensorBatch


def _still_vicon(path: Path, n: int = 600) -> Path:
    rng = np.random.default_rng(1)
    imu = np.column_stack([np.tile([0.0, 0.0, -9.81], (n, 1)), 0.002 * rng.standard_normal((n, 3))])
    gt = np.zeros((n, 3))
    sio.savemat(path, {"imu": imu, "ts": (np.arange(n) / 200.0)[None, :], "gt": gt})
    return path


def _run(capsys: pytest.CaptureFixture[str], argv: list[str]) -> tuple[int, dict, str]:
    code = main(argv)
    cap = capsys.readouterr()
    return code, json.loads(cap.out), cap.err


# ---------------------------------------------------------------------------------------------- harness rows
def _runner(batch: SensorBatch, mode: str, l0_m: float | None) -> EngineRun:
    t = batch.acc_t_ns
    stances = np.column_stack([t[[0, 100, 200]].astype(float), [0.0, 1.0, 2.0], [0.0] * 3, [0.0] * 3])
    pos = np.column_stack([np.minimum(np.arange(t.size) / 100.0, 2.0), np.zeros((t.size, 2))])
    return EngineRun(t, pos, np.full(t.size, "walk"), stances, 1.0, 100.0)


def _rec(extra: dict | None) -> Recording:
    n = 300
    b = SensorBatch.from_arrays(np.arange(n) / 100.0, np.tile([0.0, 0.0, -9.81], (n, 1)), np.zeros((n, 3)))
    return Recording("exp98", b, RecordingMeta("sensorconnect-a", 100.0), Truth(extra=extra) if extra else None)


def test_a_recording_without_truth_is_listed_with_its_own_figures_not_failed() -> None:
    ev = harness.evaluate_gdin_recording(_rec(None), _runner, "zupt")
    r = ev.row
    assert not ev.usable and r["gt_usable"] is False
    assert r["distance_err_pct"] is None and r["strides_truth"] is None
    assert r["strides_detected"] == 2 and r["est_path_m"] == pytest.approx(2.0)
    assert "no ground truth" in " ".join(r["notes"])
    assert harness.gdin_summary([r])["distance_err_pct"]["n"] == 0


@pytest.mark.parametrize("n_rows", [0, 1])
def test_a_stride_table_without_two_strides_skips_only_the_stride_errors(n_rows: int) -> None:
    gcp = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    x = {"exp": 98, "gcp_m": gcp, "closed_loop": False, "truth_path_length_m": 2.0, "number_of_strides": 2,
         "gcp_exist_and_correct": True, "stride_t_ns": np.array([0, 10**9], dtype=np.int64)[:n_rows]}
    r = harness.evaluate_gdin_recording(_rec(x), _runner, "zupt").row
    assert "stride_mean_err_m" not in r and r["distance_err_pct"] == pytest.approx(0.0)
    assert "no stride errors" in " ".join(r["notes"])


# ---------------------------------------------------------------------------------------------- vicon CLI
def test_eval_vicon_lists_a_bad_file_in_one_line_and_evaluates_the_rest(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    _still_vicon(tmp_path / "2099-01-01-00-00-00.mat")
    _still_vicon(tmp_path / "2099-01-01-00-00-01.MAT")  # a Windows export's upper-case extension
    sio.savemat(tmp_path / "notes.mat", {"foo": np.arange(3)})
    (tmp_path / "readme.txt").write_text("not a trial")
    with caplog.at_level(logging.ERROR):
        code, doc, _ = _run(capsys, ["eval", "vicon", str(tmp_path), "--json"])
    rows = {r["name"]: r for r in doc["trials"]}
    assert code == 1 and set(rows) == {"2099-01-01-00-00-00", "2099-01-01-00-00-01", "notes"}
    assert "imu: variable missing" in rows["notes"]["error"] and "notes.mat" in rows["notes"]["error"]
    assert doc["summary"]["trials"] == 2
    bad = [r for r in caplog.records if r.levelno >= logging.ERROR]
    assert len(bad) == 1 and bad[0].exc_info is None and "notes.mat" in bad[0].getMessage()


@pytest.mark.parametrize("dataset", ["vicon", "gdin"])
def test_eval_of_a_folder_without_recordings_is_not_a_success(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], dataset: str
) -> None:
    (tmp_path / "own").mkdir()
    (tmp_path / "own" / "notes.csv").write_text("a,b\n1,2\n")
    code, doc, err = _run(capsys, ["eval", dataset, str(tmp_path), "--json"])
    assert code == 1 and "no recording found" in err
    assert doc["trials" if dataset == "vicon" else "recordings"] == []
    # as text: the one line, not an empty table and summary after it
    code = main(["eval", dataset, str(tmp_path)])
    cap = capsys.readouterr()
    assert code == 1 and cap.out == "" and cap.err.strip().splitlines() == [
        f"pednav eval {dataset}: no recording found in {tmp_path}"]


# ---------------------------------------------------------------------------------------------- gdin CLI, real files
def _copy_exp(gdin_dir: Path, dest: Path, exp: int, truth: bool = True, stride: bool = True) -> None:
    for f in gdin_dir.glob(f"*/SensorConnectData_{exp:02d}*"):
        kind = f.parent.name
        if (f.suffix == ".mat" and kind != "llio_mat" and not truth) or (kind == "stride_gcp" and not stride):
            continue
        (dest / kind).mkdir(parents=True, exist_ok=True)
        shutil.copy(f, dest / kind / f.name)


def test_eval_gdin_on_an_unseen_layout(gdin_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                       caplog: pytest.LogCaptureFixture) -> None:
    """The folders one level deeper (the dataset repository's data/), a recording without its truth file,
    a file named like a recording that is not one, and unrelated files: exp31 is evaluated exactly as in the
    development folder."""
    root = tmp_path / "repo"
    _copy_exp(gdin_dir, root / "data", 31)
    _copy_exp(gdin_dir, root / "data", 34, truth=False, stride=False)
    (root / "data" / "own" / "SensorConnectData_99.csv").write_text("garbage,not,a,recording\n1,2,3,4\n")
    (root / "data" / "own" / ".DS_Store").write_bytes(b"\x00\x01")
    (root / "data" / "own" / "SensorConnectData_31_backup.csv").write_text("Time\n0\n")
    (root / "README.md").write_text("x")
    with caplog.at_level(logging.ERROR):
        code, doc, _ = _run(capsys, ["eval", "gdin", str(root), "--mode", "zupt", "--json"])
    rows = {r["name"]: r for r in doc["recordings"]}
    assert set(rows) == {"exp31", "exp34", "exp99"} and code == 1  # exp99 is a broken recording
    assert "no 'Time'" in rows["exp99"]["error"] and "SensorConnectData_99.csv" in rows["exp99"]["error"]
    assert rows["exp34"]["gt_usable"] is False and rows["exp34"]["distance_err_pct"] is None
    assert rows["exp34"]["strides_detected"] > 10
    assert "exp34" in doc["excluded_from_summary"] and doc["summary"]["stride_mean_err_m"]["n"] == 1
    _, ref, _ = _run(capsys, ["eval", "gdin", str(gdin_dir), "--mode", "zupt", "--match", "exp31", "--json"])
    assert rows["exp31"] == ref["recordings"][0]
    assert all(r.exc_info is None for r in caplog.records if r.levelno >= logging.ERROR)
    (root / "data" / "own" / "SensorConnectData_99.csv").unlink()
    code, doc, _ = _run(capsys, ["eval", "gdin", str(root), "--mode", "zupt", "--json", "--plot", str(tmp_path / "p")])
    assert code == 0  # a recording without truth is listed, not a failure
    assert (tmp_path / "p" / "exp31.png").exists() and not (tmp_path / "p" / "exp34.png").exists()


# ---------------------------------------------------------------------------------------------- cut-short sensor file
def _stride_table(path: Path, t_s: np.ndarray) -> Path:
    rows = ["strideIndex,timestamp,gcpX,gcpY"] + [f"{round(t * 200)},{t},{1.2 * k},0.0" for k, t in enumerate(t_s.tolist())]
    path.write_text("\n".join(rows) + "\n")
    return path


def test_a_stride_table_past_the_end_of_the_recording_is_cut_not_piled_on_the_last_sample(tmp_path: Path) -> None:
    """A sensor file that ends before its truth (logger stopped): strides after its end used to be placed on
    the last sample, silently; now they are left out, noted, and the truth is not comparable."""
    from clients.importers.gdin import find_gdin, load_gdin
    from tests.clients.test_importer_robustness import _rows, write_a

    (tmp_path / "own").mkdir()
    (tmp_path / "stride_gcp").mkdir()
    write_a(tmp_path / "own" / "SensorConnectData_88.csv", _rows(n=400))  # 2.0 s at 200 Hz
    _stride_table(tmp_path / "stride_gcp" / "SensorConnectData_88_strideIndex_timestamp_gcpX_gcpY.csv",
                  np.array([0.2, 0.9, 1.6, 2.3, 3.0, 3.7]))
    (e,) = find_gdin(tmp_path)
    x = load_gdin(e).truth.extra
    assert len(x["stride_t_ns"]) == 3 and np.all(np.diff(x["stride_t_ns"]) > 0)
    assert x["truth_covers_recording"] is False
    assert any("3 of 6 strides lie outside the recording" in n for n in x["truth_notes"])


def test_eval_gdin_on_a_sensor_file_cut_short(gdin_dir: Path, tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    _copy_exp(gdin_dir, tmp_path, 31)
    f = tmp_path / "own" / "SensorConnectData_31.csv"
    f.write_text("\n".join(f.read_text().splitlines()[:6001]) + "\n")  # the first 30 s of 42.7 s
    code, doc, _ = _run(capsys, ["eval", "gdin", str(tmp_path), "--json"])
    (r,) = doc["recordings"]
    assert code == 0 and r["gt_usable"] is False and doc["excluded_from_summary"] == ["exp31"]
    assert r["stride_mean_err_m"] < 1.0  # before: 1.98 m, the strides after 30 s all compared at the last sample
    assert any("cut short" in n for n in r["notes"])


def test_eval_vicon_skips_macos_resource_forks_and_dotfiles(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A trial folder copied from a Mac to a FAT/exFAT drive has a ._NAME.mat beside every trial: each one was
    listed as a failed trial (exit 1)."""
    _still_vicon(tmp_path / "2099-01-01-00-00-00.mat")
    (tmp_path / "._2099-01-01-00-00-00.mat").write_bytes(b"\x00\x05\x16\x07\x00\x02\x00\x00Mac OS X        " + bytes(200))
    _still_vicon(tmp_path / ".2099-01-01-00-00-01.mat")  # a dotfile: hidden, even when readable
    code, doc, _ = _run(capsys, ["eval", "vicon", str(tmp_path), "--json"])
    assert code == 0 and [r["name"] for r in doc["trials"]] == ["2099-01-01-00-00-00"]
    assert doc["summary"]["trials"] == 1


def test_eval_gaitmap_lists_no_hidden_files(tmp_path: Path) -> None:
    head = "sensor," + ",".join(["left_sensor"] * 6) + "\naxis,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z\n0,0,0,9.81,0,0,0\n"
    (tmp_path / "imu_sample.csv").write_text(head)
    (tmp_path / ".imu_sample.csv").write_text(head)
    (tmp_path / "._imu_sample.csv").write_bytes(b"\x00\x05\x16\x07\x00\x02\x00\x00Mac OS X        \xb0\xe2" + bytes(200))
    assert harness.gaitmap_recordings(tmp_path) == [(tmp_path / "imu_sample.csv", "left")]
