from __future__ import annotations

import numpy as np
import pytest

from models.detectors import adaptive_threshold, multi_condition_detector, shoe_detector, shoe_statistic


def gait(rate=200.0, stride_s=1.0, stance_frac=0.4, peak_rate=6.0, peak_acc=15.0, n_strides=6, seed=0):
    """Synthetic foot signal: rest (|a| = g, tiny noise) during stance, strong rotation/acceleration in swing."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, n_strides * stride_s, 1 / rate)
    ph = (t % stride_s) / stride_s
    swing = ph >= stance_frac
    s = np.where(swing, np.sin(np.pi * (ph - stance_frac) / (1 - stance_frac)), 0.0)
    acc = np.zeros((t.size, 3))
    acc[:, 2] = -9.8
    acc[:, 0] = peak_acc * s * np.cos(7 * ph)
    acc += rng.normal(0, 0.02, acc.shape)
    gyr = np.zeros((t.size, 3))
    gyr[:, 1] = peak_rate * s
    gyr += rng.normal(0, 0.005, gyr.shape)
    return t, acc, gyr, ~swing


@pytest.mark.parametrize("stance_frac", [0.3, 0.5, 0.6])
def test_shoe_finds_stance(stance_frac):
    t, acc, gyr, stance = gait(stance_frac=stance_frac)
    zv = shoe_detector(acc, gyr, threshold=3e5)
    # interior of every stance is detected; swing core never is
    core_stance = stance & np.roll(stance, 5) & np.roll(stance, -5)
    core_swing = ~stance & np.roll(~stance, 10) & np.roll(~stance, -10)
    assert zv[core_stance].mean() > 0.98
    assert not zv[core_swing].any()


def test_shoe_statistic_grows_with_motion():
    _, acc, gyr, stance = gait()
    T = shoe_statistic(acc, gyr)
    assert np.median(T[~stance]) > 100 * np.median(T[stance])


@pytest.mark.parametrize("peak_rate", [3.0, 12.0])
def test_multi_condition_detects_stance(peak_rate):
    _, acc, gyr, stance = gait(peak_rate=peak_rate)
    zv = multi_condition_detector(acc, gyr)
    core_swing = ~stance & np.roll(~stance, 20) & np.roll(~stance, -20)
    core_stance = stance & np.roll(stance, 20) & np.roll(stance, -20)
    assert zv[core_stance].mean() > 0.95
    assert not zv[core_swing].any()


def test_adaptive_threshold_rises_for_running():
    tw, aw, gw, _ = gait(peak_rate=4.0, peak_acc=10.0)
    tr, ar, gr, _ = gait(peak_rate=15.0, peak_acc=60.0, stride_s=0.7)
    kw = dict(gamma0=6e4, gamma_exp=2.5, tau_s=1.5, intensity_ref=30.0, gamma_min=1e3, gamma_max=1e10)
    walk = adaptive_threshold(np.linalg.norm(aw, axis=1), tw, **kw)
    run = adaptive_threshold(np.linalg.norm(ar, axis=1), tr, **kw)
    assert np.median(run[200:]) > 10 * np.median(walk[200:])
    # exponent 0 gives the fixed threshold of 002 eq. (3)
    fixed = adaptive_threshold(np.linalg.norm(aw, axis=1), tw, **{**kw, "gamma_exp": 0.0})
    assert np.all(fixed == 6e4)


def test_kernel_statistic_matches_reference():
    from models.zupt_nav import ZuptNavigator

    t, acc, gyr, _ = gait()
    out = ZuptNavigator().run(t, acc, gyr)
    # half_window_s = 0.011 s at 200 Hz is +-2 samples, as the reference's half_window=2
    np.testing.assert_allclose(out.statistic, shoe_statistic(acc, gyr, half_window=2), rtol=1e-9)


def test_bad_input_named():
    with pytest.raises(ValueError, match="NaN or inf"):
        shoe_statistic(np.full((10, 3), np.nan), np.zeros((10, 3)))
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        shoe_statistic(np.zeros((10, 2)), np.zeros((10, 2)))


def test_first_still_run_finds_the_first_long_enough_stretch() -> None:
    from models.detectors import first_still_run

    t = np.arange(20) * 0.01
    acc = np.tile([0.0, 0.0, 9.81], (20, 1))
    gyr = np.zeros((20, 3))
    gyr[:5, 0] = 3.0  # swing
    gyr[8, 0] = 3.0  # a short still moment (5..7) before it
    assert first_still_run(t, acc, gyr, 0.04, 1.0, 1.5) == (9, 13)
    # too short anywhere: the still run reaching the end is reported for the caller to keep
    assert first_still_run(t[:12], acc[:12], gyr[:12], 0.04, 1.0, 1.5) == (9, -1)
    gyr[-1, 0] = 3.0
    assert first_still_run(t[:12], acc[:12], np.vstack([gyr[:11], [[3.0, 0, 0]]]), 0.04, 1.0, 1.5) == (12, -1)
    assert first_still_run(t[:0], acc[:0], gyr[:0], 0.04, 1.0, 1.5) == (0, -1)
