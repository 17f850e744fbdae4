"""PNG plots of evaluations (matplotlib, Agg backend): a recording's estimated trajectory vs truth, the energy
against the accuracy of a run's recordings, a recording's mode/gyroscope/behaviour timeline."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["plot_vicon", "plot_gdin", "plot_gaitmap", "plot_energy_accuracy", "plot_recording_timeline"]


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


_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "<", ">")
MODES_BY_COST = ("idle", "pdr", "zupt")  # navigation modes, cheapest at the bottom of a timeline


def _short(name: str) -> str:
    """A point label: VICON trial names are dates and times; their time of day tells them apart in one run."""
    parts = name.split("-")
    return "-".join(parts[-3:]) if len(parts) == 6 else name


_FINE_TICKS = (0.1, 0.2, 0.3, 0.5, 0.7, 1.0, 1.3, 1.5, 2.0, 3.0, 5.0, 10.0)
_DECADE_TICKS = tuple(m * 10.0**e for e in range(-3, 5) for m in (1.0, 2.0, 5.0))


def _log_axis(ax: Any, which: str, lo: float, hi: float) -> None:
    """Axis ``which`` (``"x"``/``"y"``) of ``ax`` logarithmic from ``lo`` to ``hi``, labelled with plain numbers
    (0.2, 0.5, 1, 1.3, 2 ...)."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullFormatter, NullLocator

    getattr(ax, f"set_{which}scale")("log")
    getattr(ax, f"set_{which}lim")(lo, hi)
    axis = getattr(ax, f"{which}axis")
    wide = hi / lo > 30.0  # more than a decade and a half: 1-2-5 ticks, else finer ones around 1
    ticks = [t for t in (_DECADE_TICKS if wide else _FINE_TICKS) if lo <= t <= hi]
    axis.set_major_locator(FixedLocator(ticks))
    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    axis.set_minor_locator(NullLocator())
    axis.set_minor_formatter(NullFormatter())


