"""Evaluation metrics of DESIGN.md "Evaluation contracts".

- :func:`armse`: the University of Toronto authors' ARMSE (datasets/vicon/ABOUT.md), reproduced including
  their alignment-index off-by-one and their rounding to the millimetre.
- :func:`loop_closure_pct`, :func:`path_length_xy`, :func:`distance_error_pct`, :func:`stride_errors`: the gdin
  metrics (loop closure, horizontal path length error, per-stride footprint errors after the y-negation and
  the least-squares rotation fitted on strides 1-5).

All positions are in metres; the horizontal plane is columns 0 and 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "align_like_authors",
    "armse",
    "path_length_xy",
    "loop_closure_pct",
    "distance_error_pct",
    "fit_rotation_2d",
    "StrideErrors",
    "stride_errors",
    "summarise",
    "segment_distance_error_pct",
    "StrideLengthErrors",
    "stride_length_errors",
]


def _as_xyz(a: np.ndarray, name: str) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] not in (2, 3):
        raise ValueError(f"{name}: expected an (N, 2) or (N, 3) array of positions [m], got shape {a.shape}")
    if a.shape[1] == 2:
        a = np.hstack([a, np.zeros((a.shape[0], 1))])
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: positions contain NaN or inf")
    return a


def align_like_authors(
    est: np.ndarray, truth: np.ndarray, dist_m: float = 0.8, fallback_index: int = 300
) -> tuple[np.ndarray, np.ndarray, int]:
    """Shift both trajectories to start at the origin and rotate the estimate about the vertical axis.

    The alignment sample ``i`` is the first ``k`` with ``|est[k+1, :2] - est[0, :2]| >= dist_m`` and the authors'
    code then uses sample ``k`` itself (an off-by-one kept for comparability; datasets/vicon/ABOUT.md step 2);
    when the estimate never travels ``dist_m``, ``i = fallback_index``. The rotation turns the estimate's
    horizontal position at ``i`` onto the truth's horizontal position at ``i``; z is not rotated; no scale.

    Parameters
    ----------
    est, truth : ndarray, shape (N, 3)
        Estimated and true positions [m] at the same N instants, in frames of the same handedness with z
        along the same vertical direction.
    dist_m : float
        Horizontal travel that selects the alignment sample [m].
    fallback_index : int
        Alignment sample when the estimate never travels ``dist_m``.

    Returns
    -------
    est_aligned, truth_shifted : ndarray, shape (N, 3)
        Rotated estimate and truth, both starting at the origin [m].
    index : int
        Alignment sample used.
    """
    e = _as_xyz(est, "est")
    g = _as_xyz(truth, "truth")
    if e.shape != g.shape:
        raise ValueError(f"est has shape {e.shape} but truth {g.shape}: the ARMSE needs the same instants")
    if e.shape[0] < 2:
        raise ValueError("ARMSE needs at least two samples")
    e = e - e[0]
    g = g - g[0]
    d = np.linalg.norm(e[1:, :2], axis=1)  # d[k] = |est[k+1] - est[0]| (horizontal)
    hit = np.flatnonzero(d >= dist_m)
    i = int(hit[0]) if hit.size else int(fallback_index)
    i = min(i, e.shape[0] - 1)
    v1, v2 = e[i, :2], g[i, :2]
    n1, n2 = np.linalg.norm(v1), np.linalg.norm(v2)
    if n1 == 0.0 or n2 == 0.0:
        angle = 0.0
    else:
        # authors: sign(cross) * arccos(cos); atan2 is the same angle without arccos' loss near 0
        # (and, like sign(0) = 0 in their code, no rotation when the vectors are exactly (anti)parallel)
        cross = float(v1[0] * v2[1] - v1[1] * v2[0])
        angle = float(np.arctan2(cross, float(v1 @ v2))) if cross != 0.0 else 0.0
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s], [s, c]])
    out = e.copy()
    out[:, :2] = e[:, :2] @ rot.T
    return out, g, i


def armse(
    est: np.ndarray,
    truth: np.ndarray,
    dims: int = 2,
    dist_m: float = 0.8,
    fallback_index: int = 300,
    round_mm: bool = True,
) -> float:
    """Average RMSE of the dataset authors (datasets/vicon/ABOUT.md).

    After :func:`align_like_authors`, per sample ``e_k = sqrt(mean_over_axes((est_k - truth_k)^2))`` over the
    first ``dims`` axes (2: x, y, i.e. horizontal distance / sqrt(2); 3: x, y, z / sqrt(3)), averaged over all
    samples and (``round_mm``) rounded to the millimetre as the authors do.

    Parameters
    ----------
    est, truth : ndarray, shape (N, 3)
        Positions [m] at the same instants, same handedness, z along the same vertical direction.
    dims : {2, 3}
        Axes compared.
    dist_m, fallback_index : float, int
        See :func:`align_like_authors`.
    round_mm : bool
        Round the result to 1 mm like the authors.

    Returns
    -------
    float
        ARMSE [m].
    """
    if dims not in (2, 3):
        raise ValueError(f"dims must be 2 or 3, got {dims}")
    e, g, _ = align_like_authors(est, truth, dist_m, fallback_index)
    per_sample = np.sqrt(np.mean((e[:, :dims] - g[:, :dims]) ** 2, axis=1))
    value = float(np.mean(per_sample))
    return round(value, 3) if round_mm else value


def path_length_xy(points: np.ndarray) -> float:
    """Horizontal length of the polyline through ``points`` (K, >=2) [m]."""
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] < 2:
        raise ValueError(f"points: expected (K, 2+) positions [m], got shape {p.shape}")
    if p.shape[0] < 2:
        return 0.0
    return float(np.sum(np.linalg.norm(np.diff(p[:, :2], axis=0), axis=1)))


def loop_closure_pct(first_xy: np.ndarray, last_xy: np.ndarray, truth_length_m: float) -> float:
    """Horizontal distance between the estimate at the final and at the first stance, in % of the true path.

    Parameters
    ----------
    first_xy, last_xy : array_like, shape (2+,)
        Estimated positions [m] at the first and at the final stance (columns 0, 1 used).
    truth_length_m : float
        Ground-truth path length [m] (sum of distances between consecutive ground-control points).
    """
    if not truth_length_m > 0:
        raise ValueError(f"truth path length must be positive, got {truth_length_m}")
    a = np.asarray(first_xy, dtype=np.float64)[:2]
    b = np.asarray(last_xy, dtype=np.float64)[:2]
    return float(100.0 * np.linalg.norm(b - a) / truth_length_m)


def distance_error_pct(est_length_m: float, truth_length_m: float) -> float:
    """``|estimated - true horizontal path length| / true length`` in %."""
    if not truth_length_m > 0:
        raise ValueError(f"truth path length must be positive, got {truth_length_m}")
    return float(100.0 * abs(est_length_m - truth_length_m) / truth_length_m)


def fit_rotation_2d(src: np.ndarray, dst: np.ndarray) -> float:
    """Angle [rad] of the rotation about the origin that best maps ``src`` onto ``dst`` (least squares).

    Minimises ``sum |R(theta) src_k - dst_k|^2`` (no translation, no scale): ``theta = atan2(sum cross,
    sum dot)``.
    """
    a = np.asarray(src, dtype=np.float64)[:, :2]
    b = np.asarray(dst, dtype=np.float64)[:, :2]
    cross = float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]))
    dot = float(np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]))
    return float(np.arctan2(cross, dot))


@dataclass(frozen=True)
class StrideErrors:
    """Result of :func:`stride_errors`.

    Attributes
    ----------
    mean_m, rmse_m : float
        Mean and RMS of the horizontal errors over strides 1..N [m].
    errors_m : ndarray, shape (N,)
        Per-stride horizontal errors [m] (strides 1..N).
    aligned_xy : ndarray, shape (N+1, 2)
        The transformed estimate (stride 0 at the origin) in the ground-control frame [m].
    angle_rad : float
        The fitted rotation.
    """

    mean_m: float
    rmse_m: float
    errors_m: np.ndarray
    aligned_xy: np.ndarray
    angle_rad: float


def stride_errors(est_xy: np.ndarray, gcp_xy: np.ndarray, n_fit: int = 5) -> StrideErrors:
    """Per-stride footprint errors (DESIGN.md, gdin stride errors).

    The estimate at each ground-truth stride sample is translated so stride 0 is at the origin, its y is
    negated (the ground-control frame is mirrored relative to a right-handed NED solution), it is rotated
    about the origin by the least-squares rotation matching strides ``1..n_fit`` to the ground-control points
    ``1..n_fit``, and the horizontal Euclidean errors over strides ``1..N`` are summarised.

    Parameters
    ----------
    est_xy : ndarray, shape (N+1, 2+)
        Estimated (north, east) [m] at strides 0..N.
    gcp_xy : ndarray, shape (N+1, 2)
        Ground-control points [m] at strides 0..N (GCP_meters; point 0 at the origin).
    n_fit : int
        Number of strides (after stride 0) used for the rotation fit.
    """
    e = np.asarray(est_xy, dtype=np.float64)[:, :2].copy()
    g = np.asarray(gcp_xy, dtype=np.float64)[:, :2]
    if e.shape != g.shape:
        raise ValueError(f"est_xy has {e.shape[0]} strides but gcp_xy {g.shape[0]}")
    if e.shape[0] < 2:
        raise ValueError("stride errors need at least strides 0 and 1")
    if not (np.all(np.isfinite(e)) and np.all(np.isfinite(g))):
        raise ValueError("stride positions contain NaN or inf")
    e -= e[0]
    g = g - g[0]
    e[:, 1] = -e[:, 1]
    k = min(n_fit, e.shape[0] - 1)
    theta = fit_rotation_2d(e[1 : k + 1], g[1 : k + 1])
    c, s = np.cos(theta), np.sin(theta)
    aligned = e @ np.array([[c, -s], [s, c]]).T
    err = np.linalg.norm(aligned[1:] - g[1:], axis=1)
    return StrideErrors(
        mean_m=float(np.mean(err)),
        rmse_m=float(np.sqrt(np.mean(err**2))),
        errors_m=err,
        aligned_xy=aligned,
        angle_rad=float(theta),
    )


def segment_distance_error_pct(est_xy: np.ndarray, truth_xy: np.ndarray, inside: np.ndarray) -> tuple[float | None, int]:
    """Distance error over chosen strides only (e.g. those Gait-DR navigated).

    Parameters
    ----------
    est_xy, truth_xy : ndarray, shape (K, 2)
        Estimated and true horizontal foot positions at the K stride samples [m] (any frames: only the lengths
        of consecutive differences are used).
    inside : ndarray of bool, shape (K - 1,)
        Which strides (k-1 -> k) count.

    Returns
    -------
    (float or None, int)
        ``|sum est - sum true| / sum true`` over the counted strides in % (None without any), and their number.
    """
    e = np.linalg.norm(np.diff(np.asarray(est_xy, dtype=np.float64)[:, :2], axis=0), axis=1)
    t = np.linalg.norm(np.diff(np.asarray(truth_xy, dtype=np.float64)[:, :2], axis=0), axis=1)
    m = np.asarray(inside, dtype=bool)
    if m.shape != e.shape:
        raise ValueError(f"inside: expected {e.shape[0]} stride flags, got {m.shape}")
    n = int(m.sum())
    if n == 0 or not t[m].sum() > 0:
        return None, n
    return distance_error_pct(float(e[m].sum()), float(t[m].sum())), n


def summarise(values: list[float | None]) -> dict[str, float | int | None]:
    """``{"mean", "median", "n"}`` over the non-``None`` values (``None`` statistics when there are none)."""
    v = np.array([x for x in values if x is not None and np.isfinite(x)], dtype=np.float64)
    if v.size == 0:
        return {"mean": None, "median": None, "n": 0}
    return {"mean": float(np.mean(v)), "median": float(np.median(v)), "n": int(v.size)}


@dataclass(frozen=True)
class StrideLengthErrors:
    """Stance-to-stance errors against a marker that is still at the same stances (:func:`stride_length_errors`).

    Attributes
    ----------
    mean_abs_m, rmse_m : float or None
        Mean absolute and RMS error of the horizontal stride length [m] over the strides whose true length is
        at least ``min_length_m`` (None when there are none).
    height_rmse_m : float or None
        RMS error of the height change per stride [m] over the same strides.
    n : int
        Number of those strides.
    distance_err_pct : float or None
        :func:`distance_error_pct` of the summed horizontal lengths of all stance-to-stance intervals (None when
        the truth moved less than ``min_length_m`` in all).
    """

    mean_abs_m: float | None
    rmse_m: float | None
    height_rmse_m: float | None
    n: int
    distance_err_pct: float | None


def stride_length_errors(est_ned: np.ndarray, truth_xyz_up: np.ndarray, min_length_m: float = 0.3) -> StrideLengthErrors:
    """Stride lengths and height changes of the estimate against a truth marker at the same stances.

    Lengths and height changes do not depend on where either frame starts or which way its horizontal axes
    point, so nothing is aligned. A marker on the foot (e.g. the heel) moves with the sensor from one stance to
    the next except for the foot's turn, which shortens or lengthens a turning stride by the lever arm.

    Parameters
    ----------
    est_ned : array_like, shape (K, 3)
        Estimated positions at K consecutive stances, NED [m].
    truth_xyz_up : array_like, shape (K, 3)
        True marker positions at the same stances, horizontal x, y and z up [m].
    min_length_m : float
        Strides shorter than this in the truth (steps on the spot, turns) count only towards the distance.
    """
    e = _as_xyz(est_ned, "est_ned")
    g = _as_xyz(truth_xyz_up, "truth_xyz_up")
    if e.shape != g.shape:
        raise ValueError(f"est_ned {e.shape} and truth_xyz_up {g.shape}: the same stances are needed")
    if e.shape[0] < 2:
        return StrideLengthErrors(None, None, None, 0, None)
    de, dg = np.diff(e, axis=0), np.diff(g, axis=0)
    le, lg = np.linalg.norm(de[:, :2], axis=1), np.linalg.norm(dg[:, :2], axis=1)
    k = lg >= min_length_m
    n = int(k.sum())
    dist = distance_error_pct(float(le.sum()), float(lg.sum())) if lg.sum() >= min_length_m else None
    if n == 0:
        return StrideLengthErrors(None, None, None, 0, dist)
    err = le[k] - lg[k]
    dh = -de[k, 2] - dg[k, 2]  # NED down against z up
    return StrideLengthErrors(float(np.mean(np.abs(err))), float(np.sqrt(np.mean(err**2))),
                              float(np.sqrt(np.mean(dh**2))), n, dist)
