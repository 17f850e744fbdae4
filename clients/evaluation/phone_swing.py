"""The statistics behind the phone's compass-swing wake (:mod:`energy.compass_swing`).

``python -m clients.evaluation.phone_swing [DIR] [--json]`` over the IPIN 2023 T3 dev trials (GetSensorData
logfiles; default ``PEDNAV_DATA/ipin2023-t3-phone``). Each trial's accelerometer and magnetometer go through
:class:`energy.compass_swing.CompassSwing` as the device's detector sees them while the phone engine keeps the
gyroscope off walking (the accelerometer's 50-Hz and the magnetometer's 10-Hz outputs, each the mean of its output
period's native samples, :meth:`energy.device.DeviceEmulator._odr_samples`). The reference is the recorded
gyroscope (100 Hz, never seen by the detector): its rate about the detector's vertical, integrated. At each
magnetometer output between the first and the last landmark (no calibration manoeuvre; no landmark position used):

- ``D``: the detector's largest azimuth change between an output within the window and the newest;
- ``G``: the same of the gyroscope's integrated turn, over 1 s whatever the detector's window.

Windows with ``G`` below 10 deg are straight (the compass's own swing there is its noise and its place error
changing: a wake there is a false one), with ``G`` above 45 deg a turn (about half a right-angle turn). The
threshold is the 99th percentile of ``D`` on straight windows (a false wake in about one window of a hundred); its
worth is the share of turn windows it catches and how long after the gyroscope's turn passed 20 deg the detector
fires (``delay``: per turn, the first swing from 0.5 s before the gyroscope's crossing on), and how far the device
had turned in the second before it fired (``turned_at_wake``, also as a share of the turn's largest ``G``): the part
of the turn a woken gyroscope does not see. Computed for a grid of windows and low-pass time constants, on all
trials and leaving out each route in turn.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from clients.recording import Recording

__all__ = ["SwingTable", "swing_table", "turn_spans", "swing_statistics", "loro_statistics", "main"]

ACC_HZ = 50.0  # the phone engine's walking accelerometer rate (PhoneEngineConfig.acc_rate_hz)
MAG_HZ = 10.0  # ... and its walking magnetometer rate (PhoneEngineConfig.walk_mag_rate_hz)
STRAIGHT_DEG = 10.0
TURN_DEG = 45.0
CROSS_DEG = 20.0
REF_WINDOW_S = 1.0  # [s] the gyroscope's turn that classifies a time (straight / turn) is taken over this, whatever the detector's window


@dataclass(frozen=True)
class SwingTable:
    """Per magnetometer output of one trial between the first and the last landmark (shape (n,) each)."""

    name: str
    t_s: np.ndarray  # time [s]
    detector: np.ndarray  # D [deg]
    gyro: np.ndarray  # G [deg]


def _odr(t: np.ndarray, v: np.ndarray, native_hz: float, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    k = max(1, int(round(native_hz / rate_hz)))
    n = (len(t) // k) * k
    return t[k - 1 : n : k], v[:n].reshape(-1, k, 3).mean(axis=1)


def _window_max(t: np.ndarray, x: np.ndarray, window_ns: int) -> np.ndarray:
    out = np.zeros(len(t))
    j = 0
    for k in range(len(t)):
        while t[j] < t[k] - window_ns:
            j += 1
        out[k] = np.nanmax(np.abs(x[k] - x[j : k + 1])) if k > j else 0.0
    return out


def swing_table(rec: Recording, window_s: float, tau_s: float) -> SwingTable:
    """The detector's and the gyroscope's azimuth changes over ``window_s`` at each magnetometer output."""
    from clients.evaluation.ipin import landmarks
    from energy.compass_swing import CompassSwing

    b = rec.batch
    acc_t, acc_v = _odr(b.acc_t_ns, b.acc, b.rate_hz("acc"), ACC_HZ)
    mag_t, mag_v = _odr(b.mag_t_ns, b.mag, b.rate_hz("mag"), MAG_HZ)
    det = CompassSwing(math.inf, window_s, tau_s)
    t, psi, _ = det.process(acc_t, acc_v, mag_t, mag_v)
    # the gyroscope's turn about the same vertical: the low-passed accelerometer at each gyroscope sample
    g = CompassSwing(math.inf, window_s, tau_s)
    up = np.zeros((len(b.gyr_t_ns), 3))
    i = 0
    for k, tk in enumerate(b.gyr_t_ns):
        while i < len(acc_t) and acc_t[i] <= tk:
            g.feed_acc(int(acc_t[i]), acc_v[i])
            i += 1
        if g.up is not None:
            up[k] = g.up
    rate = np.einsum("ij,ij->i", b.gyr, up)
    yaw = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(b.gyr_t_ns) * 1e-9)])
    gyro_psi = -np.interp(t, b.gyr_t_ns, yaw)  # the field turns the other way in the device's frame
    w = int(round(window_s * 1e9))
    D, G = _window_max(t, psi, w), _window_max(t, gyro_psi, int(REF_WINDOW_S * 1e9))
    T, _ = landmarks(rec)
    keep = (t > T[0]) & (t <= T[-1]) & np.isfinite(psi)
    return SwingTable(rec.name, (t[keep] - t[keep][0]) * 1e-9, np.degrees(D[keep]), np.degrees(G[keep]))


def turn_spans(gyro_deg: np.ndarray) -> list[tuple[int, int, float]]:
    """The turns of a table's ``G`` [deg] (per output, the gyroscope's largest turn within ``REF_WINDOW_S``): each
    rise through ``CROSS_DEG`` into a stretch that reaches ``TURN_DEG``, as (the crossing's index, the index after
    the stretch's end, the stretch's largest ``G`` [deg])."""
    out = []
    above = gyro_deg >= CROSS_DEG
    for k in np.flatnonzero(above[1:] & ~above[:-1]) + 1:
        end = int(k)
        while end < len(gyro_deg) and gyro_deg[end] >= CROSS_DEG:
            end += 1
        top = float(gyro_deg[k:end].max())
        if top >= TURN_DEG:
            out.append((int(k), end, top))
    return out


def _turns(s: SwingTable, thr_deg: float) -> list[tuple[float, float, float]]:
    """Per turn (``G`` rising through ``CROSS_DEG`` into a stretch that reaches ``TURN_DEG``): the time [s] from the
    crossing to the detector's first swing from 0.5 s before it (up to 2 s after; NaN: missed), the gyroscope's
    turn within the second before that swing (how far the device had turned when it woke the gyroscope) and the
    stretch's largest ``G`` [deg]."""
    out = []
    for k, _end, top in turn_spans(s.gyro):
        tk = s.t_s[k]
        m = np.flatnonzero((s.t_s >= tk - 0.5) & (s.t_s <= tk + 2.0) & (s.detector > thr_deg))
        out.append((float(s.t_s[m[0]] - tk), float(s.gyro[m[0]]), top) if len(m) else (math.nan, math.nan, top))
    return out


