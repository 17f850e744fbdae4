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
   needs a swing of at least ``swing_frac`` periods (``min_swing_s`` at least) after the previous stance;
   two still stances (``q < stance_threshold``) with such a swing between them do not compete whatever the
   refractory period (it lags a change of pace, e.g. walk -> run: :func:`_k_parted`).

A selected candidate is a step when a swing (``|a| - g`` peak above ``swing_min``) separates it from the
previous one. Decisions are final once no competing candidate can still arrive, i.e. ``refractory`` plus
``context_s`` after the onset (the latency of the step events).

The statistic and the candidate/selection state machine run in one compiled (numba) kernel per chunk with
the state in small float arrays (:func:`_k_process`); equal, event for event, to the pure-Python version it
replaced (checked on every gdin recording at 20, 25, 50 Hz and native rate). Per-step features for the
step-length models: step frequency f_s = 1 / period (004 eq. 15), mean, maximum
and minimum of the filtered acceleration magnitude over the step. The gyroscope, when on, is not used, so
the events do not change when the engine switches it. Chunk-invariant and serialisable.

Memory is bounded while the person stands: a quiet stretch that has already been decided on keeps only its
start (and the context before it) and the samples near its current end; the samples in between collapse into
one that holds their largest ``|a|`` (:meth:`StepSegmenter._collapse_quiet`), so the state no longer grows with
the time stood and the events stay the same, bit for bit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit

