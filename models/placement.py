"""Does a recording look like a foot? The stance phases of a walking or running foot, at a stride's rhythm.

A foot rests flat on the ground once per stride (0.6-1.8 s apart), with the swing's fast rotation between: the
ZUPT-KF's stance detector (:class:`models.zupt_nav.ZuptNavigator`) finds them at that rhythm. A phone in the hand
or a pocket, or a wrist, is never still like that while its wearer walks: the detector fires at random, brief moments.
Measured (``STRIDE_LIKE_MIN``): the fraction of consecutive detected stances 0.6-1.8 s apart is at least 0.50 on
every walking or running foot of the development recordings (42 VICON trials' walks and runs, 26 gdin walks,
gaitmap's feet and stairs: 0.50-0.94) and at most 0.35 on the 16 hand-held phone recordings of IPIN 2023 (0.17-0.33);
a foot that does not walk (in-place foot lifts, crawling: VICON 0.22-0.49) does not look like a walking foot either.
Judged only with at least ``MIN_GAIT_S`` of motion (2.5-s windows whose |a| varies by more than 1 m/s^2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FootCheck", "check_foot", "STRIDE_LIKE_MIN", "MIN_GAIT_S"]

STRIDE_LIKE_MIN = 0.40  # fraction of stance intervals of a stride's length a walking foot has at least
MIN_GAIT_S = 20.0  # s of motion needed to judge
_WINDOW_S = 2.5  # s
_MOTION_STD = 1.0  # m/s^2
_STRIDE_S = (0.6, 1.8)  # s, stance-to-stance interval of one foot's stride


@dataclass(frozen=True)
class FootCheck:
    """Result of :func:`check_foot`.

    Attributes
    ----------
    gait_s : float
        Time in motion [s] (2.5-s windows whose |a| has a standard deviation above 1 m/s^2).
    stances : int
        Stances the ZUPT-KF's detector found.
    stride_like : float
        Fraction of consecutive stances 0.6-1.8 s apart (NaN with fewer than two).
    looks_like_foot : bool or None
        False: no stance phases at a stride's rhythm; None: too little motion to judge.
    reason : str
        One sentence saying what was measured.
    """

    gait_s: float
    stances: int
    stride_like: float
    looks_like_foot: bool | None
    reason: str


def check_foot(t_s: np.ndarray, acc: np.ndarray, gyr: np.ndarray) -> FootCheck:
    """Judge a recording (``t_s`` [s], ``acc`` [m/s^2], ``gyr`` [rad/s], (N, 3), one time axis)."""
    from models.zupt_nav import ZuptNavigator

    t = np.asarray(t_s, dtype=float)
    a = np.asarray(acc, dtype=float)
    n = np.linalg.norm(a, axis=1)
    gait = 0.0
    edges = np.searchsorted(t, np.arange(t[0], t[-1] + _WINDOW_S, _WINDOW_S))
    for i0, i1 in zip(edges[:-1], edges[1:]):
        if i1 - i0 >= 10 and float(np.std(n[i0:i1])) > _MOTION_STD:
            gait += _WINDOW_S
    out = ZuptNavigator().run(t - t[0], a, np.asarray(gyr, dtype=float))
    ts = np.array([s.t_end_s for s in out.stances])
    iv = np.diff(ts)
    frac = float(np.mean((iv >= _STRIDE_S[0]) & (iv <= _STRIDE_S[1]))) if iv.size else float("nan")
    if gait < MIN_GAIT_S:
        return FootCheck(gait, len(ts), frac, None, f"{gait:.0f} s of motion: too little to tell a foot")
    ok = bool(iv.size and frac >= STRIDE_LIKE_MIN)
    what = (f"{len(ts)} stance phases in {gait:.0f} s of motion, {frac:.0%} of them a stride apart "
            f"({_STRIDE_S[0]:g}-{_STRIDE_S[1]:g} s)" if iv.size else f"no stance phase in {gait:.0f} s of motion")
    if ok:
        return FootCheck(gait, len(ts), frac, True, f"{what}: a walking foot")
    return FootCheck(gait, len(ts), frac, False, f"{what}; a walking or running foot has a stance every stride "
                     f"(at least {STRIDE_LIKE_MIN:.0%} of them a stride apart): this does not look like a foot "
                     "(a hand-held phone, a pocket, a wrist), or the foot did not walk")
