"""Hamming-window linear-phase FIR filters and the anti-aliasing decimator (004 Section 2.2 and 4.3).

The step-length model of 004 eq. (15) uses acceleration filtered by a Hamming-window, linear-phase FIR
filter; the adaptive de-sampling of 004 Section 4.3 lowers the rate of the Gait-PDR mode (e.g. 200 -> 25 Hz),
which needs an anti-aliasing low-pass before samples are dropped. Both are streaming and chunk-invariant:
feeding a signal in one call or in arbitrary pieces gives the same output (the filter keeps the last
``numtaps - 1`` inputs as state).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numba import njit
from scipy import signal

__all__ = ["hamming_lowpass", "FirFilter", "Decimator", "fir_advance"]


def hamming_lowpass(numtaps: int, cutoff_hz: float, rate_hz: float) -> np.ndarray:
    """Design a linear-phase low-pass FIR with a Hamming window (004 Section 2.2).

    Parameters
    ----------
    numtaps : int
        Filter length; must be odd (type-I linear phase, group delay ``(numtaps - 1) / 2`` samples).
    cutoff_hz : float
        -6 dB cut-off frequency [Hz], ``0 < cutoff_hz < rate_hz / 2``.
    rate_hz : float
        Sampling rate [Hz].

    Returns
    -------
    ndarray, shape (numtaps,)
        Symmetric taps with unit DC gain.
    """
    if numtaps < 1 or numtaps % 2 == 0:
        raise ValueError(f"numtaps must be odd and positive, got {numtaps}")
    if not 0.0 < cutoff_hz < rate_hz / 2.0:
        raise ValueError(f"cutoff {cutoff_hz} Hz must lie in (0, {rate_hz / 2.0}) Hz")
    return _firwin_hamming(int(numtaps), float(cutoff_hz), float(rate_hz)).copy()


@lru_cache(maxsize=64)
def _firwin_hamming(numtaps: int, cutoff_hz: float, rate_hz: float) -> np.ndarray:
    # engines are rebuilt from state on every batch; the design is the same few filters each time
    return signal.firwin(numtaps, cutoff_hz, window="hamming", fs=rate_hz)


class FirFilter:
    """Streaming FIR filter over one or more channels.

    The output at input sample ``n`` is ``sum_k h[k] x[n - k]`` (causal, delayed by the group delay
    ``(numtaps - 1) / 2`` samples for linear-phase taps). Before the first sample the history is filled
    with the first sample (no start-up transient for a signal at rest), which keeps the filter
    chunk-invariant.

    Parameters
    ----------
    taps : ndarray, shape (L,)
        FIR coefficients.
    channels : int
        Number of channels (columns) of the signal.
    """

    def __init__(self, taps: np.ndarray, channels: int = 1) -> None:
        self.taps = np.asarray(taps, dtype=np.float64).reshape(-1)
        self.channels = int(channels)
        self._hist: np.ndarray | None = None  # last L-1 inputs, oldest first, shape (L-1, C)

    @property
    def history(self) -> np.ndarray | None:
        """The last ``L - 1`` inputs, oldest first, shape (L-1, C); None before the first chunk."""
        return self._hist

    @history.setter
    def history(self, h: np.ndarray) -> None:
        self._hist = h

    @property
    def delay_samples(self) -> float:
        """Group delay [samples] of linear-phase taps."""
        return (self.taps.size - 1) / 2.0

    def _extend(self, x2: np.ndarray) -> np.ndarray:
        """History + new inputs (the filter's input span), and the history advanced."""
        n_hist = self.taps.size - 1
        if self._hist is None:
            self._hist = np.repeat(x2[:1], n_hist, axis=0)
        ext = np.concatenate([self._hist, x2], axis=0)
        self._hist = ext[ext.shape[0] - n_hist:].copy() if n_hist else ext[:0].copy()
        return ext

    def process(self, x: np.ndarray) -> np.ndarray:
        """Filter the next chunk.

        Parameters
        ----------
        x : ndarray, shape (N, C) or (N,) when ``channels == 1``
            Input samples (any unit; the output has the same unit).

        Returns
        -------
        ndarray, same shape as ``x``
        """
        x = np.asarray(x, dtype=np.float64)
        squeeze = x.ndim == 1
        x2 = x.reshape(-1, self.channels)
        if x2.shape[0] == 0:
            return x.copy()
        if self._hist is not None and self._hist.shape[0] and x2.shape[0] >= self._hist.shape[0]:
            # the steady state: the same outputs, the history advanced in place, in one compiled call
            y = fir_advance(self._hist, x2, self.taps)
        else:
            y = _fir_rows(self._extend(x2), self.taps, np.arange(x2.shape[0]))
        return y.reshape(-1) if squeeze else y

    def process_rows(self, x: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Filter the next chunk but compute only the outputs ``rows`` (indices into the chunk).

        The history advances by the whole chunk, exactly as :meth:`process`; a decimator that keeps one
        output in ``factor`` pays for those only.

        Returns
        -------
        ndarray, shape (len(rows), C)
        """
        x2 = np.asarray(x, dtype=np.float64).reshape(-1, self.channels)
        if x2.shape[0] == 0:
            return np.zeros((0, self.channels))
        return _fir_rows(self._extend(x2), self.taps, np.asarray(rows, dtype=np.int64))

    def get_state(self) -> dict:
        """Plain-data state for ``energy.codec``."""
        return {"taps": self.taps.copy(), "channels": self.channels,
                "hist": None if self._hist is None else self._hist.copy()}

    @classmethod
    def from_state(cls, d: dict) -> FirFilter:
        """Rebuild from :meth:`get_state` output."""
        f = cls(np.asarray(d["taps"]), int(d["channels"]))
        f._hist = None if d["hist"] is None else np.asarray(d["hist"], dtype=np.float64).copy()
        return f


class Decimator:
    """Anti-aliased integer down-sampling of a timestamped stream (004 Section 4.3 de-sampling).

    A Hamming-window low-pass at the input rate (cut-off ``0.4 * rate_out_hz``) followed by keeping every
    ``factor``-th sample. The kept output is stamped with the time of the input sample at the centre of the
    filter (the group delay is compensated): outputs sit on input samples 0, factor, 2 factor, ... and
    appear ``(numtaps - 1) / 2`` input samples later (the filter's latency).

    Parameters
    ----------
    rate_in_hz : float
        Nominal input rate [Hz].
    rate_out_hz : float
        Requested output rate [Hz]; the factor is ``round(rate_in_hz / rate_out_hz)`` (>= 1) and the actual
        output rate is ``rate_in_hz / factor`` (see :attr:`rate_out_actual_hz`).
    channels : int
        Number of signal columns.
    taps_per_factor : int
        Filter length is ``taps_per_factor * factor + 1`` (longer = sharper transition).
    """

    def __init__(self, rate_in_hz: float, rate_out_hz: float, channels: int = 3,
                 taps_per_factor: int = 16) -> None:
        self.rate_in_hz = float(rate_in_hz)
        self.rate_out_hz = float(rate_out_hz)
        self.factor = max(1, int(round(self.rate_in_hz / self.rate_out_hz)))
        self.channels = int(channels)
        self.taps_per_factor = int(taps_per_factor)
        if self.factor == 1:
            taps = np.ones(1)
        else:
            taps = hamming_lowpass(self.taps_per_factor * self.factor + 1, 0.4 * self.rate_in_hz / self.factor,
                                   self.rate_in_hz)
        self._fir = FirFilter(taps, self.channels)
        self._count = 0  # input samples consumed so far
        self._t_hist = np.zeros(0, dtype=np.int64)  # timestamps of the last `delay` inputs

    @property
    def rate_out_actual_hz(self) -> float:
        """Output rate [Hz] actually produced."""
        return self.rate_in_hz / self.factor

    def process(self, t_ns: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Down-sample the next chunk.

        Parameters
        ----------
        t_ns : ndarray of int64, shape (N,)
            Input sample times [ns].
        x : ndarray, shape (N, C)
            Input samples (any unit).

        Returns
        -------
        t_out_ns : ndarray of int64, shape (M,)
            Times [ns] of the output samples (group delay compensated).
        y : ndarray, shape (M, C)
            Filtered, down-sampled samples.
        """
        t_ns = np.asarray(t_ns, dtype=np.int64).reshape(-1)
        x = np.asarray(x, dtype=np.float64).reshape(-1, self.channels)
        delay = int(self._fir.delay_samples)
        hist = self._fir.history
        if self._count > 0 and t_ns.size and hist is not None and self._t_hist.size == delay \
                and x.shape[0] == t_ns.size:
            # the steady state (a history of both streams): the same steps in one compiled call, the histories
            # advanced in place (their lengths are fixed; both arrays are this decimator's own)
            t_out, y = _decimate(t_ns, x, hist, self._t_hist, self._count, self.factor, self._fir.taps)
            self._count += t_ns.size
            return t_out, y
        if self._count == 0 and t_ns.size:
            self._t_hist = np.repeat(t_ns[:1], delay)  # matches the FIR's replicated start
        t_all = np.concatenate([self._t_hist, t_ns])
        t_centre = t_all[: t_ns.size]  # input time `delay` samples before each output
        # output n is centred on input n - delay: keep inputs 0, factor, 2 factor, ... (none before the start),
        # i.e. the chunk rows j >= delay - count with count + j - delay a multiple of factor
        j0 = max(delay - self._count, 0)
        rows = np.arange(j0 + (delay - self._count - j0) % self.factor, t_ns.size, self.factor)
        y = self._fir.process_rows(x, rows)  # only the kept outputs are computed
        self._count += t_ns.size
        self._t_hist = t_all[max(t_all.size - delay, 0) :].copy() if delay else t_all[:0].copy()
        return t_centre[rows], y

    def process_seconds(self, t_s: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`process` with the times in seconds: the input stamped ``round(t_s * 1e9)`` [ns] (``t_s`` [s],
        float64, shape (N,)), the output times [ns] returned divided by 1e9 [s]. In the steady state (both
        histories there, ``x`` float64 of shape (N, C)) the conversions and the down-sampling are one compiled
        call (the same values)."""
        hist = self._fir.history
        if (self._count > 0 and t_s.size and hist is not None and self._t_hist.size == int(self._fir.delay_samples)
                and x.shape[0] == t_s.size and x.dtype == np.float64 and x.ndim == 2 and x.shape[1] == self.channels):
            t_out, y = _decimate_s(t_s, x, hist, self._t_hist, self._count, self.factor, self._fir.taps)
            self._count += t_s.size
            return t_out, y
        t_out_ns, y = self.process(np.round(t_s * 1e9).astype(np.int64), x)
        return t_out_ns / 1e9, y

    def flush(self) -> tuple[np.ndarray, np.ndarray]:
        """End of the stream: the outputs still held back by the filter's latency.

        The filter is fed ``delay`` copies of the last input (the mirror of the replicated start), so the
        output reaches the last input's time. Call once, after the last :meth:`process`.

        Returns
        -------
        t_out_ns : ndarray of int64, shape (M,)
            Times [ns] of the remaining output samples.
        y : ndarray, shape (M, C)
            Their filtered values.
        """
        delay = int(self._fir.delay_samples)
        hist = self._fir.history
        if delay == 0 or self._count == 0 or hist is None:
            return np.zeros(0, dtype=np.int64), np.zeros((0, self.channels))
        t_c = self._t_hist  # times of the last `delay` inputs: the outputs are centred on them
        c = np.arange(self._count - delay, self._count)  # their input indices
        keep = (c >= 0) & ((c % self.factor) == 0)  # the same grid as process() keeps
        y = self._fir.process_rows(np.repeat(hist[-1:], delay, axis=0), np.flatnonzero(keep))
        self._count += delay
        self._t_hist = self._t_hist[:0]
        return t_c[keep].copy(), y

    def get_state(self) -> dict:
        """Plain-data state for ``energy.codec``."""
        return {"rate_in_hz": self.rate_in_hz, "rate_out_hz": self.rate_out_hz, "channels": self.channels,
                "taps_per_factor": self.taps_per_factor, "fir": self._fir.get_state(), "count": self._count,
                "t_hist": self._t_hist.copy()}

    @classmethod
    def from_state(cls, d: dict) -> Decimator:
        """Rebuild from :meth:`get_state` output."""
        obj = cls(d["rate_in_hz"], d["rate_out_hz"], int(d["channels"]), int(d["taps_per_factor"]))
        obj._fir = FirFilter.from_state(d["fir"])
        obj._count = int(d["count"])
        obj._t_hist = np.asarray(d["t_hist"], dtype=np.int64).copy()
        return obj


@njit(cache=True)
def _fir_rows(ext: np.ndarray, taps: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``y[j, c] = sum_k taps[k] ext[rows[j] + L - 1 - k, c]`` (what ``np.convolve(..., "valid")`` gives at
    ``rows``), in a fixed summation order so the output does not depend on how the stream was chunked: each
    channel's sum from 0.0 over ``k = 0 .. L - 1``. Channels go four at a time (four independent sums in
    registers instead of one chain of dependent additions after another: the same sums, about twice as fast),
    the rest one by one."""
    n_taps = taps.size
    nc = ext.shape[1]
    y = np.empty((rows.size, nc))
    for j in range(rows.size):
        r = rows[j] + n_taps - 1
        c = 0
        while c + 4 <= nc:
            a0 = a1 = a2 = a3 = 0.0
            for k in range(n_taps):
                h = taps[k]
                e = r - k
                a0 += h * ext[e, c]
                a1 += h * ext[e, c + 1]
                a2 += h * ext[e, c + 2]
                a3 += h * ext[e, c + 3]
            y[j, c], y[j, c + 1], y[j, c + 2], y[j, c + 3] = a0, a1, a2, a3
            c += 4
        while c < nc:
            a = 0.0
            for k in range(n_taps):
                a += taps[k] * ext[r - k, c]
            y[j, c] = a
            c += 1
    return y


@njit(cache=True)
def fir_advance(hist: np.ndarray, x: np.ndarray, taps: np.ndarray) -> np.ndarray:
    """:meth:`FirFilter.process` of a chunk ``x`` (N, C) at least as long as the history ``hist`` (L - 1, C):
    the outputs of every row by :func:`_fir_rows` over the span history + chunk, and the history advanced in
    place to the chunk's last ``L - 1`` rows (what the concatenation, ``np.arange`` and copy gave)."""
    n, nh = x.shape[0], hist.shape[0]
    ext = np.empty((nh + n, x.shape[1]))
    ext[:nh] = hist
    ext[nh:] = x
    y = _fir_rows(ext, taps, np.arange(n))
    hist[:] = x[n - nh:]
    return y


@njit(cache=True)
def _decimate(t_ns, x, hist, t_hist, count, factor, taps):
    """One chunk of :meth:`Decimator.process` once both histories are there (``count > 0``; ``hist`` the FIR's
    last ``L - 1`` inputs, ``t_hist`` the times [ns] of the last ``delay`` inputs): the FIR's input span and
    time span, the kept rows, their outputs by :func:`_fir_rows`, with the same values as the array form
    (concatenations, ``np.arange``, fancy indexing) in one call; ``hist`` and ``t_hist`` are advanced in place.

    Returns ``(t_out_ns, y)``."""
    n = t_ns.size
    nh = hist.shape[0]
    delay = t_hist.size
    ext = np.empty((nh + n, x.shape[1]))
    ext[:nh] = hist
    ext[nh:] = x
    t_all = np.empty(delay + n, dtype=np.int64)
    t_all[:delay] = t_hist
    t_all[delay:] = t_ns
    j0 = max(delay - count, 0)
    d = delay - count - j0
    rows = np.arange(j0 + ((d % factor) + factor) % factor, n, factor)  # (Python's modulo of a negative d)
    y = _fir_rows(ext, taps, rows)
    t_out = np.empty(rows.size, dtype=np.int64)
    for j in range(rows.size):
        t_out[j] = t_all[rows[j]]
    hist[:] = ext[n:]
    t_hist[:] = t_all[n:]
    return t_out, y


@njit(cache=True)
def _decimate_s(t_s, x, hist, t_hist, count, factor, taps):
    """:func:`_decimate` with the times in seconds (:meth:`Decimator.process_seconds`): the input times
    ``rint(t_s * 1e9)`` as int64 (what ``np.round(t_s * 1e9).astype(np.int64)`` gives), the output times [ns]
    divided by 1e9 [s]. Returns ``(t_out_s, y)``."""
    t_ns = np.empty(t_s.size, dtype=np.int64)
    for i in range(t_s.size):
        t_ns[i] = np.int64(np.rint(t_s[i] * 1e9))
    t_out, y = _decimate(t_ns, x, hist, t_hist, count, factor, taps)
    t_out_s = np.empty(t_out.size)
    for j in range(t_out.size):
        t_out_s[j] = t_out[j] / 1e9
    return t_out_s, y
