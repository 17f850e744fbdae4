"""``clients.evaluation.phone_duty``: a duty-cycled gyroscope's turn on synthetic rates, and the dev trials'
finding (docs/phone.md "A duty-cycled gyroscope (measured; not built)")."""

from __future__ import annotations

import math

import numpy as np
import pytest

from clients.evaluation.phone_duty import duty_yaw, gyro_energy_fraction

HZ = 100.0


def _turn(rate: float, t0: float, t1: float, t_end: float = 6.0) -> tuple[np.ndarray, np.ndarray]:
    """100-Hz samples over ``[0, t_end)`` of a rate [rad/s] that is ``rate`` on ``[t0, t1)`` and 0 elsewhere (the
    sample times shifted by 3.7 ms, so that no on-window edge falls exactly on a sample)."""
    t = np.arange(0.0, t_end, 1.0 / HZ) + 0.0037
    return t, np.where((t >= t0 - 1e-9) & (t < t1 - 1e-9), rate, 0.0)


@pytest.mark.parametrize("period,duty", [(0.25, 0.2), (0.5, 0.4), (1.0, 0.6)])
def test_scaled_estimate_of_a_constant_rate_turn_over_whole_periods(period: float, duty: float) -> None:
    """A turn at 1.5 rad/s lasting a whole number of periods is measured exactly by the on-parts over ``d``,
    wherever the on-windows fall (the interval spans whole periods)."""
    rate = 1.5
    for k in range(8):
        off = k * period / 8
        t, w = _turn(rate, 1.0 + off, 1.0 + off + 4 * period)
        y = duty_yaw(t, w, period, duty, off, "scaled")
        assert y[-1] == pytest.approx(rate * 4 * period, rel=1e-6)


@pytest.mark.parametrize("period,duty", [(0.25, 0.2), (0.5, 0.3), (1.0, 0.5)])
def test_interp_estimate_of_a_constant_rate_is_exact_inside(period: float, duty: float) -> None:
    """Inside a constant-rate stretch the gaps are filled with the adjacent windows' equal means: the estimated
    turn over any interval well inside it (a window on either side) is the true one, at any offset."""
    rate = -0.8
    t, w = _turn(rate, 0.0, 6.0)
    for k in range(8):
        y = duty_yaw(t, w, period, duty, k * period / 8, "interp")
        a, b = np.searchsorted(t, [1.3, 4.1])
        assert y[b] - y[a] == pytest.approx(rate * (t[b] - t[a]), rel=1e-9)


def test_scaled_estimate_is_unbiased_over_offsets_and_wrong_for_one() -> None:
    """A short turn (0.3 s) against a 1-s period with d = 0.2: one offset sees none of it, another sees it whole
    and counts it as a whole period at its rate (3.3 times it); the mean over offsets is the turn."""
    t, w = _turn(2.0, 2.0, 2.3)
    est = [duty_yaw(t, w, 1.0, 0.2, k / 20, "scaled")[-1] for k in range(20)]
    assert min(est) == pytest.approx(0.0, abs=1e-9)
    assert max(est) == pytest.approx(2.0 * 1.0, rel=0.05)  # an on-window inside the turn: its rate over a period
    assert np.mean(est) == pytest.approx(0.6, rel=0.05)


def test_energy_fraction() -> None:
    """``(d P + t_on) / P``, at most 1; always-on is 1."""
    assert gyro_energy_fraction(0.5, 0.4, 0.08) == pytest.approx(0.56)
    assert gyro_energy_fraction(0.25, 0.2, 0.002) == pytest.approx(0.208)
    assert gyro_energy_fraction(0.25, 0.9, 0.08) == 1.0
    assert gyro_energy_fraction(1.0, 1.0, 0.08) == 1.0


def test_duty_cycled_turn_beats_the_compass_on_the_dev_trials(ipin_dir) -> None:  # type: ignore[no-untyped-def]
    """The finding: at P = 0.5 s, d = 0.3 (gyroscope energy 0.46 with an 80-ms power-up) the duty-cycled turn errs
    per turn by about half the compass's error across the same turns (below 0.6 of it averaged over the on-window
    offsets, below 0.75 at the worst offset); with P = 1 s it errs by more than the compass (the walkers' turns
    last about a second)."""
    from clients.evaluation.phone_duty import duty_statistics, duty_trial
    from clients.importers import load

    trials = [duty_trial(load(f)) for f in sorted(ipin_dir.glob("*.txt"))]
    st = duty_statistics(trials, 0.5, 0.3, "interp")
    assert st["turns"] >= 40 and st["swing_turns"] >= 80
    assert st["turn_rms_deg_worst"] < 0.75 * st["compass_turn_rms_deg"]
    assert st["turn_rms_deg"] < 0.6 * st["compass_turn_rms_deg"]
    slow = duty_statistics(trials, 1.0, 0.3, "interp")
    assert slow["turn_rms_deg"] > st["compass_turn_rms_deg"]
    assert not math.isnan(st["window_rms_deg"])


@pytest.mark.parametrize("module", ["phone_duty", "phone_swing", "phone_centripetal", "phone_heading", "phone_step_length"])
def test_diagnosis_scripts_refuse_a_folder_without_logfiles_in_one_line(module: str, tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    """The phone diagnosis scripts (``python -m clients.evaluation.phone_*``): an empty folder or a ``.txt`` that is not
    a GetSensorData logfile ends with one ``error:`` line and exit code 2, never a traceback."""
    import importlib

    main = importlib.import_module(f"clients.evaluation.{module}").main
    assert main([str(tmp_path)]) == 2
    assert capsys.readouterr().out.startswith("error: no GetSensorData logfiles")
    (tmp_path / "notes.txt").write_text("% time seconds\n1 2\n")
    assert main([str(tmp_path)]) == 2
    out = capsys.readouterr().out
    assert out.startswith("error: ") and "notes.txt" in out and out.count("\n") == 1
