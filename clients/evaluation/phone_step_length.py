"""Why the step length is short on the SM-G930F: per-trial step statistics of the IPIN 2023 T3 dev trials.

``python -m clients.evaluation.phone_step_length [DIR] [--json]`` (default ``PEDNAV_DATA/ipin2023-t3-phone``).
Each trial runs always-on through the step-and-heading engine with the Weinberg constant 1 (so a step's length is
its feature ``(a_max - a_min)^(1/4)``, 000 eq. 35); only the steps between the first and the last landmark count.
Per trial:

- ``steps``, ``step_m``: the steps and the surveyed path over them (the landmark-to-landmark distances: a lower
  bound of the walked path), i.e. the walker's mean step length [m];
- ``weinberg``: the median Weinberg feature [(m/s^2)^(1/4)], and ``period_s``, the median step period [s];
- from the recorded accelerometer over the same time (no engine): the power of the specific force along the
  gravity direction (gravity: a 0.3-Hz low-pass of it) in the walking band 1-2.5 Hz, ``vert_power``
  [(m/s^2)^2], which the phone's own filtering cannot shape (it is far below any accelerometer's bandwidth), and
  the share of the magnitude's power above 5 Hz in its power above 0.5 Hz, ``hf_share`` [-], which it can.

A step-length model that is device-independent needs a feature that is larger where the steps are longer. These
statistics use the surveyed length, so they are for diagnosis, not for fitting.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

import numpy as np

from clients.recording import Recording

__all__ = ["trial_statistics", "main"]


def _band_power(x: np.ndarray, fs: float, lo: float, hi: float) -> float:
    """Power of ``x`` between ``lo`` and ``hi`` [Hz] (Welch, 512-sample Hann segments) [unit^2]."""
    from scipy.signal import welch

    f, p = welch(x - np.mean(x), fs=fs, nperseg=min(512, len(x)))
    df = f[1] - f[0]
    return float(np.sum(p[(f >= lo) & (f < hi)]) * df)


def trial_statistics(rec: Recording) -> dict[str, Any]:
    """The statistics of the module docstring for one trial."""
    from scipy.signal import butter, filtfilt

    from clients.evaluation.ipin import _surveyed, landmarks, run_phone

    T, _ = landmarks(rec)
    run = run_phone(rec, "always-on", 1.0)
    inside = (run.t_ns > T[0]) & (run.t_ns <= T[-1])
    t_s = run.t_ns[inside] * 1e-9
    period = np.diff(t_s)
    b = rec.batch
    fs = b.rate_hz("acc")
    acc = np.asarray(b.acc, dtype=float)
    bb, aa = butter(2, 0.3 / (fs / 2.0))
    g = filtfilt(bb, aa, acc, axis=0)
    up = g / np.linalg.norm(g, axis=1)[:, None]
    vert = np.sum(acc * up, axis=1) - np.linalg.norm(g, axis=1)
    mag = np.linalg.norm(acc, axis=1)
    w = (b.acc_t_ns > T[0]) & (b.acc_t_ns < T[-1])
    n = int(inside.sum())
    return {
        "name": rec.name,
        "phone": (rec.aux.get("device") or {}).get("Model"),
        "steps": n,
        "step_m": _surveyed(rec) / n if n else float("nan"),
        "weinberg": float(np.median(run.step_m[inside])) if n else float("nan"),
        "period_s": float(np.median(period[period < 1.5])) if len(period) else float("nan"),
        "vert_power": _band_power(vert[w], fs, 1.0, 2.5),
        "hf_share": _band_power(mag[w], fs, 5.0, fs / 2.0) / _band_power(mag[w], fs, 0.5, fs / 2.0),
    }


def main(argv: Sequence[str] | None = None) -> int:
    from clients.evaluation.ipin import logfile_recordings

    parsed = logfile_recordings("python -m clients.evaluation.phone_step_length", __doc__, argv)
    if parsed is None:
        return 2
    a, recs = parsed
    rows = [trial_statistics(r) for r in recs]
    if a.json:
        print(json.dumps(rows, indent=1))
        return 0
    print(f"{'trial':<42} {'phone':<9} {'steps':>5} {'step m':>6} {'weinb.':>6} {'period':>6} {'vert 1-2.5':>10} {'hf share':>8}")
    for r in rows:
        print(f"{r['name']:<42} {r['phone']!s:<9} {r['steps']:>5d} {r['step_m']:>6.3f} {r['weinberg']:>6.3f} "
              f"{r['period_s']:>6.3f} {r['vert_power']:>10.2f} {r['hf_share']:>8.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
