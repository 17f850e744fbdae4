"""Step segmentation with the gyroscope OFF: accelerometer-only stance detection and per-step features.

For a foot-mounted sensor one "step" here is one stance of the instrumented foot (a stride): the step
event is the stance onset, and the step period is the time between consecutive onsets. The detector works
on the Hamming-window FIR filtered specific force (004 Section 2.2) at any rate from ~20 to 250 Hz.

Why not a fixed threshold: at a normal pace the stance is a long quiet stretch of the specific force, but
at a fast pace (the foot rolls from heel to toe in ~0.1 s) the stance is *not* the quietest moment of the
stride: the accelerometer passes through near-gravity briefly in mid-swing, and the rolling stance stays
2-9 m/s^2 away from rest. What does tell the stance apart at every pace is its context: the heel-strike
impact just before it, the push-off just after it, and (at normal paces) its length. The detector
therefore works on *candidates* and picks one per stride:

1. quietness statistic ``q`` over a trailing window of ``window_s`` (vector variance plus the squared
   departure of the mean magnitude from g, m/s^2): the foot is still when both the magnitude and the
   direction of the specific force are steady;
2. candidates: every run of ``q < stance_threshold`` (a quiet stretch, with its duration), and every local
   minimum of ``q`` above it (a brief near-still moment);
3. adaptive threshold relative to the recent step energy: a candidate counts only if its ``q`` is below
   ``rel_threshold`` times the largest filtered ``|a| - g`` of the last ``level_s`` seconds;
4. score = ``k_duration * min(duration, duration_cap_s)`` + (impact before - impact after) -
   ``k_quiet * q`` [m/s^2], the impacts being the largest ``|a| - g`` within ``context_s`` before the
   candidate's start and after its end (heel strike precedes a stance; the heel strike of the *next*
   stride follows a mid-swing pause);
5. refractory period from the running stride-period estimate: candidates closer than ``refractory_frac``
   periods compete and only the best-scoring one survives (non-maximum suppression), and a new stride
   needs a swing of at least ``swing_frac`` periods (``min_swing_s`` at least) after the previous stance.

A selected candidate is a step when a swing (``|a| - g`` peak above ``swing_min``) separates it from the
previous one. Decisions are final once no competing candidate can still arrive, i.e. ``refractory`` plus
``context_s`` after the onset (the latency of the step events).

Per-step features for the step-length models: step frequency f_s = 1 / period (004 eq. 15), mean, maximum
and minimum of the filtered acceleration magnitude over the step. The gyroscope, when on, is not used, so
the events do not change when the engine switches it. Chunk-invariant and serialisable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models.fir import FirFilter, hamming_lowpass

__all__ = ["StepEvent", "StepSegmenter", "G0"]

G0 = 9.80665  # m/s^2, standard gravity

# candidate record layout (plain lists, so the state serialises without custom types)
_I_FIRST, _I_LAST, _Q, _N, _MX, _MY, _MZ, _EMIT = range(8)


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
        Nominal accelerometer rate [Hz] (sets filter, window and look-ahead lengths in samples).
    window_s : float
        Trailing window of the quietness statistic [s].
    stance_threshold : float
        Quiet stretch when the statistic is below this [m/s^2] (fixed: sensor noise scale).
    swing_min : float
        A selected stance is a step only when ``|a| - g`` exceeded this since the previous one [m/s^2].
    refractory_frac : float
        Candidates closer than this fraction of the stride period compete (one survives).
    min_period_s, max_period_s : float
        Shortest step period [s] (lower bound of the refractory period); a longer gap than
        ``max_period_s`` means a rest preceded the step.
    fir_cutoff_hz, fir_length_s : float
        Hamming-window FIR low-pass for the features and the statistic (cut-off [Hz], length [s]).
    swing_frac, min_swing_s : float
        A new stride needs at least ``max(min_swing_s, swing_frac * period)`` [s] between the end of the
        previous stance and its onset.
    context_s : float
        Look-back/look-ahead for the impacts around a candidate [s].
    level_s : float
        Look-back for the recent step energy (largest ``|a| - g``) [s].
    rel_threshold : float
        Candidates need ``q <= max(stance_threshold, rel_threshold * energy)``.
    k_duration, duration_cap_s : float
        Score weight of a quiet stretch's duration [m/s^2 per s] and the duration it saturates at [s].
    k_quiet : float
        Score weight of the candidate's quietness statistic [-].
    period_min_s, period_max_s : float
        Bounds of the running stride-period estimate used for the refractory and swing rules [s].
    default_period_s : float
        Stride period assumed until three periods have been measured [s].
    long_stance_s : float
        A quiet stretch longer than this [s] (standing) becomes a candidate without waiting for its end, so
        the last stance before a rest is reported while the person stands.
    max_latency_s : float
        Hard bound on (newest filtered sample time) - (onset) when a step is emitted [s]: competitors still
        open at that point are decided on the samples available (see :attr:`latency_s`).
    """

    def __init__(self, rate_hz: float, window_s: float = 0.12, stance_threshold: float = 1.5,
                 swing_min: float = 5.0, refractory_frac: float = 0.6, min_period_s: float = 0.35,
                 max_period_s: float = 2.5, fir_cutoff_hz: float = 8.0, fir_length_s: float = 0.16,
                 swing_frac: float = 0.45, min_swing_s: float = 0.25, context_s: float = 0.3,
                 level_s: float = 1.5, rel_threshold: float = 0.35, k_duration: float = 50.0,
                 duration_cap_s: float = 0.3, k_quiet: float = 2.0, period_min_s: float = 0.5,
                 period_max_s: float = 1.5, default_period_s: float = 1.0, long_stance_s: float = 0.6,
                 max_latency_s: float = 1.0) -> None:
        self.rate_hz = float(rate_hz)
        self.window_s = float(window_s)
        self.stance_threshold = float(stance_threshold)
        self.swing_min = float(swing_min)
        self.refractory_frac = float(refractory_frac)
        self.min_period_s = float(min_period_s)
        self.max_period_s = float(max_period_s)
        self.fir_cutoff_hz = float(fir_cutoff_hz)
        self.fir_length_s = float(fir_length_s)
        self.swing_frac = float(swing_frac)
        self.min_swing_s = float(min_swing_s)
        self.context_s = float(context_s)
        self.level_s = float(level_s)
        self.rel_threshold = float(rel_threshold)
        self.k_duration = float(k_duration)
        self.duration_cap_s = float(duration_cap_s)
        self.k_quiet = float(k_quiet)
        self.period_min_s = float(period_min_s)
        self.period_max_s = float(period_max_s)
        self.default_period_s = float(default_period_s)
        self.long_stance_s = float(long_stance_s)
        self.max_latency_s = float(max_latency_s)
        n = int(round(self.fir_length_s * self.rate_hz))
        n += n % 2 == 0
        n = max(n, 3)
        self._fir = FirFilter(hamming_lowpass(n, min(self.fir_cutoff_hz, 0.45 * self.rate_hz), self.rate_hz), 3)
        self._delay = (n - 1) // 2
        self._w = max(2, int(round(self.window_s * self.rate_hz)))
        self._n_ctx = max(1, int(round(self.context_s * self.rate_hz)))
        self._n_lvl = max(1, int(round(self.level_s * self.rate_hz)))
        self._keep = int(round((self.max_period_s + self.level_s + 2 * self.context_s) * self.rate_hz)) + self._w
        self._t_hist = np.zeros(0, dtype=np.float64)  # input times awaiting the filter delay
        self._win = np.zeros((0, 3))  # last w-1 filtered samples
        # per filtered sample (global index b0 + j): time [s], |a|-g [m/s^2], |a| [m/s^2]
        self._b0 = 0
        self._bt = np.zeros(0)
        self._be = np.zeros(0)
        self._bm = np.zeros(0)
        self._count = 0  # filtered samples produced (next global index)
        self._q1 = math.inf  # statistic of the previous sample
        self._q2 = math.inf  # ... and of the one before
        self._mu1 = (0.0, 0.0, 0.0)  # window mean of the previous sample
        self._run: list[float] | None = None  # quiet stretch in progress (candidate layout)
        self._await: list[list[float]] = []  # candidates waiting for their look-ahead
        self._pend: list[float] | None = None  # best candidate of the current refractory window (scored)
        self._last: list[float] | None = None  # last selected stance: [t_on, t_end, i_first, i_last, onset_idx]
        self._periods: list[float] = []
        self._n_events = 0
        self._flushed = False

    # -- helpers -------------------------------------------------------------------------------------------
    def _period(self) -> float:
        """Running stride-period estimate [s] for the refractory and swing rules."""
        if len(self._periods) < 3:
            return self.default_period_s
        p = sorted(self._periods[-5:])[len(self._periods[-5:]) // 2]  # median of the last (up to) five
        return min(max(p, self.period_min_s), self.period_max_s)

    def _t(self, i: int) -> float:
        """Time [s] of filtered sample with global index ``i`` (clipped to the buffer)."""
        j = min(max(i - self._b0, 0), self._bt.size - 1)
        return float(self._bt[j])

    def _emax(self, lo: int, hi: int) -> float:
        """Largest ``|a| - g`` over global indices ``lo..hi`` inclusive (clipped to the buffer) [m/s^2]."""
        a = max(lo - self._b0, 0)
        b = min(hi - self._b0 + 1, self._be.size)
        return float(self._be[a:b].max()) if b > a else -math.inf

    def _score(self, c: list[float]) -> list[float]:
        """Scored candidate: [t_on, t_end, q, score, i_first, i_last, mx, my, mz]."""
        i1, i2 = int(c[_I_FIRST]), int(c[_I_LAST])
        w1 = self._w - 1
        t_on, t_end = self._t(i1 - w1), self._t(i2 - w1)
        pre = self._emax(i1 - self._n_ctx, i1)  # heel strike before a stance
        post = self._emax(i2, i2 + self._n_ctx)  # push-off after it (or the next heel strike after a pause)
        lvl = self._emax(i1 - self._n_lvl, i1)  # recent step energy
        q = c[_Q]
        if q > max(self.stance_threshold, self.rel_threshold * lvl):
            return []
        dur = c[_N] / self.rate_hz
        s = self.k_duration * min(dur, self.duration_cap_s) + (pre - post) - self.k_quiet * q
        return [t_on, t_end, q, s, float(i1), float(i2), c[_MX], c[_MY], c[_MZ]]

    def _select(self, c: list[float], out: list[StepEvent]) -> None:
        """Non-maximum suppression of scored candidates within the refractory period."""
        x = self._score(c)
        if not x:
            return
        per = self._period()
        refr = max(self.min_period_s, self.refractory_frac * per)
        if self._pend is not None and x[0] - self._pend[0] >= refr:
            self._confirm(out)
        if self._pend is None:
            last = self._last
            if last is not None and (x[0] - last[0] < refr
                                     or x[0] - last[1] < max(self.min_swing_s, self.swing_frac * per)):
                return
            self._pend = x
        elif x[3] > self._pend[3]:
            self._pend = x

    def _confirm(self, out: list[StepEvent]) -> None:
        """The pending candidate is the stance of this stride: emit it as a step if a swing preceded it."""
        x = self._pend
        assert x is not None
        self._pend = None
        onset, i1, i2 = x[0], int(x[4]), int(x[5])
        on_idx = i1 - (self._w - 1)
        last = self._last
        lo = int(last[3]) if last is not None else self._b0
        swing = self._emax(lo + 1, i1 - 1) >= self.swing_min
        self._last = [onset, x[1], float(i1), float(i2), float(on_idx)]
        if not swing:
            return  # standing, shuffling: a new reference stance but no step
        if last is None:
            period = math.nan
        else:
            period = onset - last[0]
        after_rest = not (0.0 < period <= self.max_period_s)
        if after_rest:
            t_prev_end = last[1] if last is not None else math.nan
            swing_t = onset - t_prev_end if math.isfinite(t_prev_end) else self.min_period_s
            period = max(self.min_period_s, min(swing_t, self.max_period_s) + 0.25)  # nominal stance after a rest
        else:
            self._periods.append(period)
            self._periods = self._periods[-9:]
        first = on_idx - int(round(period * self.rate_hz))  # the step's own samples only (not a rest before it)
        if last is not None:
            first = max(first, int(last[4]))
        a = max(first - self._b0, 0)
        b = max(min(on_idx - self._b0, self._bm.size), a)
        m = self._bm[a:b]
        ev = StepEvent(t_s=onset, period_s=period, f_s=1.0 / period,
                       acc_mean=float(m.mean()) if m.size else math.nan,
                       acc_max=float(m.max()) if m.size else math.nan,
                       acc_min=float(m.min()) if m.size else math.nan,
                       acc_stance=(x[6], x[7], x[8]), after_rest=after_rest, index=self._n_events)
        self._n_events += 1
        out.append(ev)

    def _force(self, t_now: float, out: list[StepEvent]) -> None:
        """Latency bound reached for the pending candidate: decide its competitors on what is available."""
        p = self._pend
        assert p is not None
        w1 = self._w - 1
        lim = p[0] + max(self.min_period_s, self.refractory_frac * self._period())
        early = [c for c in self._await if self._t(int(c[_I_FIRST]) - w1) < lim]
        self._await = [c for c in self._await if self._t(int(c[_I_FIRST]) - w1) >= lim]
        r = self._run
        if r is not None and not r[_EMIT] and self._t(int(r[_I_FIRST]) - w1) < lim:
            early.append(r[:_EMIT])
            r[_EMIT] = 1.0
        for c in early:
            self._select(c, out)
        if self._pend is not None and t_now - self._pend[0] >= self.max_latency_s:
            self._confirm(out)

    @property
    def latency_s(self) -> float:
        """Bound on (input time when a step is emitted) - (its onset) [s]: ``max_latency_s`` + filter delay."""
        return self.max_latency_s + self._delay / self.rate_hz

    def _end_run(self, r: list[float]) -> None:
        """A quiet stretch ended: it becomes a candidate, or (already a candidate) its selected stance ends now."""
        if not r[_EMIT]:
            self._await.append(r[:_EMIT])
            return
        for c in ([self._pend] if self._pend is not None else []) + self._await:
            if int(c[4] if len(c) > 8 else c[_I_FIRST]) == int(r[_I_FIRST]):
                return  # still undecided: its end is not needed yet (decided on the first part)
        last = self._last
        if last is not None and int(last[2]) == int(r[_I_FIRST]):
            last[1] = self._t(int(r[_I_LAST]) - (self._w - 1))  # the stance really ended here
            last[3] = r[_I_LAST]

    def _try_confirm(self, t_cur_on: float, out: list[StepEvent]) -> None:
        """Confirm the pending candidate once no competitor within the refractory period can still arrive."""
        p = self._pend
        if p is None:
            return
        lim = p[0] + max(self.min_period_s, self.refractory_frac * self._period())
        if t_cur_on < lim:
            return
        w1 = self._w - 1
        if self._run is not None and not self._run[_EMIT] and self._t(int(self._run[_I_FIRST]) - w1) < lim:
            return
        if any(self._t(int(c[_I_FIRST]) - w1) < lim for c in self._await):
            return
        self._confirm(out)

    # -- streaming -----------------------------------------------------------------------------------------
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
            Steps whose stance was decided within this chunk (latency: refractory period + ``context_s``).
        """
        t_s = np.asarray(t_s, dtype=np.float64).reshape(-1)
        acc = np.asarray(acc, dtype=np.float64).reshape(-1, 3)
        if t_s.size == 0:
            return []
        af = self._fir.process(acc)
        if self._count == 0 and self._t_hist.size == 0:
            self._t_hist = np.repeat(t_s[:1], self._delay)  # matches the FIR's replicated start
        t_all = np.concatenate([self._t_hist, t_s])
        t_out = t_all[: t_s.size]  # time of the input at the centre of the filter
        self._t_hist = t_all[max(t_all.size - self._delay, 0):] if self._delay else t_all[:0]
        return self._process(t_out, af)

    def flush(self) -> list[StepEvent]:
        """End of the stream: decide the last stance (the foot is taken to stay as it last was).

        The filter delay, the statistic window and the look-ahead are filled with the last sample held
        still; the pending candidate is then final. Call once, after the last :meth:`feed`.
        """
        if self._flushed or self._count == 0:
            return []
        self._flushed = True
        n_pad = self._delay + self._w + self._n_ctx + 1
        last_in = self._fir._hist[-1:] if self._fir._hist is not None and self._fir._hist.size else self._win[-1:]
        dt = 1.0 / self.rate_hz
        t_last = float(self._t_hist[-1]) if self._t_hist.size else float(self._bt[-1])
        t_pad = t_last + dt * np.arange(1, n_pad + 1)
        af = self._fir.process(np.repeat(last_in, n_pad, axis=0))
        t_all = np.concatenate([self._t_hist, t_pad])
        out = self._process(t_all[:n_pad], af)
        if self._run is not None:
            self._end_run(self._run)
            self._run = None
        for c in self._await:
            self._select(c, out)
        self._await = []
        if self._pend is not None:
            self._confirm(out)
        return out

    def _process(self, t_out: np.ndarray, af: np.ndarray) -> list[StepEvent]:
        """Statistic, candidates and selection for filtered samples ``af`` stamped ``t_out``."""
        n = t_out.size
        w = self._w
        events: list[StepEvent] = []
        mag = np.sqrt(np.einsum("ij,ij->i", af, af))
        # append to the sample buffer (global indices count .. count+n-1)
        self._bt = np.concatenate([self._bt, t_out])
        self._be = np.concatenate([self._be, mag - G0])
        self._bm = np.concatenate([self._bm, mag])
        win = np.concatenate([self._win, af])
        off = self._win.shape[0]
        # statistic of every new sample whose window is complete (vectorised)
        q = np.full(n, math.inf)
        mu = np.zeros((n, 3))
        k0 = max(0, (w - 1) - self._count)  # first new sample with a complete window
        if k0 < n:
            seg = np.lib.stride_tricks.sliding_window_view(win[off + k0 + 1 - w:], w, axis=0)  # (m, 3, w)
            mu_k = seg.mean(axis=2)
            var = ((seg - mu_k[:, :, None]) ** 2).sum(axis=1).mean(axis=1)
            q[k0:] = np.sqrt(var + (np.sqrt(np.einsum("ij,ij->i", mu_k, mu_k)) - G0) ** 2)
            mu[k0:] = mu_k
        thr = self.stance_threshold
        # a long stretch is decided within the latency bound: onset + window + n_long + look-ahead <= bound
        n_long = max(2, min(int(round(self.long_stance_s * self.rate_hz)),
                            int((self.max_latency_s - self.context_s) * self.rate_hz) - w))
        ql = q.tolist()
        mul = [tuple(r) for r in mu.tolist()]
        w1 = w - 1
        base = self._count
        bt = self._bt
        b0 = self._b0
        for k in range(n):
            i = base + k
            qk = ql[k]
            if qk < thr:
                r = self._run
                if r is None:
                    m = mul[k]
                    self._run = [float(i), float(i), qk, 1.0, m[0], m[1], m[2], 0.0]
                else:
                    r[_I_LAST] = float(i)
                    r[_N] += 1.0
                    if qk < r[_Q]:
                        r[_Q] = qk
                    if not r[_EMIT] and r[_N] >= n_long:
                        # the foot stays still (standing): this stance competes now, not when walking resumes
                        self._await.append(r[:_EMIT])
                        r[_EMIT] = 1.0
            else:
                if self._run is not None:
                    self._end_run(self._run)
                    self._run = None
                elif self._q2 >= self._q1 < qk and math.isfinite(self._q1) and self._q1 >= thr:
                    m1 = self._mu1
                    self._await.append([float(i - 1), float(i - 1), self._q1, 1.0, m1[0], m1[1], m1[2]])
            self._q2, self._q1 = self._q1, qk
            self._mu1 = mul[k]
            # candidates whose look-ahead is complete
            while self._await and i >= int(self._await[0][_I_LAST]) + self._n_ctx:
                self._select(self._await.pop(0), events)
            if self._pend is not None and i - w1 >= b0:
                self._try_confirm(float(bt[i - w1 - b0]), events)
            if self._pend is not None and float(bt[i - b0]) - self._pend[0] >= self.max_latency_s:
                self._force(float(bt[i - b0]), events)
        self._count += n
        keep = max(w - 1, 0)
        self._win = win[max(win.shape[0] - keep, 0):].copy()
        # trim the buffer: keep what open candidates, the level look-back and the step features need
        back = self._n_lvl + self._n_ctx + w
        req = [self._count - back]  # look-back of candidates still to come
        req.append(self._count - self._keep if self._last is None else max(int(self._last[4]), self._count - self._keep))
        req += [int(c[_I_FIRST]) - back for c in self._await]
        if self._run is not None:
            req.append(int(self._run[_I_FIRST]) - back)
        if self._pend is not None:
            req.append(int(self._pend[4]) - back)
        cut = min(req) - self._b0
        if cut > 0:
            self._bt, self._be, self._bm = self._bt[cut:], self._be[cut:], self._bm[cut:]
            self._b0 += cut
        return events

    # -- state ---------------------------------------------------------------------------------------------
    _PARAMS = ("rate_hz", "window_s", "stance_threshold", "swing_min", "refractory_frac", "min_period_s",
               "max_period_s", "fir_cutoff_hz", "fir_length_s", "swing_frac", "min_swing_s", "context_s",
               "level_s", "rel_threshold", "k_duration", "duration_cap_s", "k_quiet", "period_min_s",
               "period_max_s", "default_period_s", "long_stance_s", "max_latency_s")

    def get_state(self) -> dict:
        """Plain-data state for ``energy.codec``."""
        return {
            "params": [getattr(self, p) for p in self._PARAMS],
            "fir": self._fir.get_state(), "t_hist": self._t_hist.copy(), "win": self._win.copy(),
            "b0": self._b0, "bt": self._bt.copy(), "be": self._be.copy(), "bm": self._bm.copy(),
            "count": self._count, "q": [self._q1, self._q2], "mu1": list(self._mu1),
            "run": None if self._run is None else list(self._run),
            "await": [list(c) for c in self._await],
            "pend": None if self._pend is None else list(self._pend),
            "last": None if self._last is None else list(self._last),
            "periods": list(self._periods), "n_events": self._n_events, "flushed": self._flushed,
        }

    @classmethod
    def from_state(cls, d: dict) -> StepSegmenter:
        """Rebuild from :meth:`get_state` output."""
        obj = cls(*[float(v) for v in d["params"]])
        obj._fir = FirFilter.from_state(d["fir"])
        obj._t_hist = np.asarray(d["t_hist"], dtype=np.float64).copy()
        obj._win = np.asarray(d["win"], dtype=np.float64).reshape(-1, 3).copy()
        obj._b0 = int(d["b0"])
        obj._bt = np.asarray(d["bt"], dtype=np.float64).reshape(-1).copy()
        obj._be = np.asarray(d["be"], dtype=np.float64).reshape(-1).copy()
        obj._bm = np.asarray(d["bm"], dtype=np.float64).reshape(-1).copy()
        obj._count = int(d["count"])
        obj._q1, obj._q2 = float(d["q"][0]), float(d["q"][1])
        obj._mu1 = tuple(float(v) for v in d["mu1"])  # type: ignore[assignment]
        obj._run = None if d["run"] is None else [float(v) for v in d["run"]]
        obj._await = [[float(v) for v in c] for c in d["await"]]
        obj._pend = None if d["pend"] is None else [float(v) for v in d["pend"]]
        obj._last = None if d["last"] is None else [float(v) for v in d["last"]]
        obj._periods = [float(v) for v in d["periods"]]
        obj._n_events = int(d["n_events"])
        obj._flushed = bool(d["flushed"])
        return obj
