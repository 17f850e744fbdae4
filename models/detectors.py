"""Zero-velocity (stance) detectors on whole arrays: SHOE/GLRT, multi-condition, adaptive threshold.

The streaming navigator evaluates the same SHOE statistic and adaptive threshold inside its compiled kernel
(time-based centred window, chunk-invariant); these vectorised versions are the reference used for analysis,
tests and offline tools.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import median_filter

__all__ = ["shoe_statistic", "shoe_detector", "adaptive_threshold", "multi_condition_detector", "first_still_run"]


def _check(acc: np.ndarray, gyr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    acc = np.asarray(acc, dtype=np.float64)
    gyr = np.asarray(gyr, dtype=np.float64)
    if acc.ndim != 2 or acc.shape[1] != 3 or gyr.shape != acc.shape:
        raise ValueError(f"acc/gyr: expected two (N, 3) arrays, got {acc.shape} and {gyr.shape}")
    if not (np.all(np.isfinite(acc)) and np.all(np.isfinite(gyr))):
        raise ValueError("acc/gyr: contain NaN or inf")
    return acc, gyr


def shoe_statistic(
    acc: np.ndarray, gyr: np.ndarray, half_window: int = 2, sigma_a: float = 0.01,
    sigma_w: float = 0.1 * np.pi / 180.0, gravity: float = 9.8,
) -> np.ndarray:
    """SHOE / GLRT test statistic (002 eq. 1-2) over a centred window of ``2*half_window+1`` samples.

    ``T_k = 1/W sum_j ( |a_j - g a_mean/|a_mean||^2 / sigma_a^2 + |w_j|^2 / sigma_w^2 )``; the window is
    truncated at the ends.

    Parameters
    ----------
    acc : (N,3) specific force [m/s^2]; gyr : (N,3) angular rate [rad/s]; sigma_a [m/s^2]; sigma_w [rad/s].
    """
    acc, gyr = _check(acc, gyr)
    n = acc.shape[0]
    out = np.empty(n)
    cs_a = np.vstack([np.zeros(3), np.cumsum(acc, axis=0)])
    for k in range(n):
        j0, j1 = max(0, k - half_window), min(n, k + half_window + 1)
        m = (cs_a[j1] - cs_a[j0]) / (j1 - j0)
        u = m / np.linalg.norm(m)
        r = acc[j0:j1] - gravity * u
        out[k] = np.mean(np.sum(r * r, 1) / sigma_a**2 + np.sum(gyr[j0:j1] ** 2, 1) / sigma_w**2)
    return out


def adaptive_threshold(
    intensity_signal: np.ndarray, t_s: np.ndarray, gamma0: float, gamma_exp: float, tau_s: float,
    intensity_ref: float, gamma_min: float, gamma_max: float,
) -> np.ndarray:
    """Gait-intensity adaptive SHOE threshold (project design; reduces to 002 eq. 3 when ``gamma_exp = 0``).

    The intensity ``I_k = max(s_k, I_{k-1} exp(-dt/tau_s))`` is the decaying peak of ``intensity_signal``
    (the navigator uses the specific-force magnitude |a| [m/s^2]: heel strikes of running are hard, slow
    shuffling is soft); the threshold is ``clip(gamma0 (I/intensity_ref)^gamma_exp, gamma_min, gamma_max)``.

    Parameters
    ----------
    intensity_signal : (N,) e.g. |a| [m/s^2] or the SHOE statistic; t_s : (N,) times [s]; tau_s [s].
    """
    s = np.asarray(intensity_signal, dtype=np.float64)
    t = np.asarray(t_s, dtype=np.float64)
    out = np.empty_like(s)
    inten = 0.0
    for k in range(s.shape[0]):
        dt = t[k] - t[k - 1] if k else 0.0
        inten = max(s[k], inten * (np.exp(-dt / tau_s) if tau_s > 0 else 0.0))
        g = gamma0 * (inten / intensity_ref) ** gamma_exp if gamma_exp != 0 and inten > 0 else gamma0
        out[k] = min(max(g, gamma_min), gamma_max)
    return out


def shoe_detector(
    acc: np.ndarray, gyr: np.ndarray, threshold: float | np.ndarray, half_window: int = 2,
    sigma_a: float = 0.01, sigma_w: float = 0.1 * np.pi / 180.0, gravity: float = 9.8,
) -> np.ndarray:
    """Zero-velocity decision ``T_k < gamma`` (002 eq. 3); ``threshold`` scalar or per sample."""
    return shoe_statistic(acc, gyr, half_window, sigma_a, sigma_w, gravity) < threshold


def multi_condition_detector(
    acc: np.ndarray, gyr: np.ndarray, half_window: int = 15, acc_band: tuple[float, float] = (9.0, 11.0),
    acc_std_max: float = 0.5, gyr_max: float = 1.0, median_window: int = 11,
) -> np.ndarray:
    """Multi-condition stance detector (001 eq. 16-23; 000 eq. 25-34) followed by a median filter.

    C1: ``acc_band[0] < |a_k| < acc_band[1]`` [m/s^2] (001 eq. 16-17); C2: local standard deviation of |a|
    over ``2*half_window+1`` samples below ``acc_std_max`` [m/s^2] (eq. 18-20); C3: ``|w_k| < gyr_max``
    [rad/s] (eq. 21-22); C = C1 & C2 & C3 (eq. 23), median-filtered over ``median_window`` samples.
    """
    acc, gyr = _check(acc, gyr)
    an = np.linalg.norm(acc, axis=1)
    n = an.shape[0]
    c1 = (an > acc_band[0]) & (an < acc_band[1])
    cs = np.concatenate([[0.0], np.cumsum(an)])
    cs2 = np.concatenate([[0.0], np.cumsum(an * an)])
    idx = np.arange(n)
    j0 = np.maximum(0, idx - half_window)
    j1 = np.minimum(n, idx + half_window + 1)
    w = j1 - j0
    mean = (cs[j1] - cs[j0]) / w
    var = np.maximum((cs2[j1] - cs2[j0]) / w - mean**2, 0.0)
    c2 = np.sqrt(var) < acc_std_max
    c3 = np.linalg.norm(gyr, axis=1) < gyr_max
    c = (c1 & c2 & c3).astype(np.uint8)
    if median_window > 1:
        c = median_filter(c, size=median_window, mode="nearest")
    return c.astype(bool)


def first_still_run(
    t_s: np.ndarray, acc: np.ndarray, gyr: np.ndarray, min_duration_s: float, gyr_max: float, acc_tol: float,
    gravity: float = 9.81,
) -> tuple[int, int]:
    """The first stretch where the sensor is still for ``min_duration_s``.

    Still = ``|w| < gyr_max`` [rad/s] and ``||a| - gravity| < acc_tol`` [m/s^2] (a foot on the ground).

    Parameters
    ----------
    t_s : ndarray (N,)
        Sample times [s], increasing.
    acc, gyr : ndarray (N, 3)
        Specific force [m/s^2] and angular rate [rad/s], body frame.

    Returns
    -------
    start, end : int
        Indices of the first sample of the stretch and of the sample that completes it (``end`` inclusive).
        When no stretch is long enough: ``end == -1`` and ``start`` is the first index of the still run that
        reaches the last sample (``N`` when the last sample is not still), so a caller can keep it.
    """
    n = len(t_s)
    still = (np.linalg.norm(gyr, axis=1) < gyr_max) & (np.abs(np.linalg.norm(acc, axis=1) - gravity) < acc_tol)
    # first index of the still run each sample belongs to (n where the sample is not still)
    idx = np.arange(n)
    begins = still & ~np.concatenate([[False], still[:-1]])
    run_start = np.maximum.accumulate(np.where(begins, idx, 0)) if n else idx
    done = still & (t_s - t_s[run_start] >= min_duration_s) if n else still
    if np.any(done):
        k = int(np.argmax(done))
        return int(run_start[k]), k
    return (int(run_start[-1]) if n and still[-1] else n), -1
