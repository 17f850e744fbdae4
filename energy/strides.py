"""Strides that moved: which of the engine's stance-to-stance intervals were a stride of the foot.

The engine reports one position per detected stance (ZUPT-KF) or step (Gait-DR). A person standing still shifts
weight and lifts the foot on the spot, and the stance detector reports a new stance each time: a re-stance at
the same place. A stride is an interval in which the foot travelled: its horizontal displacement between two
consecutive reported positions is at least :data:`STRIDE_MIN_M`.

The threshold comes from the real recordings with per-sample truth (VICON, datasets/vicon: the foot's
motion-capture position at every engine stance; ``pednav eval vicon``'s engine in ``zupt``): of the 1,343
stance-to-stance intervals of the 43 trials, 441 moved the foot by less than 0.05 m in the truth (standing,
in-place foot lifts); the engine's displacement over them is at most 0.081 m (99th percentile 0.052 m). The
truth's displacements have a gap from 0.05 to 0.1 m (5 intervals), and real strides go down to 0.13-0.2 m
(the slow, shuffling trials 2017-11-22-11-27-30 and -11-28-39: runs of strides of 0.14-0.22 m in the truth and
the engine alike). 0.10 m lies between the two: above every standing re-stance, below the shortest shuffling
stride.
"""

from __future__ import annotations

import numpy as np

__all__ = ["STRIDE_MIN_M", "moved", "count_moved"]

STRIDE_MIN_M = 0.10  # [m] horizontal displacement of a stride that moved (module docstring: VICON truth)


def moved(ne: np.ndarray, min_m: float = STRIDE_MIN_M) -> np.ndarray:
    """Which stance-to-stance intervals moved the foot.

    Parameters
    ----------
    ne : array_like, shape (K, 2) or (K, 3)
        Consecutive reported positions, north and east first [m] (a third column, down, is ignored).
    min_m : float
        Horizontal displacement [m] from which an interval is a stride.

    Returns
    -------
    ndarray of bool, shape (max(K - 1, 0),)
        ``True`` for the intervals whose horizontal displacement is at least ``min_m``.
    """
    p = np.asarray(ne, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] < 2:
        raise ValueError(f"ne: expected positions of shape (K, 2) or (K, 3), got {p.shape}")
    if p.shape[0] < 2:
        return np.zeros(0, dtype=bool)
    d = np.diff(p[:, :2], axis=0)
    return np.hypot(d[:, 0], d[:, 1]) >= float(min_m)


def count_moved(ne: np.ndarray, min_m: float = STRIDE_MIN_M) -> int:
    """Number of strides that moved among the intervals of ``ne`` (:func:`moved`)."""
    return int(np.count_nonzero(moved(ne, min_m)))
