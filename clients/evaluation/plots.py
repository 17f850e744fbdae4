"""PNG plots of an evaluated recording: estimated trajectory vs truth (matplotlib, Agg backend)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["plot_vicon", "plot_gdin", "plot_gaitmap"]


def _figure() -> tuple[Any, Any]:
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 6), dpi=110)
    return fig, ax


def _save(fig: Any, ax: Any, path: Path, title: str) -> Path:
    import matplotlib.pyplot as plt

    ax.set_title(title, fontsize=9)
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_vicon(out_dir: str | Path, row: dict[str, Any], plot: dict[str, Any]) -> Path:
    """Horizontal trajectory after the authors' alignment vs the Vicon truth [m]; returns the PNG path."""
    fig, ax = _figure()
    t, e = np.asarray(plot["truth_xy"]), np.asarray(plot["est_xy"])
    ax.plot(t[:, 0], t[:, 1], "k-", lw=1.0, label="Vicon truth")
    ax.plot(e[:, 0], e[:, 1], "C3-", lw=0.8, label="engine (aligned as the authors do)")
    ax.plot([0], [0], "go", ms=5, label="start")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    title = f"{row['name']}: ARMSE 2-D {row['armse_2d_m']:.3f} m, 3-D {row['armse_3d_m']:.3f} m"
    return _save(fig, ax, Path(out_dir) / f"{row['name']}.png", title)


def plot_gdin(out_dir: str | Path, row: dict[str, Any], plot: dict[str, Any]) -> Path:
    """Per-stance estimate (y negated, rotated onto the ground-control frame) with the GCPs [m].

    With a per-stride truth the rotation is the stride metric's fit on strides 1-5; otherwise the rotation
    that maps the stance reached at the first GCP after the start onto that GCP (for display only).
    """
    fig, ax = _figure()
    gcp = np.asarray(plot["gcp_xy"], dtype=np.float64)
    st = np.asarray(plot["stances_xy"], dtype=np.float64).reshape(-1, 2)
    if st.shape[0]:
        e = st - st[0]
        e[:, 1] = -e[:, 1]
        theta = plot.get("angle_rad")
        if theta is None:
            theta = _display_rotation(e, gcp, plot.get("gcp_stride_numbers"))
        c, s = np.cos(theta), np.sin(theta)
        e = e @ np.array([[c, -s], [s, c]]).T
        ax.plot(e[:, 0], e[:, 1], "C3.-", lw=0.8, ms=2, label="engine, per stance")
    if "aligned_strides_xy" in plot:
        a = np.asarray(plot["aligned_strides_xy"])
        ax.plot(a[:, 0], a[:, 1], "C0x", ms=4, label="engine at truth stride samples")
    ax.plot(gcp[:, 0], gcp[:, 1], "ko-" if gcp.shape[0] < 20 else "k.", lw=0.8, ms=4, label="ground-control points")
    ax.set_xlabel("GCP x [m]")
    ax.set_ylabel("GCP y [m]")
    parts = [f"{k}={row[k]:.3g}" for k in ("loop_closure_pct", "stride_mean_err_m", "distance_err_pct") if k in row]
    title = f"{row['name']} ({row.get('format', '')}): " + ", ".join(parts)
    return _save(fig, ax, Path(out_dir) / f"{row['name']}.png", title)


def _display_rotation(e: np.ndarray, gcp: np.ndarray, stride_numbers: Any) -> float:
    from clients.evaluation.metrics import fit_rotation_2d

    if stride_numbers is None:
        return 0.0
    sn = np.asarray(stride_numbers, dtype=np.int64)
    m = (sn > 0) & (sn < e.shape[0])
    if not m.any():
        return 0.0
    idx = np.flatnonzero(m)[:1]  # the first leg only: later corners carry the drift being shown
    return fit_rotation_2d(e[sn[idx]], gcp[idx])


def plot_gaitmap(out_dir: str | Path, row: dict[str, Any], plot: dict[str, Any]) -> Path:
    """Side view: height [m] over the horizontal distance walked [m] of the engine's stances and, where there is
    motion capture, of the heel marker at the foot's still moments (both from their first point)."""
    fig, ax = _figure()

    def side(p: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p[:, :2], axis=0), axis=1))])
        return d, up - up[0]

    st = np.asarray(plot["stances_ned"], dtype=np.float64).reshape(-1, 3)
    if "truth_xyz" in plot and len(plot["truth_xyz"]):
        g = np.asarray(plot["truth_xyz"], dtype=np.float64)
        ax.plot(*side(g, g[:, 2]), "k.-", lw=1.0, ms=3, label="heel marker (motion capture), still moments")
    if st.shape[0]:
        ax.plot(*side(st, -st[:, 2]), "C3.-", lw=0.8, ms=3, label="engine, per stance")
    ax.set_xlabel("horizontal distance walked [m]")
    ax.set_ylabel("height [m]")
    mae = row.get("stride_length_mean_abs_err_m")
    title = f"{row['name']} ({row['mode']}): climb {row['climb_m']:.2f} m" + (
        f", stride length MAE {mae:.3f} m" if mae is not None else "")
    return _save(fig, ax, Path(out_dir) / f"{row['name']}.png", title)