def swing_statistics(tables: Sequence[SwingTable]) -> dict[str, float]:
    """The statistics of the module docstring over the given trials (angles in degrees, times in s)."""
    D = np.concatenate([s.detector for s in tables])
    G = np.concatenate([s.gyro for s in tables])
    straight, turn = D[G < STRAIGHT_DEG], D[G > TURN_DEG]
    thr = float(np.percentile(straight, 99))
    turns = np.array([x for s in tables for x in _turns(s, thr)]).reshape(-1, 3)
    delays = turns[:, 0]
    found = delays[np.isfinite(delays)]
    before = turns[np.isfinite(delays), 1]
    share = before / turns[np.isfinite(delays), 2]
    return {
        "straight_windows": float(len(straight)),
        "turn_windows": float(len(turn)),
        "straight_p95_deg": float(np.percentile(straight, 95)),
        "straight_p99_deg": thr,
        "turn_median_deg": float(np.median(turn)),
        "turn_caught": float(np.mean(turn > thr)),
        "turns": float(len(delays)),
        "turns_missed": float(np.sum(~np.isfinite(delays))),
        "delay_median_s": float(np.median(found)) if len(found) else math.nan,
        "delay_p90_s": float(np.percentile(found, 90)) if len(found) else math.nan,
        "turned_at_wake_median_deg": float(np.median(before)) if len(found) else math.nan,
        "turned_at_wake_p90_deg": float(np.percentile(before, 90)) if len(found) else math.nan,
        "turned_at_wake_share_median": float(np.median(share)) if len(found) else math.nan,
    }


def loro_statistics(tables: Sequence[SwingTable]) -> dict[str, Any]:
    """:func:`swing_statistics` on all trials, and the range over the folds that leave out one route each."""
    from clients.evaluation.ipin import leave_one_route_out

    return leave_one_route_out(tables, swing_statistics)


GRID = ((0.5, 0.25), (0.5, 0.5), (0.5, 1.0), (1.0, 0.5), (1.5, 0.5))  # (window_s, tau_s)


def main(argv: Sequence[str] | None = None) -> int:
    from clients.evaluation.ipin import logfile_recordings, print_loro

    parsed = logfile_recordings("python -m clients.evaluation.phone_swing", __doc__, argv)
    if parsed is None:
        return 2
    a, recs = parsed
    out = {f"window {w} s, tau {tau} s": loro_statistics([swing_table(r, w, tau) for r in recs]) for w, tau in GRID}
    if a.json:
        print(json.dumps(out, indent=1))
    else:
        for name, st in out.items():
            print(name)
            print_loro(st, indent="  ", width=20)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
