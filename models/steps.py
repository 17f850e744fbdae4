"""Step segmentation with the gyroscope OFF: accelerometer-only stance detection and per-step features.

For a foot-mounted sensor one "step" here is one stance of the instrumented foot (a stride): the step
event is the stance onset (heel strike settled), and the step period is the time between consecutive
onsets. The detector works on the Hamming-window FIR filtered specific force (004 Section 2.2) at any rate
from ~20 to 250 Hz:

* stance statistic over a trailing window of ``window_s`` seconds (vector variance plus the squared
  departure of the mean magnitude from g, in m/s^2): the foot is still when both the magnitude and the
  *direction* of the specific force are steady, which the gyroscope-free magnitude alone cannot tell;
* a stance onset is a step event when the swing before it reached ``swing_min`` (a real swing, not
  vibration), and when it comes at least ``refractory_frac`` of the recent median period after the last
  event (no double counts inside one stance);
* per-step features for the step-length models: step frequency f_s = 1 / period (004 eq. 15), mean,
  maximum and minimum of the filtered acceleration magnitude over the step.

The gyroscope, when on, is not needed; the segmenter ignores it so that its events do not change when the
engine switches the gyroscope. Chunk-invariant and serialisable.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from models.fir import FirFilter, hamming_lowpass

__all__ = ["StepEvent", "StepSegmenter", "G0"]

G0 = 9.80665  # m/s^2, standard gravity


@dataclass(frozen=True)
class StepEvent:
    """One detected step (stance onset of the instrumented foot).

    Attributes
    ----------
    t_s : float
        Stance-onset time [s] (same clock as the input, filter delay compensated).
    period_s : float
        Time since the previous stance onset [s] (after a rest: swing time plus a nominal stance).
    f_s : float
        Step frequency [Hz] = 1 / period_s (004 eq. 15).
    acc_mean, acc_max, acc_min : float
        Mean, maximum, minimum of the FIR-filtered specific-force magnitude over the step [m/s^2].
    acc_stance : tuple of float
        Mean filtered specific force over the quiet window at onset [m/s^2], body frame (gives the tilt).
    after_rest : bool
        True when the foot had been still for longer than ``max_period_s`` before this step.
    index : int
        0-based count of the step within the stream.
    """

    t_s: float
    period_s: float
    f_s: float
    acc_mean: float
    acc_max: float
    acc_min: float
    acc_stance: tuple[float, float, float]
    after_rest: bool
    index: int


class StepSegmenter:
    """Streaming accelerometer-only step segmentation (any rate, gyroscope not required).

    Parameters
    ----------
    rate_hz : float
        Nominal accelerometer rate [Hz] (sets filter and window lengths).
    window_s : float
        Trailing window of the stance statistic [s].
    stance_threshold : float
        Stance when the statistic is below this [m/s^2].
    swing_min : float
        Minimum peak of the statistic during the swing for a step to count [m/s^2].
    refractory_frac : float
        A new step needs at least this fraction of the median recent period since the last one.
    min_period_s, max_period_s : float
        Shortest possible step period [s]; longer than ``max_period_s`` means a rest preceded the step.
    fir_cutoff_hz, fir_length_s : float
        Hamming-window FIR low-pass for the features and the statistic (cut-off [Hz], length [s]).
    """

    def __init__(self, rate_hz: float, window_s: float = 0.12, stance_threshold: float = 1.5,
                 swing_min: float = 5.0, refractory_frac: float = 0.6, min_period_s: float = 0.4,
                 max_period_s: float = 2.5, fir_cutoff_hz: float = 8.0, fir_length_s: float = 0.16) -> None:
        self.rate_hz = float(rate_hz)
        self.window_s = float(window_s)
        self.stance_threshold = float(stance_threshold)
        self.swing_min = float(swing_min)
        self.refractory_frac = float(refractory_frac)
        self.min_period_s = float(min_period_s)
        self.max_period_s = float(max_period_s)
        self.fir_cutoff_hz = float(fir_cutoff_hz)
        self.fir_length_s = float(fir_length_s)
        n = int(round(self.fir_length_s * self.rate_hz))
        n += n % 2 == 0
        n = max(n, 3)
        self._fir = FirFilter(hamming_lowpass(n, min(self.fir_cutoff_hz, 0.45 * self.rate_hz), self.rate_hz), 3)
        self._delay = (n - 1) // 2
        self._w = max(2, int(round(self.window_s * self.rate_hz)))
        self._t_hist = np.zeros(0, dtype=np.float64)  # input times awaiting the filter delay
        self._win = np.zeros((0, 3))  # last w filtered samples
        self._win_t = np.zeros(0)  # their (delay-compensated) times
        self._stance = False
        self._quiet_start = float("nan")
        self._peak = 0.0
        self._last_onset = float("nan")  # last stance onset (event or not)
        self._last_event = float("nan")
        self._last_stance_end = float("nan")
        self._periods: list[float] = []
        self._buf = np.zeros(0)  # filtered |a| of the current step [m/s^2]
        self._count = 0
        self._n_events = 0

    # -- streaming -------------------------------------------------------------------------------------
    def feed(self, t_s: np.ndarray, acc: np.ndarray, gyr: np.ndarray | None = None) -> list[StepEvent]:
        """Consume a chunk of accelerometer samples.

        Parameters
        ----------
        t_s : ndarray, shape (N,)
            Sample times [s], increasing.
        acc : ndarray, shape (N, 3)
            Specific force [m/s^2], body frame.
        gyr : ndarray, optional
            Angular rate [rad/s]; accepted for symmetry and ignored (gyro-off design).

        Returns
        -------
        list of StepEvent
            Steps whose stance onset was confirmed within this chunk.
        """
        t_s = np.asarray(t_s, dtype=np.float64).reshape(-1)
        acc = np.asarray(acc, dtype=np.float64).reshape(-1, 3)
        if t_s.size == 0:
            return []
        af = self._fir.process(acc)
        if self._t_hist.size == 0 and self._count == 0 and self._win_t.size == 0:
            self._t_hist = np.repeat(t_s[:1], self._delay)  # matches the FIR's replicated start
        t_all = np.concatenate([self._t_hist, t_s])
        t_out = t_all[: t_s.size]  # time of the input at the centre of the filter
        self._t_hist = t_all[max(t_all.size - self._delay, 0):] if self._delay else t_all[:0]
        mag = np.linalg.norm(af, axis=1)
        events: list[StepEvent] = []
        w = self._w
        win = np.concatenate([self._win, af])
        win_t = np.concatenate([self._win_t, t_out])
        off = self._win.shape[0]
        n = t_s.size
        # stance statistic of every new sample whose window is complete (vectorised)
        stat = np.zeros(n)
        valid = (off + np.arange(n) + 1) >= w
        if np.any(valid):
            k0 = int(np.argmax(valid))
            seg = np.lib.stride_tricks.sliding_window_view(win[off + k0 + 1 - w:], w, axis=0)  # (m, 3, w)
            mu = seg.mean(axis=2)
            var = ((seg - mu[:, :, None]) ** 2).sum(axis=1).mean(axis=1)
            stat[k0:] = np.sqrt(var + (np.linalg.norm(mu, axis=1) - G0) ** 2)
        else:
            k0 = n
            mu = np.zeros((0, 3))
        below = valid & (stat < self.stance_threshold)
        # walk the state machine only at transitions; features accumulate over sample ranges
        acc_from = 0
        k = k0
        while k < n:
            if self._stance:
                nxt = np.flatnonzero(~below[k:])
                if nxt.size == 0:
                    break
                k += int(nxt[0])
                self._last_stance_end = float(win_t[off + k])
                self._stance = False
            else:
                nxt = np.flatnonzero(below[k:])
                stop = n if nxt.size == 0 else k + int(nxt[0])
                if stop > k:
                    self._peak = max(self._peak, float(stat[k:stop].max()))
                if nxt.size == 0:
                    break
                k = stop
                self._stance = True
                self._accumulate(mag[acc_from:k + 1])
                acc_from = k + 1
                onset = float(win_t[off + k + 1 - w])
                ev = self._on_onset(onset, tuple(float(v) for v in mu[k - k0]))
                if ev is not None:
                    events.append(ev)
                k += 1
        self._accumulate(mag[acc_from:])
        keep = max(w - 1, 0)
        self._win = win[max(win.shape[0] - keep, 0):].copy()
        self._win_t = win_t[max(win_t.size - keep, 0):].copy()
        self._count += t_s.size
        return events

    def _accumulate(self, m: np.ndarray) -> None:
        # the step's magnitudes are kept, so its mean does not depend on how the stream was chunked
        if m.size:
            self._buf = np.concatenate([self._buf, m])

    def _on_onset(self, onset: float, mu: tuple[float, float, float]) -> StepEvent | None:
        refr = self.min_period_s
        if len(self._periods) >= 3:
            refr = max(refr, self.refractory_frac * float(np.median(self._periods[-5:])))
        last = self._last_event
        ok = self._peak >= self.swing_min and (np.isnan(last) or onset - last >= refr)
        if not ok:
            if np.isnan(self._last_onset):
                self._last_onset = onset  # the standing stance before the first step
            return None
        prev = self._last_onset if not np.isnan(self._last_onset) else onset
        period = onset - prev
        after_rest = not (0.0 < period <= self.max_period_s)
        if after_rest:
            swing = onset - self._last_stance_end if not np.isnan(self._last_stance_end) else self.min_period_s
            period = max(self.min_period_s, swing + 0.25)  # nominal stance after a rest
        else:
            self._periods.append(period)
            self._periods = self._periods[-9:]
        ev = StepEvent(t_s=onset, period_s=period, f_s=1.0 / period,
                       acc_mean=float(self._buf.mean()) if self._buf.size else float("nan"),
                       acc_max=float(self._buf.max()) if self._buf.size else float("nan"),
                       acc_min=float(self._buf.min()) if self._buf.size else float("nan"),
                       acc_stance=mu, after_rest=after_rest, index=self._n_events)
        self._n_events += 1
        self._last_event = onset
        self._last_onset = onset
        self._peak = 0.0
        self._buf = np.zeros(0)
        return ev

    # -- state -----------------------------------------------------------------------------------------
    def get_state(self) -> dict:
        """Plain-data state for ``energy.codec``."""
        return {
            "params": [self.rate_hz, self.window_s, self.stance_threshold, self.swing_min, self.refractory_frac,
                       self.min_period_s, self.max_period_s, self.fir_cutoff_hz, self.fir_length_s],
            "fir": self._fir.get_state(), "t_hist": self._t_hist.copy(), "win": self._win.copy(),
            "win_t": self._win_t.copy(), "stance": self._stance, "peak": self._peak,
            "last_onset": self._last_onset, "last_event": self._last_event,
            "last_stance_end": self._last_stance_end, "periods": list(self._periods),
            "buf": self._buf.copy(), "count": self._count,
            "n_events": self._n_events,
        }

    @classmethod
    def from_state(cls, d: dict) -> StepSegmenter:
        """Rebuild from :meth:`get_state` output."""
        obj = cls(*[float(v) for v in d["params"]])
        obj._fir = FirFilter.from_state(d["fir"])
        obj._t_hist = np.asarray(d["t_hist"], dtype=np.float64).copy()
        obj._win = np.asarray(d["win"], dtype=np.float64).reshape(-1, 3).copy()
        obj._win_t = np.asarray(d["win_t"], dtype=np.float64).copy()
        obj._stance = bool(d["stance"])
        obj._peak = float(d["peak"])
        obj._last_onset = float(d["last_onset"])
        obj._last_event = float(d["last_event"])
        obj._last_stance_end = float(d["last_stance_end"])
        obj._periods = [float(v) for v in d["periods"]]
        obj._buf = np.asarray(d["buf"], dtype=np.float64).reshape(-1).copy()
        obj._count = int(d["count"])
        obj._n_events = int(d["n_events"])
        return obj
