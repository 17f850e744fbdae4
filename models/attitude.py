"""Attitude from vector observations: initial alignment at rest (001 eq. 1-5) and TRIAD (002 Appendix A).

Works for ANY sensor mounting: the body frame is the sensor's own axes; no Euler-angle singularities.
"""

from __future__ import annotations

import numpy as np

from models._zupt_kernel import triad_s

__all__ = ["triad", "align_at_rest"]


def triad(r1: np.ndarray, r2: np.ndarray, s1: np.ndarray, s2: np.ndarray) -> np.ndarray:
    """TRIAD (002 Appendix A): the rotation ``C`` with ``C r1 = s1`` exactly and ``C r2`` in the plane of
    ``(s1, s2)``. Body vectors ``r``, navigation vectors ``s`` (any units; only directions matter).

    Raises
    ------
    ValueError
        When a pair of vectors is zero or (nearly) parallel.
    """
    vs = [np.asarray(v, dtype=np.float64).reshape(3) for v in (r1, r2, s1, s2)]
    if not all(np.all(np.isfinite(v)) for v in vs):
        raise ValueError("triad: vectors must be finite")
    c = triad_s(*vs)
    if np.isnan(c[0, 0]):
        raise ValueError("triad: a vector is zero or the two vectors of a pair are parallel")
    return c


def align_at_rest(
    acc_mean: np.ndarray, mag_mean: np.ndarray | None = None, mag_reference: np.ndarray | None = None
) -> np.ndarray:
    """Body-to-NED DCM from the mean specific force (and field) over a rest period (001 eq. 1-5).

    Parameters
    ----------
    acc_mean : (3,) mean specific force [m/s^2], body frame (reads +g away from the Earth).
    mag_mean : (3,) mean field [uT], body frame, or None.
    mag_reference : (3,) expected field in NED [uT] (e.g. WMM, gives true north); None = magnetic north.

    Returns
    -------
    C : (3, 3) body-to-NED DCM. Without a field the heading of the body x axis is set to 0 (to the y axis
    when x is nearly vertical).
    """
    f = np.asarray(acc_mean, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(f)) or not 5.0 < np.linalg.norm(f) < 15.0:
        raise ValueError(f"acc_mean: expected about 9.8 m/s^2 at rest, got |a| = {np.linalg.norm(f):.3g}")
    down_b = -f
    down_n = np.array([0.0, 0.0, 1.0])
    if mag_mean is not None:
        ref = np.array([1.0, 0.0, 0.0]) if mag_reference is None else np.asarray(mag_reference, dtype=np.float64)
        return triad(down_b, mag_mean, down_n, ref)
    if abs(down_b[0]) > 0.9 * np.linalg.norm(down_b):
        return triad(down_b, [0.0, 1.0, 0.0], down_n, [0.0, 1.0, 0.0])
    return triad(down_b, [1.0, 0.0, 0.0], down_n, [1.0, 0.0, 0.0])
