"""Leave-one-group-out behaviour evaluation: the fitted constant, the groups, and the lag-only bound (the oracle)
on gdin's pace changes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clients.evaluation.behaviour import LabelRange, score
from clients.evaluation.behaviour_fit import (
    fit_stand_enter,
    group_of,
    leave_one_group_out,
    oracle_decisions,
    oracle_shares,
    quiet_in_gait,
    quiet_stretches,
    recent_stance,
)


def test_groups_are_recordings_and_gaitmaps_two_feet_are_one() -> None:
    assert group_of("gaitmap", "imu_sample-left") == group_of("gaitmap", "imu_sample-right") == "gaitmap/imu_sample"
    assert group_of("vicon", "2017-11-22-11-22-03") != group_of("vicon", "2017-11-22-11-22-46")
    assert group_of("gdin", "exp34") == "gdin/exp34"


def test_stand_enter_lies_above_the_longest_quiet_stretch_of_the_training_groups() -> None:
    assert fit_stand_enter([np.array([0.2, 0.93]), np.array([0.5])]) == pytest.approx(1.0)
    assert fit_stand_enter([np.array([1.23])]) == pytest.approx(1.3)
    assert fit_stand_enter([np.array([1.3])]) == pytest.approx(1.4)  # strictly above
    assert fit_stand_enter([np.zeros(0), np.array([0.4])]) == pytest.approx(1.0)  # never below MAX_STANCE_S


def test_quiet_stretches_count_only_inside_gait_time() -> None:
    t = np.arange(0.0, 10.0, 0.01)
    acc = np.zeros((t.size, 3))
    acc[:, 2] = 9.80665 + 5.0 * np.sin(2 * np.pi * t)  # loud except near the zero crossings
    acc[(t > 2.0) & (t < 2.6), 2] = 9.80665  # one 0.6-s quiet stretch in the walk
    acc[(t > 8.0), 2] = 9.80665  # a stand at the end
    ranges = [LabelRange("x", "r", 0.0, 5.0, "walk"), LabelRange("x", "r", 5.0, 10.0, "stand")]
    q = quiet_in_gait(t, acc, ranges)
    # the 0.6-s stretch with the sine's quiet edges either side (0.64 s); the stand's 2 s and the walk/stand boundary
    # are not gait
    assert q.max() == pytest.approx(0.64, abs=0.015)
    assert np.sort(q)[-2] < 0.1


def test_recent_stance_is_the_longest_stance_ended_in_the_window_before() -> None:
    # a walk whose foot is quiet for 0.4 s every 1.0-s stride, one 0.7-s stance at 5 s, then a stop at 8 s
    t = np.arange(0.0, 12.0, 0.01)
    acc = np.zeros((t.size, 3))
    acc[:, 2] = 9.80665 + 5.0
    quiet = ((t % 1.0) < 0.4) | ((t >= 5.0) & (t < 5.7)) | (t >= 8.0)
    acc[quiet, 2] = 9.80665
    t0, t1 = quiet_stretches(t, acc)
    d = t1 - t0
    assert np.isinf(t1[-1]) and t0[-1] == pytest.approx(7.99)  # the stop runs to the end of the recording
    rec = recent_stance(t0, t1)
    i = int(np.argmin(np.abs(t0 - 4.99)))
    assert d[i] == pytest.approx(0.71, abs=0.011)
    assert rec[i] == pytest.approx(0.41, abs=0.011)  # the 0.4-s stances of the 3 s before, not itself
    assert np.isnan(rec[0])  # no stances before the first one
    j = int(np.argmin(np.abs(t0 - 6.99)))
    assert rec[j] == pytest.approx(0.71, abs=0.011)  # the long stance is still in the 3-s history
    assert np.isnan(recent_stance(t0, t1, min_n=50)).all()


def test_the_oracle_loses_the_first_stride_of_every_pace_and_nothing_else() -> None:
    # toe-offs every second from 2 s; strides 1-4 walk (1.2 m/s), 5-8 run (3 m/s), 9-12 walk
    s = 2.0 + np.arange(13.0)
    speed = np.array([1.2] * 4 + [3.0] * 4 + [1.2] * 4)
    ranges = [LabelRange("x", "r", 0.0, 2.0, "stand"), LabelRange("x", "r", 2.0, 3.0, "ignore"),
              LabelRange("x", "r", 3.0, 6.0, "walk"), LabelRange("x", "r", 6.0, 10.0, "run"),
              LabelRange("x", "r", 10.0, 14.0, "walk")]
    got = score(oracle_decisions(s, speed, 14.0), ranges)
    # 11 s of walk/run labelled; the first stride of the run (6-7 s) and of the second walk (10-11 s) held the
    # pace before, less the decision grid's 0.25 s
    assert got["walk_run_share"] == pytest.approx(9.0 / 11.0, abs=0.03)
    assert got["walk_run_share"] < 0.85


@pytest.mark.slow
def test_lag_alone_caps_the_pace_changing_gdin_walks(gdin_dir: Path) -> None:
    """Measured 2026-12-04 (clients.evaluation.behaviour_fit.oracle_shares): a recogniser that knows each stride's
    pace once the stride is over reaches a walk/run share of 0.900 on exp34, 0.895 on exp35, 0.993 on exp43 and
    1.000 on the seven gdin walks that keep their pace. The recogniser itself: 0.34, 0.61, 0.76 (docs/behaviour.md);
    lag is not what holds exp34 down."""
    shares = oracle_shares(gdin_dir.parent)
    assert len(shares) >= 10
    assert shares["exp34"] == pytest.approx(0.900, abs=0.01)
    assert shares["exp35"] == pytest.approx(0.895, abs=0.01)
    assert shares["exp43"] == pytest.approx(0.993, abs=0.01)
    assert min(v for k, v in shares.items() if k not in ("exp34", "exp35", "exp43")) >= 0.99


@pytest.mark.slow
def test_held_out_stand_entry_constant(vicon_dir: Path, gdin_dir: Path, gaitmap_dir: Path) -> None:
    """Measured 2026-12-04: fitted without the held-out group, ``STAND_ENTER_S`` is the module's 1.0 s for all 53
    groups at the recorded rate (longest quiet stretch in gait 0.94 s), so the held-out figures are
    ``pednav eval behaviour``'s (walk/run share 0.926, stand entered 1.19 s, left 0.99 s); at 25 Hz two in-place
    foot-lift trials hold 1.08-1.12 s quiet stretches, the fit is 1.1-1.2 s and stand is entered after 1.35 s
    (1.14 s with the module's 1.0 s) with one boundary missed."""
    assert vicon_dir.parent == gdin_dir.parent == gaitmap_dir.parent
    doc = leave_one_group_out(vicon_dir.parent, (None, 25.0))
    assert doc["groups"] == 53
    rec, low = doc["rates"]["recorded"], doc["rates"]["25"]
    assert {r["stand_enter_s"] for r in rec["recordings"]} == {1.0}
    assert rec["summary"]["walk_run_share_mean"] == pytest.approx(0.926, abs=0.005)
    assert rec["summary"]["stand_entered_median_abs_s"] == pytest.approx(1.19, abs=0.05)
    assert max(low["longest_quiet_in_gait_s"].values()) > 1.05
    assert low["summary"]["stand_entered_median_abs_s"] > 1.2