from models.fir import FirFilter, fir_advance, hamming_lowpass

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
        Time since the previous stance onset [s] (after a rest: swing time plus a nominal stance; after a
        stance longer than a stride, i.e. a short pause: the running stride-period estimate).
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
    paused : bool
        True when a short pause preceded the step: its own period is not measurable and ``period_s`` is the
        running stride-period estimate (the pace before the pause).
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
    paused: bool = False

    def to_row(self) -> list[float]:
        """The event as the segmentation kernel's row of plain numbers (also the engine state's form):
        ``[t_s, period_s, f_s, acc_mean, acc_max, acc_min, mx, my, mz, rest, index]``, ``rest`` 1 after a rest,
        2 after a short pause, else 0."""
        rest = 1.0 if self.after_rest else (2.0 if self.paused else 0.0)
        return [self.t_s, self.period_s, self.f_s, self.acc_mean, self.acc_max, self.acc_min, *self.acc_stance, rest,
                float(self.index)]

    @classmethod
    def from_row(cls, r: Sequence[float]) -> StepEvent:
        """Inverse of :meth:`to_row`."""
        return cls(float(r[0]), float(r[1]), float(r[2]), float(r[3]), float(r[4]), float(r[5]),
                   (float(r[6]), float(r[7]), float(r[8])), 0.5 < r[9] < 1.5, int(r[10]), r[9] > 1.5)


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
        self._n_long = max(2, min(int(round(self.long_stance_s * self.rate_hz)),
                                  int((self.max_latency_s - self.context_s) * self.rate_hz) - self._w))
        # samples a decided quiet stretch keeps before its newest one (see _collapse_quiet): the trim's own
        # look-back (so its first cut after the stretch ends drops the collapsed part whole) and the longest
        # step a stance after the stretch can measure its features over (nominal stance after a rest included)
        longest_step = max(self.min_period_s, self.max_period_s + _REST_STANCE_S)
        self._tail = max(self._keep, self._n_lvl + self._n_ctx + self._w,
                         self._w + int(math.ceil(longest_step * self.rate_hz))) + 2
        self._pf = np.array([self.stance_threshold, self.swing_min, self.refractory_frac, self.min_period_s,
                             self.max_period_s, self.swing_frac, self.min_swing_s, self.rel_threshold,
                             self.k_duration, self.duration_cap_s, self.k_quiet, self.period_min_s,
                             self.period_max_s, self.default_period_s, self.max_latency_s, self.rate_hz])
        self._pi = np.array([self._w, self._n_ctx, self._n_lvl, self._n_long], dtype=np.int64)
        self._t_hist = np.zeros(0, dtype=np.float64)  # input times awaiting the filter delay
        self._win = np.zeros((0, 3))  # last w-1 filtered samples
        # per filtered sample (index b0 + j; indices count the samples, except that a long decided quiet
        # stretch counts as its ends plus one sample, see _collapse_quiet): time [s] ...
        self._bt = np.zeros(0)
        self._bm = np.zeros(0)  # ... and |a| [m/s^2]
        self._fs = np.array([np.inf, np.inf, 0.0, 0.0, 0.0])
        self._run = np.zeros(9)
        self._aw = np.zeros((_AW_MAX, 7))
        self._pend = np.zeros(11)
        self._last = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -np.inf, np.inf, 0.0])
        self._per = np.zeros(_N_PER)
        self._ist = np.zeros(5, dtype=np.int64)  # count, b0, n_events, n_await, n_periods
        self._flushed = False
        self._compact = True  # collapse long decided quiet stretches (False: the reference, for tests)

    @property
    def window_samples(self) -> int:
        """Samples in one quietness window (``window_s`` at ``rate_hz``, at least 2)."""
        return self._w

    @property
    def latency_s(self) -> float:
        """Bound on (input time when a step is emitted) - (its onset) [s]: ``max_latency_s`` + filter delay."""
        return self.max_latency_s + self._delay / self.rate_hz

    @property
    def final_before_s(self) -> float:
        """Every step with an onset before this time [s] has been emitted (input clock).

        The earliest onset any candidate can still have: the pending one, those awaiting their look-ahead, the
        quiet stretch in progress, and one a later sample can open (a local minimum at the newest statistic,
        one sample back). Never more than :attr:`latency_s` behind the newest input; through the engine's 200 ->
        25 Hz decimation 0.6 s at the median on the synthetic mixed day.
        """
        if self._flushed:
            return math.inf
        count, b0 = int(self._ist[0]), int(self._ist[1])
        if count == 0 or self._bt.size == 0:
            return -math.inf
        w1 = self._w - 1
        first = count - 1 - w1  # statistic index of the earliest candidate a later sample can open
        if self._run[0] > 0.0 and self._run[8] <= 0.0:
            first = min(first, int(self._run[1]))
        if self._ist[3]:
            first = min(first, int(min(self._aw[: self._ist[3], 0].tolist())))
        t = float(self._bt[min(max(first - w1 - b0, 0), self._bt.size - 1)])
        if self._pend[0] > 0.0:
            t = min(t, float(self._pend[1]))
        return t

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
            Steps whose stance was decided within this chunk (latency at most :attr:`latency_s`).
        """
        t_s = np.asarray(t_s, dtype=np.float64).reshape(-1)
        if t_s.size == 0:
            return []
        acc = np.asarray(acc, dtype=np.float64).reshape(-1, 3)
        hist, n = self._fir.history, t_s.size
        if (hist is not None and 0 < hist.shape[0] <= n and self._delay <= n and self._t_hist.size == self._delay
                and self._win.shape[0] == self._w - 1):
            # the steady state (every history full, a chunk at least as long as each): the filter, the buffer's
            # extension and the kernel in one compiled call, the histories advanced in place
            self._bt, self._bm, ev, n_ev = _k_feed(hist, self._fir.taps, self._t_hist, t_s, acc, self._win, self._bt,
                                                   self._bm, self._fs, self._run, self._aw, self._pend, self._last,
                                                   self._per, self._ist, self._pf, self._pi)
            return self._trim(ev, n_ev)
        af = self._fir.process(acc)
        if self._ist[0] == 0 and self._t_hist.size == 0:
            self._t_hist = np.repeat(t_s[:1], self._delay)  # matches the FIR's replicated start
        t_all = np.concatenate([self._t_hist, t_s])
        t_out = t_all[: t_s.size]  # time of the input at the centre of the filter
        self._t_hist = t_all[t_all.size - self._delay:] if self._delay else t_all[:0]
        return self._process(t_out, af)

    def flush(self) -> list[StepEvent]:
        """End of the stream: decide the last stance (the foot is taken to stay as it last was).

        The filter delay, the statistic window and the look-ahead are filled with the last sample held
        still; the pending candidate is then final. Call once, after the last :meth:`feed`.
        """
        if self._flushed or self._ist[0] == 0:
            return []
        self._flushed = True
        n_pad = self._delay + self._w + self._n_ctx + 1
        last_in = self._fir._hist[-1:] if self._fir._hist is not None and self._fir._hist.size else self._win[-1:]
        t_last = float(self._t_hist[-1]) if self._t_hist.size else float(self._bt[-1])
        t_pad = t_last + np.arange(1, n_pad + 1) / self.rate_hz
        af = self._fir.process(np.repeat(last_in, n_pad, axis=0))
        out = self._process(np.concatenate([self._t_hist, t_pad])[:n_pad], af)
        ev = np.empty((_AW_MAX + 2, 11))
        n_ev = _k_finish(self._run, self._aw, self._bt, self._bm, self._pend, self._last, self._per, self._ist,
                         self._pf, self._pi, ev)
        return out + self._events(ev, n_ev)

    @staticmethod
    def _events(ev: np.ndarray, n_ev: int) -> list[StepEvent]:
        return [StepEvent.from_row(r) for r in ev[:n_ev].tolist()]

    def _process(self, t_out: np.ndarray, af: np.ndarray) -> list[StepEvent]:
        """Statistic, candidates and selection (compiled kernel) for filtered samples ``af`` stamped ``t_out``."""
        n = t_out.size
        # the buffer extended by this chunk's times and |a| (one compiled pass instead of a norm and two
        # concatenations)
        nb = self._bt.size
        bt, bm = np.empty(nb + n), np.empty(nb + n)
        _k_append(self._bt, self._bm, t_out, af, bt, bm)
        self._bt, self._bm = bt, bm
        win = np.concatenate([self._win, af])
        ev = np.empty((n // 2 + 8, 11))
        n_ev = _k_process(win, t_out, self._bt, self._bm, self._fs, self._run, self._aw, self._pend, self._last,
                          self._per, self._ist, self._pf, self._pi, ev)
        self._win = win[max(win.shape[0] - (self._w - 1), 0):].copy()
        return self._trim(ev, n_ev)

    def _trim(self, ev: np.ndarray, n_ev: int) -> list[StepEvent]:
        """After a chunk: trim the buffer and collapse a long quiet stretch; the chunk's ``n_ev`` events (rows of
        ``ev``)."""
        # trim the buffer: keep what open candidates, the level look-back and the step features need
        count, b0 = int(self._ist[0]), int(self._ist[1])
        back = self._n_lvl + self._n_ctx + self._w
        need = min(count - back, count - self._keep if self._last[0] <= 0.0
                   else max(int(self._last[5]), count - self._keep))
        if self._ist[3]:
            need = min(need, int(min(self._aw[: self._ist[3], 0].tolist())) - back)
        if self._run[0] > 0.0:
            need = min(need, int(self._run[1]) - back)
        if self._pend[0] > 0.0:
            need = min(need, int(self._pend[5]) - back)
        cut = need - b0
        if cut > 0:
            last = self._last
            lo = int(last[4]) + 1 - b0
            if last[0] > 0.0 and lo < cut:
                # the next stance's swing test spans every sample since the last stance's end (a stand with a
                # shuffle in it outlasts the buffer): keep the largest |a| of those the cut drops
                last[6] = max(last[6], float(self._bm[max(lo, 0):cut].max()))
            self._bt, self._bm = self._bt[cut:], self._bm[cut:]
            self._ist[1] = b0 + cut
        self._collapse_quiet()
        return self._events(ev, n_ev) if n_ev else []

    def _collapse_quiet(self) -> None:
        """Bound the buffer during a long quiet stretch (standing) without changing any event.

        The trim above keeps every sample from an open quiet stretch's first one (it may still become a
        candidate). Once the stretch has competed (``run[8]``) and nothing is waiting (no candidate, none
        pending), the kernel reads the samples of its middle only through one maximum: the swing test of the next
        stance after it (``_k_emax`` from the previous stance's end to that stance, which spans the whole
        stretch when the stretch itself was not selected). Every other access lies before ``g0`` (the stretch's
        start, its context and the stored stance indices) or within ``self._tail`` samples of the newest one
        (the stretch's end, and the next stance's impacts, level look-back and step features). So the samples
        ``[g0, count - tail)`` are replaced by one holding their largest ``|a|``, and the indices after them
        (the sample count, the stretch's last index) move down by the number removed; the trim's first cut
        after the stretch ends lies beyond that sample (``tail`` covers its look-back), so from then on the
        buffer is what it would have been.

        Samples kept: ``b0 .. g0`` (the level and context look-back before the stretch and its first
        ``long_stance_s``, ~2.5 s) + 1 + ``tail`` (~4.7 s): 184 at 25 Hz, 1447 at 200 Hz with the default
        parameters, whatever the time stood (the buffer of a walk holds up to ~175 / ~1400). A state stored
        before the stretches were collapsed restores as it is and is collapsed at the next :meth:`feed`.
        """
        run, last, ist = self._run, self._last, self._ist
        if not self._compact or run[0] <= 0.0 or run[8] <= 0.0 or ist[3] or self._pend[0] > 0.0:
            return
        count, b0 = int(ist[0]), int(ist[1])
        g0 = int(run[1]) + 1  # after every index the state refers to (none refers to the stretch's middle)
        if last[0] > 0.0:
            g0 = max(g0, int(last[3]) + 1, int(last[4]) + 1, int(last[5]) + 1)
        g1 = count - self._tail
        if g1 - g0 < 2:
            return
        p0, p1 = g0 - b0, g1 - b0
        bm, bt = self._bm, self._bt
        self._bm = np.concatenate([bm[:p0], [bm[p0:p1].max()], bm[p1:]])
        self._bt = np.concatenate([bt[:p0], [bt[p1 - 1]], bt[p1:]])  # never read (only the maximum is)
        shift = g1 - g0 - 1
        ist[0] = count - shift
        run[2] -= shift

    # -- state ---------------------------------------------------------------------------------------------
    _PARAMS = ("rate_hz", "window_s", "stance_threshold", "swing_min", "refractory_frac", "min_period_s",
               "max_period_s", "fir_cutoff_hz", "fir_length_s", "swing_frac", "min_swing_s", "context_s",
               "level_s", "rel_threshold", "k_duration", "duration_cap_s", "k_quiet", "period_min_s",
               "period_max_s", "default_period_s", "long_stance_s", "max_latency_s")
    _ARRAYS = ("t_hist", "win", "bt", "bm", "fs", "run", "aw", "pend", "last", "per", "ist")

    def get_state(self) -> dict:
        """Plain-data state for ``energy.codec``."""
        d: dict = {"params": [getattr(self, p) for p in self._PARAMS], "fir": self._fir.get_state(),
                   "flushed": self._flushed}
        for a in self._ARRAYS:
            d[a] = getattr(self, "_" + a).copy()
        return d

    @classmethod
    def from_state(cls, d: dict) -> StepSegmenter:
        """Rebuild from :meth:`get_state` output.

        A state written by the earlier threshold-only segmenter (no ``"ist"``; its first nine parameters are
        the same) restores as a fresh detector with that filter history: at most the step in flight is lost.
        """
        obj = cls(*[float(v) for v in d["params"]])
        obj._fir = FirFilter.from_state(d["fir"])
        if "ist" not in d:
            return obj
        obj._flushed = bool(d["flushed"])
        for a in cls._ARRAYS:
            ref = getattr(obj, "_" + a)
            setattr(obj, "_" + a, np.asarray(d[a], dtype=ref.dtype).reshape((-1,) + ref.shape[1:]).copy())
        if obj._last.size < 7:  # stored before the dropped samples' maximum was kept
            obj._last = np.concatenate([obj._last, [-np.inf]])
        if obj._last.size < 8:  # stored before the stance's statistic was kept: not taken as still
            obj._last = np.concatenate([obj._last, [np.inf]])
        if obj._last.size < 9:  # stored before a paused stride was marked: not marked
            obj._last = np.concatenate([obj._last, [0.0]])
        return obj


# -- compiled kernel (numba) ------------------------------------------------------------------------------
# State arrays (plain float64/int64 so the state serialises as it is):
#   fs   [q1, q2, mu1x, mu1y, mu1z]                 statistic of the previous two samples, window mean of the last
#   run  [valid, i_first, i_last, q, n, mx, my, mz, emitted]   quiet stretch in progress
#   aw   (AW_MAX, 7) [i_first, i_last, q, n, mx, my, mz]        candidates waiting for their look-ahead
#   pend [valid, t_on, t_end, q, score, i_first, i_last, mx, my, mz, lim]   best candidate of the refractory window
#   last [valid, t_on, t_end, i_first, i_last, onset_idx, emax, q, paused]  last selected stance; emax: largest |a|
#        of the samples after its end that the buffer dropped (the next swing test spans them); q: its statistic;
#        paused: 1 when the stride that ended there was taken as one after a short pause (_k_confirm)
#   per  (9,) ring of the last stride periods [s]
#   ist  [count, b0, n_events, n_await, n_periods]
# Parameters: pf [thr, swing_min, refr_frac, min_period, max_period, swing_frac, min_swing, rel_thr, k_dur, dur_cap,
#                 k_quiet, per_min, per_max, default_per, max_lat, rate]; pi [w, n_ctx, n_lvl, n_long]
# Events rows: StepEvent.to_row's layout
_AW_MAX = 64
_N_PER = 9
_REST_STANCE_S = 0.25  # nominal stance added to the swing time of the first step after a rest [s] (_k_confirm)
_PAUSE_STANCE_FRAC = 0.75  # a stance longer than this fraction of the stride period is a pause (_k_confirm)


@njit(cache=True)
def _k_append(bt, bm, t_out, af, bt_new, bm_new):
    """``bt_new = concatenate([bt, t_out])`` and ``bm_new = concatenate([bm, |af|])`` (preallocated, ``len(bt) +
    len(t_out)`` rows)."""
    nb = bt.size
    for i in range(nb):
        bt_new[i] = bt[i]
        bm_new[i] = bm[i]
    for i in range(t_out.size):
        x, y, z = af[i, 0], af[i, 1], af[i, 2]
        bt_new[nb + i] = t_out[i]
        bm_new[nb + i] = math.sqrt(x * x + y * y + z * z)


@njit(cache=True)
def _k_t(bt, b0, i):
    j = i - b0
    if j < 0:
        j = 0
    if j > bt.size - 1:
        j = bt.size - 1
    return bt[j]


@njit(cache=True)
def _k_emax(bm, b0, lo, hi):
    a = max(lo - b0, 0)
    b = min(hi - b0 + 1, bm.size)
    if b <= a:
        return -np.inf
    m = bm[a]
    for j in range(a + 1, b):
        if bm[j] > m:
            m = bm[j]
    return m - G0


@njit(cache=True)
def _k_period(per, ist, pf):
    n = ist[4]
    if n < 3:
        return pf[13]
    k = min(n, 5)
    tmp = np.empty(k)
    for j in range(k):  # the last k periods of the ring (oldest first)
        tmp[j] = per[(n - k + j) % _N_PER]
    tmp.sort()
    p = tmp[k // 2]
    return min(max(p, pf[11]), pf[12])


@njit(cache=True)
def _k_confirm(bt, bm, pend, last, per, ist, pf, pi, ev, n_ev):
    pend[0] = 0.0
    onset = pend[1]
    i1 = int(pend[5])
    i2 = int(pend[6])
    b0 = ist[1]
    on_idx = i1 - (pi[0] - 1)
    had_last = last[0] > 0.0
    lo = int(last[4]) if had_last else b0
    last_on, last_end, last_onidx = last[1], last[2], int(last[5])
    paused_before = last[8] > 0.5
    swing = max(_k_emax(bm, b0, lo + 1, i1 - 1), last[6] - G0) >= pf[1]
    last[0] = 1.0
    last[1] = onset
    last[2] = pend[2]
    last[3] = float(i1)
    last[4] = float(i2)
    last[5] = float(on_idx)
    last[6] = -np.inf
    last[7] = pend[3]
    last[8] = 0.0
    if not swing:
        return n_ev  # standing, shuffling: a new reference stance but no step
    period = onset - last_on if had_last else np.nan
    after_rest = not (period > 0.0 and period <= pf[4])
    paused = False
    p_est = _k_period(per, ist, pf)
    stance = last_end - last_on
    if not after_rest and (stance > p_est or (stance > _PAUSE_STANCE_FRAC * p_est and not paused_before)):
        # the previous stance lasted most of a stride (a foot-flat takes about half of one): a pause (shorter than
        # max_period) that the time since its onset includes (a 1.7-s stop made a 1.15-s walking stride 2.3 s
        # long, f_s 0.44 Hz, and the fitted cadence range of 004 Table 2 (ii) took it in; a 1-s stop in the
        # synthetic mixed day, seed 24, a 1.16-s stride 1.60 s long, placed 0.87 m for 1.40 m). The stride's own
        # period is not measurable; it is taken at the pace before the pause (the estimate) and kept out of the
        # period estimate. Twice in a row, with a stance shorter than the estimate, it is the pace that slowed:
        # measured (else a sudden slow-down would never reach the estimate).
        period = p_est
        last[8] = 1.0
        paused = True
    elif after_rest:
        if had_last and np.isfinite(last_end):
            swing_t = onset - last_end
        else:
            swing_t = pf[3]
        period = max(pf[3], min(swing_t, pf[4]) + _REST_STANCE_S)  # nominal stance after a rest
    else:
        per[ist[4] % _N_PER] = period
        ist[4] += 1
    first = on_idx - int(round(period * pf[15]))  # the step's own samples only (not a rest before it)
    if had_last:
        first = max(first, last_onidx)
    a = max(first - b0, 0)
    b = max(min(on_idx - b0, bm.size), a)
    row = ev[n_ev]
    row[0] = onset
    row[1] = period
    row[2] = 1.0 / period
    if b > a:
        s = 0.0
        mx = bm[a]
        mn = bm[a]
        for j in range(a, b):
            v = bm[j]
            s += v
            if v > mx:
                mx = v
            if v < mn:
                mn = v
        row[3] = s / (b - a)
        row[4] = mx
        row[5] = mn
    else:
        row[3] = np.nan
        row[4] = np.nan
        row[5] = np.nan
    row[6] = pend[7]
    row[7] = pend[8]
    row[8] = pend[9]
    row[9] = 1.0 if after_rest else (2.0 if paused else 0.0)
    row[10] = float(ist[2])
    ist[2] += 1
    return n_ev + 1


@njit(cache=True)
def _k_parted(end0, q0, i_end0, emax0, t_on, i1, sw, bm, b0, pf):
    """Two still stances with a swing between them: two strides, whatever the refractory period says.

    The refractory period scales with the running stride-period estimate (median of the last periods), which
    lags a change of pace: after a walk (1.15-1.35 s) the first run stances (0.74 s apart) fall inside the
    walking refractory window (0.6 periods), one of each pair is suppressed, and the merged strides (two run
    strides measured as one walk-like period) keep the estimate there (demo seed 23 at 25 Hz: every other run
    stride lost). The refractory period is there for stances without a measurable end (the rolling stance at
    a fast pace; a near-still moment of the swing lies about half a period after its onset). A stance that is
    still (statistic below ``stance_threshold``, the sensor-noise scale) does have an end, and the swing rule
    measured from that end (at least ``max(min_swing_s, swing_frac * period)``, with ``|a| - g`` above
    ``swing_min``) already tells a stance after the swing from a moment within it; a candidate that is still
    too is then the next stride's stance, not a competitor.

    Parameters
    ----------
    end0 : float
        End of the earlier stance [s].
    q0 : float
        Its statistic [m/s^2] (at or above ``stance_threshold``: not still, the rule does not apply).
    i_end0 : int
        Its last statistic index.
    emax0 : float
        Largest ``|a|`` [m/s^2] of the samples after it that the buffer dropped (``-inf``: none).
    t_on : float
        Onset of the (still) candidate [s].
    i1 : int
        Its first statistic index.
    sw : float
        Shortest swing [s].

    Returns
    -------
    bool
        True when the earlier stance was still and a swing separates the two.
    """
    if not (q0 < pf[0]) or t_on - end0 < sw:
        return False
    return max(_k_emax(bm, b0, i_end0 + 1, i1 - 1), emax0 - G0) >= pf[1]


@njit(cache=True)
def _k_select(c, bt, bm, pend, last, per, ist, pf, pi, ev, n_ev, i_now):
    """Score a candidate and run the non-maximum suppression (returns the new event count).

    ``i_now`` is the newest sample index processed: the look-ahead reads no sample after it (a candidate decided by
    the latency bound before its look-ahead completed read the rest of the chunk, so the events depended on where
    the stream was cut)."""
    b0 = ist[1]
    i1 = int(c[0])
    i2 = int(c[1])
    w1 = pi[0] - 1
    t_on = _k_t(bt, b0, i1 - w1)
    t_end = _k_t(bt, b0, i2 - w1)
    pre = _k_emax(bm, b0, i1 - pi[1], i1)  # heel strike before a stance
    post = _k_emax(bm, b0, i2, min(i2 + pi[1], i_now))  # push-off after it (or the next heel strike after a pause)
    lvl = _k_emax(bm, b0, i1 - pi[2], i1)  # recent step energy
    q = c[2]
    if q > max(pf[0], pf[7] * lvl):
        return n_ev
    dur = c[3] / pf[15]
    score = pf[8] * min(dur, pf[9]) + (pre - post) - pf[10] * q
    p = _k_period(per, ist, pf)
    refr = max(pf[3], pf[2] * p)
    sw = max(pf[6], pf[5] * p)  # shortest swing [s]
    still = q < pf[0]
    if pend[0] > 0.0 and (t_on - pend[1] >= refr or (still and _k_parted(pend[2], pend[3], int(pend[6]), -np.inf,
                                                                          t_on, i1, sw, bm, b0, pf))):
        n_ev = _k_confirm(bt, bm, pend, last, per, ist, pf, pi, ev, n_ev)
    if pend[0] <= 0.0:
        if last[0] > 0.0 and (t_on - last[1] < refr or t_on - last[2] < sw):
            if not (still and t_on - last[1] >= pf[3]
                    and _k_parted(last[2], last[7], int(last[4]), last[6], t_on, i1, sw, bm, b0, pf)):
                return n_ev
    elif score <= pend[4]:
        return n_ev
    pend[0] = 1.0
    pend[1] = t_on
    pend[2] = t_end
    pend[3] = q
    pend[4] = score
    pend[5] = float(i1)
    pend[6] = float(i2)
    pend[7] = c[4]
    pend[8] = c[5]
    pend[9] = c[6]
    pend[10] = t_on + refr  # end of its refractory window
    return n_ev


@njit(cache=True)
def _k_await_push(aw, ist, i_first, i_last, q, n, mx, my, mz):
    k = ist[3]
    if k >= _AW_MAX:  # cannot happen at walking rates; drop the oldest rather than overflow
        for j in range(1, k):
            aw[j - 1, :] = aw[j, :]
        k -= 1
    aw[k, 0] = i_first
    aw[k, 1] = i_last
    aw[k, 2] = q
    aw[k, 3] = n
    aw[k, 4] = mx
    aw[k, 5] = my
    aw[k, 6] = mz
    ist[3] = k + 1


@njit(cache=True)
def _k_end_run(run, aw, pend, last, bt, ist, pi):
    """A quiet stretch ended: it becomes a candidate, or (already one) the selected stance ends here."""
    if run[8] <= 0.0:
        _k_await_push(aw, ist, run[1], run[2], run[3], run[4], run[5], run[6], run[7])
        run[0] = 0.0
        return
    run[0] = 0.0
    i_first = int(run[1])
    if pend[0] > 0.0 and int(pend[5]) == i_first:
        return  # still undecided: decided on its first part
    for j in range(ist[3]):
        if int(aw[j, 0]) == i_first:
            return
    if last[0] > 0.0 and int(last[3]) == i_first:
        last[2] = _k_t(bt, ist[1], int(run[2]) - (pi[0] - 1))  # the stance really ended here
        last[4] = run[2]


@njit(cache=True)
def _k_try_confirm(t_cur_on, run, aw, bt, bm, pend, last, per, ist, pf, pi, ev, n_ev):
    lim = pend[10]
    if t_cur_on < lim:
        return n_ev
    w1 = pi[0] - 1
    b0 = ist[1]
    if run[0] > 0.0 and run[8] <= 0.0 and _k_t(bt, b0, int(run[1]) - w1) < lim:
        return n_ev
    for j in range(ist[3]):
        if _k_t(bt, b0, int(aw[j, 0]) - w1) < lim:
            return n_ev
    return _k_confirm(bt, bm, pend, last, per, ist, pf, pi, ev, n_ev)


@njit(cache=True)
def _k_force(t_now, i_now, run, aw, bt, bm, pend, last, per, ist, pf, pi, ev, n_ev):
    """Latency bound reached for the pending candidate: decide its competitors on what is available."""
    w1 = pi[0] - 1
    b0 = ist[1]
    lim = pend[10]
    early = np.empty((ist[3] + 1, 7))
    ne = 0
    keep = 0
    for j in range(ist[3]):
        if _k_t(bt, b0, int(aw[j, 0]) - w1) < lim:
            early[ne, :] = aw[j, :]
            ne += 1
        else:
            aw[keep, :] = aw[j, :]
            keep += 1
    ist[3] = keep
    if run[0] > 0.0 and run[8] <= 0.0 and _k_t(bt, b0, int(run[1]) - w1) < lim:
        early[ne, :] = run[1:8]
        ne += 1
        run[8] = 1.0
    for j in range(ne):
        n_ev = _k_select(early[j], bt, bm, pend, last, per, ist, pf, pi, ev, n_ev, i_now)
    if pend[0] > 0.0 and t_now - pend[1] >= pf[14]:
        n_ev = _k_confirm(bt, bm, pend, last, per, ist, pf, pi, ev, n_ev)
    return n_ev


@njit(cache=True)
def _k_process(win, t_out, bt, bm, fs, run, aw, pend, last, per, ist, pf, pi, ev):
    """Statistic, candidates and selection for the filtered samples of one chunk; returns the event count.

    ``win`` holds the last ``w - 1`` filtered samples of the previous chunks followed by this chunk's;
    ``bt``/``bm`` are the sample buffer (times, |a|) already extended by this chunk.
    """
    n = t_out.size
    w = pi[0]
    w1 = w - 1
    off = win.shape[0] - n
    thr = pf[0]
    n_ctx = pi[1]
    n_long = pi[3]
    base = ist[0]
    n_ev = 0
    q1 = fs[0]
    q2 = fs[1]
    mux, muy, muz = fs[2], fs[3], fs[4]
    for k in range(n):
        i = base + k
        prev_x, prev_y, prev_z = mux, muy, muz
        qk = np.inf
        if i >= w1:  # window complete: vector variance + squared departure of the mean magnitude from g
            lo = off + k - w1
            sx = 0.0
            sy = 0.0
            sz = 0.0
            ss = 0.0
            for j in range(lo, lo + w):
                x0, x1, x2 = win[j, 0], win[j, 1], win[j, 2]
                sx += x0
                sy += x1
                sz += x2
                ss += x0 * x0 + x1 * x1 + x2 * x2
            mux, muy, muz = sx / w, sy / w, sz / w
            mu2 = mux * mux + muy * muy + muz * muz
            var = max(ss / w - mu2, 0.0)
            qk = math.sqrt(var + (math.sqrt(mu2) - G0) ** 2)
        else:
            mux, muy, muz = 0.0, 0.0, 0.0
        if qk < thr:
            if run[0] <= 0.0:
                run[0] = 1.0
                run[1] = float(i)
                run[2] = float(i)
                run[3] = qk
                run[4] = 1.0
                run[5] = mux
                run[6] = muy
                run[7] = muz
                run[8] = 0.0
            else:
                run[2] = float(i)
                run[4] += 1.0
                if qk < run[3]:
                    run[3] = qk
                if run[8] <= 0.0 and run[4] >= n_long:
                    # the foot stays still (standing): this stance competes now, not when walking resumes
                    _k_await_push(aw, ist, run[1], run[2], run[3], run[4], run[5], run[6], run[7])
                    run[8] = 1.0
        elif run[0] > 0.0:
            _k_end_run(run, aw, pend, last, bt, ist, pi)
        elif q2 >= q1 and q1 < qk and q1 >= thr:
            _k_await_push(aw, ist, float(i - 1), float(i - 1), q1, 1.0, prev_x, prev_y, prev_z)
        q2 = q1
        q1 = qk
        # candidates whose look-ahead is complete
        while ist[3] > 0 and i >= int(aw[0, 1]) + n_ctx:
            c = aw[0].copy()
            for j in range(1, ist[3]):
                aw[j - 1, :] = aw[j, :]
            ist[3] -= 1
            n_ev = _k_select(c, bt, bm, pend, last, per, ist, pf, pi, ev, n_ev, i)
        if pend[0] > 0.0:
            t_on_cur = _k_t(bt, ist[1], i - w1)
            if i - w1 >= ist[1] and t_on_cur >= pend[10]:
                n_ev = _k_try_confirm(t_on_cur, run, aw, bt, bm, pend, last, per, ist, pf, pi, ev, n_ev)
            if pend[0] > 0.0 and t_out[k] - pend[1] >= pf[14]:
                n_ev = _k_force(t_out[k], i, run, aw, bt, bm, pend, last, per, ist, pf, pi, ev, n_ev)
    fs[0] = q1
    fs[1] = q2
    fs[2] = mux
    fs[3] = muy
    fs[4] = muz
    ist[0] = base + n
    return n_ev


@njit(cache=True)
def _k_feed(hist, taps, t_hist, t_s, acc, win, bt, bm, fs, run, aw, pend, last, per, ist, pf, pi):
    """:meth:`StepSegmenter.feed` of a chunk in the steady state, in one call: the FIR (``hist`` its last ``L - 1``
    inputs, ``taps``) by :func:`models.fir.fir_advance`, the filter delay's times (``t_hist``, the ``delay``
    input times [s] before the chunk's), the buffer's extension (:func:`_k_append`) and :func:`_k_process`.
    ``hist``, ``t_hist`` and ``win`` (the last ``w - 1`` filtered samples) are advanced in place; the caller
    guarantees ``len(t_s)`` at least as long as each. The same values as the array steps of ``feed`` and
    ``_process`` (concatenations and slices). Returns ``(bt, bm, ev, n_ev)``: the extended buffer and the
    chunk's events."""
    n = t_s.size
    af = fir_advance(hist, acc, taps)
    delay = t_hist.size
    t_out = np.empty(n)  # the input time at the centre of the filter: (t_hist + t_s)[:n]
    t_out[:delay] = t_hist
    t_out[delay:] = t_s[:n - delay]
    t_hist[:] = t_s[n - delay:]
    nb = bt.size
    bt_new, bm_new = np.empty(nb + n), np.empty(nb + n)
    _k_append(bt, bm, t_out, af, bt_new, bm_new)
    nw = win.shape[0]
    ext = np.empty((nw + n, 3))
    ext[:nw] = win
    ext[nw:] = af
    ev = np.empty((n // 2 + 8, 11))
    n_ev = _k_process(ext, t_out, bt_new, bm_new, fs, run, aw, pend, last, per, ist, pf, pi, ev)
    win[:] = ext[n:]
    return bt_new, bm_new, ev, n_ev


@njit(cache=True)
def _k_finish(run, aw, bt, bm, pend, last, per, ist, pf, pi, ev):
    """End of stream: the open stretch and the waiting candidates are decided, the pending one confirmed."""
    n_ev = 0
    if run[0] > 0.0:
        _k_end_run(run, aw, pend, last, bt, ist, pi)
    for j in range(ist[3]):
        c = aw[j].copy()
        n_ev = _k_select(c, bt, bm, pend, last, per, ist, pf, pi, ev, n_ev, ist[0] - 1)
    ist[3] = 0
    if pend[0] > 0.0:
        n_ev = _k_confirm(bt, bm, pend, last, per, ist, pf, pi, ev, n_ev)
    return n_ev
