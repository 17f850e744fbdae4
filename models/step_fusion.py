"""Complementary fusion of two devices' steps (000 Section 5.3, eq. 70 and Table 7): a phone and a watch carried
by one walker.

Each step of the primary device (the phone) is paired with the secondary device's step nearest in time (within
``pair_s``). Their lengths are blended, 000 eq. (70): ``d = alpha d_secondary + (1 - alpha) d_primary`` with
``alpha = weight`` when the two agree (``ratio_low < d_secondary / d_primary < ratio_high``, 000 Table 7's
0.8-1.2) and ``alpha = 0`` otherwise (000 takes the device it trusts when they disagree: a false step of one
shows as a ratio far from 1). The headings are blended the same way on the circle, gated by ``max_heading_rad``.
A step without a partner keeps the primary's length and heading.

000's secondary is an ankle INS and its primary a hand-held PDR; here both are step-and-heading devices, and which
is trusted when they disagree is the primary (the phone held in front walks with the body; a wrist swings).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["StepFusionConfig", "fuse_steps", "fuse_track"]


@dataclass(frozen=True)
class StepFusionConfig:
    """Parameters of :func:`fuse_steps` (000 Table 7: weight 0.5, ratio 0.8-1.2).

    Attributes
    ----------
    weight : float
        ``alpha`` of 000 eq. (70) when the devices agree.
    ratio_low, ratio_high : float
        The step lengths agree when their ratio lies between these.
    max_heading_rad : float
        The headings agree when they differ by less than this [rad].
    pair_s : float
        Largest time difference of paired steps [s].
    """

    weight: float = 0.5
    ratio_low: float = 0.8
    ratio_high: float = 1.2
    max_heading_rad: float = math.radians(20.0)
    pair_s: float = 0.25

    def __post_init__(self) -> None:
        if not (0.0 <= self.weight <= 1.0 and 0.0 < self.ratio_low < 1.0 < self.ratio_high):
            raise ValueError("StepFusionConfig: weight within [0, 1], ratio_low < 1 < ratio_high")
        if not (self.max_heading_rad > 0 and self.pair_s > 0):
            raise ValueError("StepFusionConfig: max_heading_rad and pair_s must be positive")


def fuse_steps(t_a: np.ndarray, len_a: np.ndarray, head_a: np.ndarray, t_b: np.ndarray, len_b: np.ndarray,
               head_b: np.ndarray, config: StepFusionConfig | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fused lengths [m] and headings [rad] of the primary's steps, and which steps were blended.

    Parameters
    ----------
    t_a, len_a, head_a : ndarray, shape (N,)
        Primary steps: times [s or ns, any one unit with ``pair_s`` in seconds if seconds], lengths [m], headings
        [rad].
    t_b, len_b, head_b : ndarray, shape (M,)
        Secondary steps, same units.
    """
    c = config or StepFusionConfig()
    ta, la, ha = (np.asarray(x, dtype=float) for x in (t_a, len_a, head_a))
    tb, lb, hb = (np.asarray(x, dtype=float) for x in (t_b, len_b, head_b))
    out_l, out_h = la.copy(), ha.copy()
    blended = np.zeros(len(ta), dtype=bool)
    if len(tb) == 0:
        return out_l, out_h, blended
    j = np.clip(np.searchsorted(tb, ta), 1, len(tb) - 1) if len(tb) > 1 else np.zeros(len(ta), dtype=int)
    if len(tb) > 1:
        j = np.where(np.abs(tb[j - 1] - ta) < np.abs(tb[j] - ta), j - 1, j)
    for i, k in enumerate(j):
        if abs(tb[k] - ta[i]) > c.pair_s or not la[i] > 0:
            continue
        if c.ratio_low < lb[k] / la[i] < c.ratio_high:
            out_l[i] = c.weight * lb[k] + (1.0 - c.weight) * la[i]  # 000 eq. (70)
            blended[i] = True
        dh = math.remainder(hb[k] - ha[i], 2.0 * math.pi)
        if abs(dh) < c.max_heading_rad:
            out_h[i] = ha[i] + c.weight * dh
            blended[i] = True
    return out_l, out_h, blended


def fuse_track(north: np.ndarray, east: np.ndarray, t_a_s: np.ndarray, len_a: np.ndarray, head_a: np.ndarray,
               t_b_s: np.ndarray, len_b: np.ndarray, head_b: np.ndarray,
               config: StepFusionConfig | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The primary's step-and-heading track with its steps fused with the secondary's (:func:`fuse_steps`).

    A step-and-heading track is the sum of its step vectors, ``p_k = p_(k-1) + L_k (cos h_k, sin h_k)`` (north,
    east); each position moves by the running sum of the fused steps' vectors minus the primary's own, so a
    track with no blended step comes back unchanged, bit for bit.

    Parameters
    ----------
    north, east : ndarray, shape (N,)
        The primary's positions [m] in its engine's frame.
    t_a_s, len_a, head_a : ndarray, shape (N,)
        The primary's step times [s], lengths [m] and headings [rad] (same frame as ``north``/``east``).
    t_b_s, len_b, head_b : ndarray, shape (M,)
        The secondary's steps, its times on the same clock [s] and its headings in the same frame.

    Returns
    -------
    north, east, length, heading : ndarray, shape (N,)
        The fused track [m], step lengths [m] and headings [rad].
    blended : ndarray of bool, shape (N,)
        Which of the primary's steps took the secondary's into account.
    """
    la, ha = np.asarray(len_a, dtype=float), np.asarray(head_a, dtype=float)
    lf, hf, blended = fuse_steps(t_a_s, la, ha, t_b_s, len_b, head_b, config)
    dn = np.cumsum(lf * np.cos(hf) - la * np.cos(ha))
    de = np.cumsum(lf * np.sin(hf) - la * np.sin(ha))
    return np.asarray(north, dtype=float) + dn, np.asarray(east, dtype=float) + de, lf, hf, blended
