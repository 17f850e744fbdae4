"""``pednav replay FILE`` on recordings the engine cannot or can only partly use: a clear refusal (non-zero
exit, no traceback) or a replay that reports what the importer noted."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from clients.cli import main


def _phyphox_acc_only(path: Path, n: int = 600) -> Path:
    """phyphox's "Acceleration with g" export: one table, no gyroscope."""
    rows = ['"Time (s)","Acceleration x (m/s^2)","Acceleration y (m/s^2)","Acceleration z (m/s^2)"']
    rows += [f"{k / 100:.2f},0.1,0.2,9.80" for k in range(n)]
    path.write_text("\n".join(rows) + "\n")
    return path


def _gaitmap_with_mag(path: Path, n: int = 400) -> Path:
    rows = [",acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z,mag_x,mag_y,mag_z"]
    rows += [f"{k / 100:.2f},0,0,9.81,0,0,0,0.4,0,0.806" for k in range(n)]
    path.write_text("\n".join(rows) + "\n")
    return path


@pytest.mark.parametrize("mode", ["auto", "zupt", "pdr"])
def test_replay_of_a_recording_without_gyroscope_is_refused_not_empty(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], mode: str
) -> None:
    """Before: exit 0 with "0 positions, gyro on 100%"; the engine cannot start without a gyroscope."""
    f = _phyphox_acc_only(tmp_path / "Raw Data.csv")
    assert main(["replay", str(f), "--mode", mode]) == 1
    cap = capsys.readouterr()
    assert "Raw Data.csv" in cap.err and "no gyroscope" in cap.err and "Traceback" not in cap.err
    assert cap.out == ""


def test_replay_reports_what_the_importer_noted(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    f = _gaitmap_with_mag(tmp_path / "still.csv")
    assert main(["replay", str(f), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert any("magnetometer" in n and "left out" in n for n in doc["notes"])
    assert main(["replay", str(f)]) == 0
    assert "note: magnetometer" in capsys.readouterr().err
    assert np.isfinite(doc["gyro_on_fraction"])


def test_replay_tells_the_user_of_a_time_gap(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Before: a recording with a 5-s hole replayed without a word about it."""
    rows = [",acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z"]
    rows += [f"{k / 100 + (5.0 if k >= 300 else 0.0):.2f},0,0,9.81,0,0,0" for k in range(600)]
    f = tmp_path / "paused.csv"
    f.write_text("\n".join(rows) + "\n")
    assert main(["replay", str(f), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert any("time gap" in n and "5.01 s from t = 2.990 s" in n for n in doc["notes"])
    assert main(["replay", str(f)]) == 0
    assert "note: acc/gyr: 1 time gap(s)" in capsys.readouterr().err


def test_replay_rate_hz_replays_the_desampled_recording(capsys: pytest.CaptureFixture[str]) -> None:
    """--rate-hz 50: the engine gets the anti-aliased 50-Hz version of the 200-Hz recording, and says so."""
    from clients.commands.replay import desampled, replay_local
    from clients.synth import synthesize

    with pytest.raises(SystemExit):
        main(["replay", "--help"])
    assert "--rate-hz HZ" in capsys.readouterr().out
    assert main(["replay", "walk", "--rate-hz", "50", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert any("--rate-hz 50: de-sampled" in n and "acc 200 -> 50 Hz" in n for n in doc["notes"])
    ref = replay_local(desampled(synthesize("walk"), 50.0), 1.0)
    assert len(doc["positions"]) == len(ref["positions"]) > 10
    np.testing.assert_allclose(doc["positions"], ref["positions"], atol=1e-9)
    full = replay_local(synthesize("walk"), 1.0)
    assert doc["positions"] != full["positions"]


@pytest.mark.parametrize("rate", ["0", "-25"])
def test_replay_rate_hz_must_be_positive(capsys: pytest.CaptureFixture[str], rate: str) -> None:
    assert main(["replay", "walk", "--rate-hz", rate]) == 1
    err = capsys.readouterr().err
    assert "--rate-hz must be a positive rate" in err and "Traceback" not in err
