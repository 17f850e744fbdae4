"""Step-and-heading front end (003 Section 5, Figure 5): one pass over the merged sensor samples that runs the
MARG filter (:mod:`models.marg`), the step detector (:mod:`models.step_detector`) and the walking-direction
statistics (:mod:`models.walking_direction`), and emits one record per detected step.

A record (:data:`STEP_RECORD`) says, for the samples since the previous step: the step's time, peak and valley
of the filtered ``|f|`` and period; the circular mean of the device's forward azimuth in the filter's frame and
its resultant length; the mean azimuth of the horizontal magnetic field in that frame (its difference to the
declination turns any azimuth of the filter's frame into a compass azimuth, whatever the filter's own heading
knows); the principal direction of the horizontal specific force over the last stride (two steps), its
eigenvalue ratio and the gait-cycle sign statistic for it; the filter's heading standard deviation; the
fraction of accelerometer samples that had gyroscope samples; the field's magnitude and dip; the mean resultant
length of the body's down direction (1: a steady tilt, as held in front; a pocket's or a swinging arm's tilt
swings with the stride), the mean angular rate [rad/s] (NaN without gyroscope) and ``gyro_dyaw``, the turn about
the vertical the bias-corrected gyroscope measured over the step [rad] (integrated as the filter integrates it;
unlike the change of the filter's azimuths, free of its compass corrections); ``bias_settled`` is 1 when the
filter's vertical gyroscope bias has settled since the start and the device's latest wave
(:func:`models.marg.bias_settled`).

Everything that carries over between calls is in plain arrays (:class:`PdrState`), so the pass is
deterministic whatever the input's chunking, and serialisable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit

from models import marg as M
from models.step_detector import N_STATE, new_step_state, step_update
from models.walking_direction import RING, forward_azimuth, forward_sign, principal_direction, window

__all__ = ["STEP_RECORD", "PdrState", "pdr_run", "run_pdr"]

STEP_RECORD = ("t_s", "a_max", "a_min", "period_s", "fwd_az", "fwd_r", "field_az", "field_r", "pca_az", "pca_ratio",
               "pca_sign", "yaw_std", "gyro_frac", "n_mag", "field_ut", "dip_rad", "tilt_r", "rate_rad_s", "gyro_dyaw",
               "bias_settled")
_NREC = len(STEP_RECORD)
# accumulator slots (since the previous step)
(_A_FC, _A_FS, _A_FN, _A_MC, _A_MS, _A_MN, _A_NACC, _A_NGYR, _A_MAG, _A_DIP, _A_PREV, _A_PREV2, _A_DX, _A_DY, _A_DZ,
 _A_RATE, _A_DYAW) = range(17)
_NACC = 17


@dataclass
class PdrState:
    """The front end's carried state: MARG filter, step detector, accumulators and the specific-force ring."""

    marg: M.MargState
    steps: np.ndarray
    acc: np.ndarray
    ring: np.ndarray
    ring_n: np.ndarray  # (1,) samples ever written to the ring

    @classmethod
    def new(cls, marg: M.MargState) -> PdrState:
        acc = np.zeros(_NACC)
        acc[_A_PREV] = acc[_A_PREV2] = -math.inf
        return cls(marg, new_step_state(), acc, np.zeros((RING, 4)), np.zeros(1, dtype=np.int64))

    def get_state(self) -> dict[str, Any]:
        return {"marg": self.marg.get_state(), "steps": self.steps.copy(), "acc": self.acc.copy(),
                "ring": self.ring.copy(), "ring_n": int(self.ring_n[0])}

    @classmethod
    def from_state(cls, d: dict[str, Any]) -> PdrState:
        return cls(M.MargState.from_state(d["marg"]), np.asarray(d["steps"], dtype=float).reshape(N_STATE).copy(),
                   M._pad(np.asarray(d["acc"], dtype=float).reshape(-1), _NACC),
                   np.asarray(d["ring"], dtype=float).reshape(RING, 4).copy(), np.array([int(d["ring_n"])], dtype=np.int64))


@njit(cache=True)
def _emit(row: np.ndarray, det: np.ndarray, ac: np.ndarray, ring: np.ndarray, n_ring: int, P: np.ndarray,
          s: np.ndarray) -> None:
    row[0], row[1], row[2], row[3] = det[0], det[1], det[2], det[3]
    row[4] = math.atan2(ac[_A_FS], ac[_A_FC]) if ac[_A_FN] > 0 else math.nan
    row[5] = math.hypot(ac[_A_FS], ac[_A_FC]) / ac[_A_FN] if ac[_A_FN] > 0 else 0.0
    row[6] = math.atan2(ac[_A_MS], ac[_A_MC]) if ac[_A_MN] > 0 else math.nan
    row[7] = math.hypot(ac[_A_MS], ac[_A_MC]) / ac[_A_MN] if ac[_A_MN] > 0 else 0.0
    t0 = ac[_A_PREV2] if ac[_A_PREV2] > -1e300 else det[0] - 1.5
    w = window(ring, n_ring, t0, det[0])
    th, ratio = principal_direction(w)
    row[8], row[9] = th, ratio
    period = det[3] if det[3] == det[3] else 0.5 * (det[0] - t0)
    row[10] = forward_sign(w, th, period) if th == th else 0.0
    row[11] = math.sqrt(max(P[2, 2], 0.0))
    row[12] = ac[_A_NGYR] / ac[_A_NACC] if ac[_A_NACC] > 0 else 0.0
    row[13] = ac[_A_MN]
    row[14] = ac[_A_MAG] / ac[_A_MN] if ac[_A_MN] > 0 else math.nan
    row[15] = ac[_A_DIP] / ac[_A_MN] if ac[_A_MN] > 0 else math.nan
    row[16] = math.sqrt(ac[_A_DX] ** 2 + ac[_A_DY] ** 2 + ac[_A_DZ] ** 2) / ac[_A_NACC] if ac[_A_NACC] > 0 else 1.0
    row[17] = ac[_A_RATE] / ac[_A_NGYR] if ac[_A_NGYR] > 0 else math.nan
    row[18] = ac[_A_DYAW]
    row[19] = 1.0 if (s[M.S_TSETTLED] > -1e299 and s[M.S_TSETTLED] >= s[M.S_TWAVE]) else 0.0


