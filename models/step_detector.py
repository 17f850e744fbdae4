"""Step detection on the specific-force magnitude of a device that is not on the foot (003 Section 5.1).

The magnitude ``|f|`` [m/s^2] is low-pass filtered (003: the filtered norm has fewer false and missed steps) by
two cascaded second-order Butterworth systems (``x'' + 2 zeta w0 x' + w0^2 x = w0^2 u``, ``zeta = 1/sqrt(2)``),
the causal counterpart of a forward-backward Butterworth filter (the same magnitude response), each integrated
exactly over each sample's own interval with its input held (zero-order hold), so irregular timestamps and any
rate from 25 to 100 Hz give the same filter (group delay ``4 zeta / w0``, 150 ms at 3 Hz). A single section
passed the small peaks of a hand's shuffle while standing and turning (1-2 m/s^2 above the valley: 2-12
extra steps per IPIN trial, half of them while standing) that the forward-backward filter keeps below the
threshold. A step is a peak of the filtered
magnitude above ``g + min_peak_ms2``, confirmed once the signal has fallen ``hysteresis_ms2`` below it, at least
``min_interval_s`` after the previous step. Each step carries the peak and the lowest value since the previous
step (000 eq. 35's ``a_max``, ``a_min``) and its period. Causal: a step is known ``hysteresis`` after its peak
(typically 0.1-0.2 s), whatever the chunking of the input.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np
from numba import njit

__all__ = ["StepDetectorConfig", "StepDetector", "STEP_FIELDS", "new_step_state"]

G = 9.80665
_ZETA = 1.0 / math.sqrt(2.0)  # Butterworth damping
# state slots (_S1, _S2 and _S3, _S4: output and derivative of the two sections)
_S1, _S2, _T, _CAND, _CAND_T, _VALLEY, _VALLEY_AT_CAND, _LAST_T, _INIT, _LAST_PEAK, _S3, _S4 = range(12)
N_STATE = 12
# fields of a detected step (one row per step)
STEP_FIELDS = ("t_s", "a_max", "a_min", "period_s")


@dataclass(frozen=True)
class StepDetectorConfig:
    """Parameters of :class:`StepDetector` (units in the names).

    Attributes
    ----------
    lowpass_hz : float
        Corner frequency of the low-pass filter [Hz] (walking: 1.5-2.2 steps/s).
    min_peak_ms2 : float
        A step's filtered peak is at least this above g [m/s^2].
    hysteresis_ms2 : float
        The peak is confirmed when the filtered magnitude has fallen this far below it [m/s^2].
    min_interval_s : float
        Shortest time between two steps [s] (3.3 steps/s: running).
    max_period_s : float
        A longer interval is not one step's period (a pause) [s].
    """

    lowpass_hz: float = 3.0
    min_peak_ms2: float = 0.7
    hysteresis_ms2: float = 0.3
    min_interval_s: float = 0.3
    max_period_s: float = 1.5

    def __post_init__(self) -> None:
        for f in fields(self):
            v = float(getattr(self, f.name))
            if not math.isfinite(v) or v <= 0:
                raise ValueError(f"StepDetectorConfig: {f.name} must be a positive finite number, got {v!r}")

    def as_array(self) -> np.ndarray:
        return np.array([2.0 * math.pi * self.lowpass_hz, self.min_peak_ms2, self.hysteresis_ms2,
                         self.min_interval_s, self.max_period_s])

    def to_dict(self) -> dict[str, float]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> StepDetectorConfig:
        return cls(**{k: float(v) for k, v in d.items()})


def new_step_state() -> np.ndarray:
    st = np.zeros(N_STATE)
    st[_CAND] = -math.inf
    st[_LAST_T] = -math.inf
    st[_VALLEY] = math.inf
    st[_VALLEY_AT_CAND] = math.inf
    return st


@njit(cache=True)
def _section(st: np.ndarray, i: int, u: float, dt: float, w0: float) -> None:
    """Exact solution over ``dt`` of one 2nd-order Butterworth section (state ``st[i]``, ``st[i + 1]``: output and
    its derivative) driven by the held input ``u``."""
    sig = w0 * _ZETA
    wd = w0 * math.sqrt(1.0 - _ZETA * _ZETA)
    e0, v0 = st[i] - u, st[i + 1]
    ex = math.exp(-sig * dt)
    cs, sn = math.cos(wd * dt), math.sin(wd * dt)
    st[i] = u + ex * (e0 * cs + (v0 + sig * e0) / wd * sn)
    st[i + 1] = ex * (v0 * cs - (sig * v0 + w0 * w0 * e0) / wd * sn)


@njit(cache=True)
def step_update(st: np.ndarray, t: float, a: float, c: np.ndarray, out: np.ndarray) -> bool:
    """Feed one magnitude sample ``a`` [m/s^2] at ``t`` [s]; True when a step was confirmed, its row in ``out``
    (:data:`STEP_FIELDS`)."""
    if st[_INIT] < 0.5:
        st[_S1] = a
        st[_S2] = 0.0
        st[_S3] = a
        st[_S4] = 0.0
        st[_T] = t
        st[_INIT] = 1.0
        return False
    dt = t - st[_T]
    st[_T] = t
    if dt > 0.0:
        u2 = st[_S1]  # the second section is driven by the first one's output, held over the interval too
        _section(st, _S1, a, dt, c[0])
        _section(st, _S3, u2, dt, c[0])
    x = st[_S3]
    found = False
    if st[_CAND] > -1e300 and x < st[_CAND] - c[2]:
        if st[_CAND_T] - st[_LAST_T] >= c[3]:
            period = st[_CAND_T] - st[_LAST_T]
            out[0] = st[_CAND_T]
            out[1] = st[_CAND]
            out[2] = st[_VALLEY_AT_CAND]
            out[3] = period if period <= c[4] else math.nan
            st[_LAST_T] = st[_CAND_T]
            st[_LAST_PEAK] = st[_CAND]
            found = True
        st[_CAND] = -math.inf
        st[_VALLEY] = x
    if x < st[_VALLEY]:
        st[_VALLEY] = x
    if x > G + c[1] and x > st[_CAND]:
        st[_CAND] = x
        st[_CAND_T] = t
        st[_VALLEY_AT_CAND] = st[_VALLEY]
    return found


@njit(cache=True)
def _run(t: np.ndarray, a: np.ndarray, st: np.ndarray, c: np.ndarray, out: np.ndarray) -> int:
    n = 0
    row = np.zeros(4)
    for i in range(t.shape[0]):
        if step_update(st, t[i], a[i], c, row):
            out[n] = row
            n += 1
    return n


class StepDetector:
    """Streaming step detector (see the module docstring).

    Parameters
    ----------
    config : StepDetectorConfig
    """

    def __init__(self, config: StepDetectorConfig | None = None) -> None:
        self.config = config or StepDetectorConfig()
        self._c = self.config.as_array()
        self.state = new_step_state()

    def process(self, t_s: np.ndarray, acc: np.ndarray) -> np.ndarray:
        """Feed accelerometer samples ``acc`` [m/s^2] (n, 3) at ``t_s`` [s]; returns the steps confirmed, one row
        each (:data:`STEP_FIELDS`)."""
        t = np.ascontiguousarray(t_s, dtype=np.float64)
        a = np.linalg.norm(np.asarray(acc, dtype=np.float64).reshape(-1, 3), axis=1)
        out = np.zeros((t.size // 2 + 1, 4))
        n = _run(t, a, self.state, self._c, out)
        return out[:n].copy()

    def get_state(self) -> dict[str, Any]:
        return {"config": self.config.to_dict(), "state": self.state.copy()}

    @classmethod
    def from_state(cls, d: dict[str, Any]) -> StepDetector:
        obj = cls(StepDetectorConfig.from_dict(d["config"]))
        obj.state = np.asarray(d["state"], dtype=float).reshape(N_STATE).copy()
        return obj