def plot_energy_accuracy(path: str | Path, docs: list[dict[str, Any]], curve: bool = False) -> int:
    """Energy ratio (x) against accuracy ratio (y), both against the always-on ZUPT-KF on the same recording, one
    series per document (``pednav eval ... --mode auto|pdr --json``), one point per recording; the series'
    median as a large hollow marker, the baseline itself at (1, 1). Log axes. Returns the number of points;
    ``ValueError`` when no row of any document has both ratios (e.g. ``eval recordings``: no truth). ``curve``:
    the medians are joined in the documents' order (a sweep of one setting, ``--set``, labelled by it)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9.5, 7), dpi=120)
    n = 0
    xs: list[float] = [1.0]
    ys: list[float] = [1.0]
    medians: list[tuple[float, float, str]] = []
    for i, doc in enumerate(docs):
        # the rows the document's summary is made of (gdin: usable ground truth only)
        rows = [r for r in doc.get("trials", doc.get("recordings")) or [] if r.get("gt_usable", True)]
        pts = [(float(r["energy_ratio"]), float(r["accuracy_ratio"]), str(r["name"])) for r in rows
               if r.get("energy_ratio") is not None and r.get("accuracy_ratio") is not None]
        missing = sum(1 for r in rows if r.get("energy_ratio") is not None and r.get("accuracy_ratio") is None)
        if not pts:
            continue
        c, mk = f"C{i % 10}", _MARKERS[i % len(_MARKERS)]
        x, y = np.array([p[0] for p in pts]), np.array([p[1] for p in pts])
        metric = ", ".join(sorted(k for k in (doc.get("accuracy_metrics") or {}) if k != "None"))
        settings = " ".join(f"{k}={v}" for k, v in (doc.get("settings") or {}).items())
        medians.append((float(np.median(x)), float(np.median(y)), settings))
        label = (f"{doc.get('dataset', '?')} --mode {doc.get('mode', '?')}{' ' + settings if settings else ''}"
                 f"{' (' + str(doc['profile']) + ')' if doc.get('profile') not in (None, 'none') else ''}: "
                 f"{len(pts)} recordings, median energy {np.median(x):.2f}, accuracy {np.median(y):.2f}"
                 f"{' [' + metric + ']' if metric else ''}{f'; {missing} without accuracy truth' if missing else ''}")
        ax.scatter(x, y, s=28, marker=mk, color=c, alpha=0.8, label=label, zorder=3)
        ax.scatter([np.median(x)], [np.median(y)], s=220, marker=mk, facecolors="none", edgecolors=c, lw=2.0, zorder=4)
        # every point named in a small series, in a large one the five least accurate, but not those at the
        # baseline's star (within 5 % of it on both axes); points that coincide (within 2 %) share one label
        named = range(len(pts)) if len(pts) <= 30 else np.argsort(-y)[:5]
        spots: dict[tuple[int, int], list[int]] = {}
        for k in named:
            if abs(np.log(x[k])) < 0.05 and abs(np.log(y[k])) < 0.05:
                continue
            spots.setdefault((round(50 * np.log(x[k])), round(50 * np.log(y[k]))), []).append(int(k))
        for ks in spots.values():
            names = [_short(pts[k][2]) for k in ks]
            text = ", ".join(names) if len(names) <= 3 else f"{', '.join(names[:2])} +{len(names) - 2} more"
            ax.annotate(text, (x[ks[0]], y[ks[0]]), xytext=(4, 3), textcoords="offset points", fontsize=7, color=c)
        xs += list(x)
        ys += list(y)
        n += len(pts)
    if n == 0:
        plt.close(fig)
        raise ValueError("no recording has both energy_ratio and accuracy_ratio (runs of --mode auto|pdr on a "
                         "dataset with truth are needed)")
    if curve and len(medians) > 1:
        ax.plot([m[0] for m in medians], [m[1] for m in medians], "-", color="0.2", lw=1.5, zorder=6,
                label="medians in the order given")
        for mx, my, text in medians:
            ax.annotate(text.split("=")[-1], (mx, my), xytext=(-6, 6), textcoords="offset points", fontsize=8,
                        color="0.1", ha="right")
    ax.scatter([1.0], [1.0], s=260, marker="*", color="k", zorder=5, label="always-on ZUPT-KF (the baseline, = 1, 1)")
    ax.axhline(1.0, color="k", lw=0.6, ls="--")
    ax.axvline(1.0, color="k", lw=0.6, ls="--")
    ax.axhline(1.3, color="0.5", lw=0.8, ls=":")
    ax.text(min(xs) * 0.9, 1.3, " 1.3x the baseline's error", fontsize=7, color="0.4", va="bottom")
    for which, v in (("x", xs), ("y", ys)):
        _log_axis(ax, which, min(min(v), 0.7) / 1.3, max(max(v), 1.4) * 1.3)
    ax.set_xlabel("energy_ratio: device energy / always-on ZUPT-KF on the same recording (log)")
    ax.set_ylabel("accuracy_ratio: metric / ZUPT-KF's, same recording (log; lower is better)")
    ax.set_title("Energy against accuracy per recording and mode (hollow marker: median)", fontsize=10)
    ax.grid(True, which="both", alpha=0.25)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.1), fontsize=8, frameon=False)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(out, bbox_inches="tight")
    plt.close(fig)
    return n


def _category_line(ax: Any, t: np.ndarray, labels: np.ndarray | None, names: tuple[str, ...], colour: str,
                   other: str | None = None) -> None:
    """Labels over time as a step line on one row per name (labels outside ``names``: on the row ``other``, or a
    gap without it)."""
    ax.set_yticks(range(len(names)), names)
    ax.set_ylim(-0.5, len(names) - 0.5)
    ax.grid(True, axis="x", alpha=0.3)
    if labels is None or not len(t):
        return
    rows = {n: float(i) for i, n in enumerate(names)}
    fallback = rows[other] if other is not None else np.nan
    k = np.array([rows.get(x, fallback) for x in np.asarray(labels).astype(str)])
    ax.step(t, k, where="post", color=colour, lw=1.2)


def plot_recording_timeline(out_dir: str | Path, row: dict[str, Any], plot: dict[str, Any]) -> Path:
    """Behaviour, navigation mode and gyroscope power over the time of one recording (``pednav eval recordings
    --plot``), titled with its energy figures; returns the PNG path (``OUT_DIR/<name>.png``, folders of the
    name replaced by ``__``)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    from clients.evaluation.harness import BEHAVIOURS

    t = np.asarray(plot["t_s"], dtype=np.float64)
    fig, ax = plt.subplots(3, 1, figsize=(11, 5.2), dpi=110, sharex=True,
                           gridspec_kw={"height_ratios": [4, 3, 1.4]})
    _category_line(ax[0], t, plot.get("behaviour"), BEHAVIOURS, "C0", other="other")
    ax[0].set_ylabel("behaviour")
    _category_line(ax[1], t, plot.get("mode"), MODES_BY_COST, "C3")
    ax[1].set_ylabel("mode")
    for a, b in plot.get("gyro_timeline", []):
        ax[2].axvspan(a, b, color="C2", alpha=0.7, lw=0)
    ax[2].set_yticks([])
    ax[2].set_ylabel("gyro on", rotation=0, ha="right", va="center")
    ax[2].set_xlim(0.0, max(float(plot.get("duration_s", 0.0)), float(t[-1]) if len(t) else 0.0, 1e-3))
    ax[2].set_xlabel("time from the recording's first sample [s]")
    ax[2].grid(True, axis="x", alpha=0.3)
    er = row.get("energy_ratio")
    fig.suptitle(f"{row['name']} ({row.get('format', '?')}, --mode {row.get('mode', '?')}): energy "
                 f"{er:.3f} of always-on, gyroscope on {row.get('gyro_on_fraction', 0.0):.0%}, "
                 f"{row.get('strides', 0)} strides" if er is not None else str(row["name"]), fontsize=10)
    out = Path(out_dir) / (str(row["name"]).replace("/", "__") + ".png")
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(out, bbox_inches="tight")
    plt.close(fig)
    return out