@njit(cache=True)
def pdr_run(t: np.ndarray, kind: np.ndarray, v: np.ndarray, q: np.ndarray, b: np.ndarray, P: np.ndarray,
            w: np.ndarray, s: np.ndarray, ref: np.ndarray, mc: np.ndarray, st: np.ndarray, sc: np.ndarray,
            ac: np.ndarray, ring: np.ndarray, ring_n: np.ndarray, out: np.ndarray) -> int:
    """Process merged samples (times [s], kinds ``models.marg.KIND_*``, values); steps go to ``out`` (one row of
    :data:`STEP_RECORD` each, at most ``out.shape[0]``); returns how many."""
    n_out = 0
    det = np.zeros(4)
    size = ring.shape[0]
    work = M.new_work()
    for i in range(t.shape[0]):
        ti = t[i]
        k = kind[i]
        vi = v[i]
        if s[M.S_INIT] > 0.5 and ti > s[M.S_T] and ti - s[M.S_TGYR] <= mc[4]:
            # the turn about the vertical the filter's prediction is about to integrate (z down: + = clockwise)
            C2 = M.dcm(q)[2]
            ac[_A_DYAW] += (C2[0] * (w[0] - b[0]) + C2[1] * (w[1] - b[1]) + C2[2] * (w[2] - b[2])) \
                * min(ti - s[M.S_T], mc[17])
        M.marg_event(q, b, P, w, s, ref, ti, k, vi, mc, work)
        if s[M.S_INIT] < 0.5:
            continue
        C = M.dcm(q)
        if k == M.KIND_ACC:
            a = math.sqrt(vi[0] ** 2 + vi[1] ** 2 + vi[2] ** 2)
            j = ring_n[0] % size
            ring[j, 0] = ti
            ring[j, 1] = C[0][0] * vi[0] + C[0][1] * vi[1] + C[0][2] * vi[2]
            ring[j, 2] = C[1][0] * vi[0] + C[1][1] * vi[1] + C[1][2] * vi[2]
            ring[j, 3] = C[2][0] * vi[0] + C[2][1] * vi[1] + C[2][2] * vi[2]
            ring_n[0] += 1
            az = forward_azimuth(C)
            ac[_A_FC] += math.cos(az)
            ac[_A_FS] += math.sin(az)
            ac[_A_FN] += 1.0
            ac[_A_NACC] += 1.0
            ac[_A_DX] += C[2][0]  # the body's down direction (row 3 of C): how steady the device's tilt is
            ac[_A_DY] += C[2][1]
            ac[_A_DZ] += C[2][2]
            if ti - s[M.S_TGYR] <= mc[4]:
                ac[_A_NGYR] += 1.0
                ac[_A_RATE] += math.sqrt((w[0] - b[0]) ** 2 + (w[1] - b[1]) ** 2 + (w[2] - b[2]) ** 2)
            if step_update(st, ti, a, sc, det):
                if n_out < out.shape[0]:
                    _emit(out[n_out], det, ac, ring, ring_n[0], P, s)
                    n_out += 1
                ac[_A_PREV2] = ac[_A_PREV]
                ac[_A_PREV] = det[0]
                for z in (_A_FC, _A_FS, _A_FN, _A_MC, _A_MS, _A_MN, _A_NACC, _A_NGYR, _A_MAG, _A_DIP, _A_DX, _A_DY, _A_DZ,
                          _A_RATE, _A_DYAW):
                    ac[z] = 0.0
        elif k == M.KIND_MAG:
            mn0 = C[0][0] * vi[0] + C[0][1] * vi[1] + C[0][2] * vi[2]
            mn1 = C[1][0] * vi[0] + C[1][1] * vi[1] + C[1][2] * vi[2]
            mn2 = C[2][0] * vi[0] + C[2][1] * vi[1] + C[2][2] * vi[2]
            mh = math.sqrt(mn0 * mn0 + mn1 * mn1)
            if mh > 1.0:
                psi = math.atan2(mn1, mn0)
                ac[_A_MC] += math.cos(psi)
                ac[_A_MS] += math.sin(psi)
                ac[_A_MN] += 1.0
                ac[_A_MAG] += math.sqrt(mh * mh + mn2 * mn2)
                ac[_A_DIP] += math.atan2(mn2, mh)
    return n_out


def run_pdr(state: PdrState, marg_config: np.ndarray, step_config: np.ndarray, t_s: np.ndarray, kind: np.ndarray,
            values: np.ndarray) -> np.ndarray:
    """Run :func:`pdr_run` on merged samples; returns the step records, shape (n_steps, len(STEP_RECORD))."""
    t = np.ascontiguousarray(t_s, dtype=np.float64)
    out = np.zeros((t.size // 4 + 4, _NREC))
    m = state.marg
    n = pdr_run(t, np.ascontiguousarray(kind, dtype=np.int64), np.ascontiguousarray(values, dtype=np.float64).reshape(-1, 3),
                m.q, m.b, m.P, m.w, m.s, m.ref, marg_config, state.steps, step_config, state.acc, state.ring,
                state.ring_n, out)
    return out[:n].copy()
