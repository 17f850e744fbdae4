"""Compiled hot loop of the ZUPT-aided navigator: detector + strapdown + 15-state error-state KF.

One ``@njit(cache=True)`` kernel (:func:`run_kernel`) processes a batch of samples with all state held in
plain arrays (in and out), so streaming costs no Python per sample. The scalar helpers below are also
njit-compiled and are reused by the pure-numpy reference modules' tests.

Every function here compiles with numpy's error model: a division by zero gives inf/NaN instead of raising
(Python's model tests every divisor, a branch per division: ~7 % of the kernel's time). The divisors of valid
inputs and settings are not zero (norms are tested against zero first, innovation covariances are positive
definite, noise parameters positive by :meth:`models.zupt_nav.ZuptConfig.validate`), so the results are those of
Python's model, bit for bit; where one were zero, the kernel carries inf/NaN on, as the numpy reference modules
do, rather than raising mid-batch.

Error state (004 eq. 6): ``dx = [dp(3), dv(3), phi(3), dba(3), dbg(3)]`` in NED, with the attitude error
defined by ``C_true = (I + [phi x]) C_est`` (phi in the navigation frame), biases ``b_true = b_est + db``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = [
    "PAR",
    "FS",
    "IS",
    "N_PAR",
    "N_FS",
    "N_IS",
    "N_ST",
    "run_kernel",
    "quat_mul_s",
    "quat_exp_s",
    "quat_dcm_s",
    "triad_s",
    "strapdown_run",
    "cov_predict",
]

# ---- parameter vector layout (filled by ZuptConfig.to_array) ------------------------------------------
PAR = {
    name: i
    for i, name in enumerate(
        (
            "sigma_a",  # SHOE accelerometer noise [m/s^2]                                   002 eq. (1)
            "sigma_w",  # SHOE gyroscope noise [rad/s]
            "half_window_s",  # half window of the detector [s]
            "gamma0",  # SHOE threshold at the reference gait intensity                  002 eq. (3)
            "gamma_exp",  # exponent of the intensity adaptation (0 = fixed threshold)
            "intensity_tau_s",  # decay time of the gait-intensity peak tracker [s]
            "intensity_ref",  # reference intensity (SHOE units)
            "gamma_min",
            "gamma_max",
            "hysteresis",  # exit threshold = hysteresis * entry threshold (>= 1)
            "gravity",  # [m/s^2]
            "acc_psd",  # velocity random walk PSD [(m/s^2)^2 s]
            "gyr_psd",  # angle random walk PSD [(rad/s)^2 s]
            "ba_psd",  # accelerometer bias random walk PSD
            "bg_psd",  # gyroscope bias random walk PSD
            "zupt_sigma",  # ZUPT pseudo-measurement noise [m/s]                         004 eq. (9)
            "zaru_sigma",  # ZARU noise [rad/s]                                          001 eq. (34-35)
            "zaru_on",
            "mag_on",
            "mag_sigma",  # magnetic heading noise [rad]                                  004 eq. (10)
            "mag_dmag",  # magnitude tolerance [uT]                                      002 eq. (4-5)
            "mag_dinc",  # inclination tolerance [rad]
            "mag_gate",  # innovation gate [sigma]
            "align_min_s",  # minimum initial rest [s]
            "align_max_s",  # rest used for alignment at most [s]
            "max_dt",  # longest interval integrated [s]
            "p0_tilt",  # initial 1-sigma tilt [rad]
            "p0_yaw",  # initial 1-sigma heading [rad]
            "p0_ba",  # [m/s^2]
            "p0_bg",  # [rad/s]
            "min_stance_s",  # shortest stance reported as a stance [s]
            "first_order",  # 1 = first-order attitude update I + [w x] dt (for comparison only)
            "align_gamma",  # fixed (strict) SHOE threshold for the initial rest used by the alignment
            "zaru_gamma",  # ZARU only where the statistic is below this (truly still foot)
            "bias_from_rest",  # > 0: initial gyro bias = mean rate over the rest shrunk by d / (d + bias_shrink_s)
            "bias_shrink_s",  # [s] prior weight of a zero bias (short, restless initial rests say little)
            "erosion_s",  # [s] the statistic is the max over +-erosion_s (shrinks stances at their edges)
            "hdr_on",  # heuristic drift reduction: straight strides keep the segment's heading
            "hdr_sigma",  # [rad] noise of that pseudo-measurement
            "hdr_delta",  # [rad] a stride within this of the segment heading counts as straight
            "hdr_min_stride",  # [m] shorter horizontal strides are ignored
            "hdr_min_n",  # consistent strides needed before the aid applies
            "hdr_turn",  # [rad] the foot turned this far from the segment on two strides running: a turn (0 = off)
            "dom_on",  # snap straight segments to dominant directions (iHDE, indoor buildings)
            "dom_delta",  # [rad] snap only segments within this of a dominant direction
            "gyr_scale_sigma",  # relative gyro scale-factor uncertainty: attitude noise grows with the turned angle
            "zupt_soft",  # ZUPT noise grows as sigma * (1 + zupt_soft * T / gamma): weak near the threshold
            "align_timeout_s",  # [s] no strict rest by then: align on the adaptive detector's first stance
            "trapezoid",  # 1: integrate the mean of consecutive samples (better at low rates)
            "intensity_mode",  # 0: decaying peak of the statistic, 1: exp. mean of its log10, 2: decaying peak |a|
            "gyr_sat_frac",  # a gyro axis within this fraction of the largest |rate| seen so far: the fastest rotation
            "gyr_sat_min",  # [rad/s] ... but only above this
            "gyr_sat_sigma",  # [rad/s] 1-sigma rate error of such a sample (tilt variance, 0 = off)
            "gyr_delay_s",  # [s] the gyro output lags the accelerometer's by this (read the gyro this much later)
            "align_swing_rate",  # [rad/s] |w| this large before the initial rest: mid-walk start, align on a stance
            "align_stance_min_s",  # [s] shortest walking stance a mid-walk start aligns on
            "p0_bg_walk",  # [rad/s] initial gyro-bias sigma of a mid-walk start (no rest to estimate it from)
            "gap_factor",  # an interval longer than this times the nominal one is a gap in the data (0 = off)
            "gap_acc_sigma",  # [m/s^2] per axis: specific force a linear interpolation over a gap misses
            "gap_gyr_sigma",  # [rad/s] per axis: tilt rate a linear interpolation over a gap misses
            "gap_yaw_sigma",  # [rad/s] heading rate it misses (unobservable by ZUPT; lets the heading aids act)
            "gap_max_s",  # [s] a longer gap is not bridged: hold, re-level at the next stance
            "swing_min_s",  # [s] no stance starts this soon after the last one ended ...
            "swing_speed",  # [m/s] ... while the mechanised foot moves faster than this (a mid-swing pause)
        )
    )
}
N_PAR = len(PAR)

# ---- float state layout --------------------------------------------------------------------------------
FS = {
    name: i
    for i, name in enumerate(
        (
            "intensity",  # decaying peak of the detector statistic (gait intensity)
            "t_prev",  # time of the last processed sample [s]
            "sa0", "sa1", "sa2",  # alignment sums: specific force
            "sg0", "sg1", "sg2",  # gyro
            "sm0", "sm1", "sm2",  # mag
            "n_align",
            "n_align_mag",
            "st_t0",  # current stance (or initial rest) start time [s]
            "st_head",  # heading at heel strike (004 psi_i) [rad]
            "prev_n", "prev_e", "prev_d",  # position at the previous reported stance [m]
            "peak_speed",  # peak speed of the current swing [m/s]
            "smn0", "smn1", "smn2",  # mag (NED) sum over the current stance
            "n_st_mag",
            "ref0", "ref1", "ref2",  # reference field NED [uT]
            "ref_valid",
            "n_align_used",  # samples used by the initial alignment
            "st_n",  # samples in the current stance
            "n_mag_used",  # magnetic heading updates applied
            "hdr_ref",  # heading of the current straight segment [rad]
            "hdr_n",  # consecutive strides consistent with it
            "dom_ref",  # first straight segment's heading: building dominant directions are dom_ref + k*90 deg
            "dom_valid",
            "t_first",  # time of the first sample [s]
            "gyr_peak",  # largest single-axis |rate| seen so far [rad/s]
            "moved",  # 1: the foot swung before the initial rest (mid-walk start): align on the next stance
            "t_align",  # time the initial alignment was made [s]
            "coast",  # 1: after a gap longer than gap_max_s, position held until the next stance re-levels
            "n_bridged",  # gaps bridged by interpolation
            "n_coasted",  # gaps held through (longer than gap_max_s)
            "dt_n",  # intervals pushed into the ring below
            "dtr0", "dtr1", "dtr2", "dtr3", "dtr4", "dtr5", "dtr6", "dtr7", "dtr8",  # latest intervals [s]
            "dt_min",  # smallest of them [s]
            "t_toe_off",  # end of the last stance [s]
            "hdr_free",  # heading with the drift reduction's own corrections left out [rad] (the gyro's turns)
            "hdr_last_h",  # heading after the last drift-reduction step [rad]
            "hdr_free_ok",  # 1: hdr_last_h is valid (0 after a reset or a restored older state)
            "hdr_free_ref",  # hdr_free of the current segment (slowly following) [rad]
            "hdr_turn_prev",  # the previous stride's turn from the segment, hdr_free - hdr_free_ref [rad]
            "hdr_corr",  # heading the pull applied since the foot last pointed along the segment [rad]
            "hdr_bg0", "hdr_bg1", "hdr_bg2",  # gyro bias before the pull that hdr_corr sums began [rad/s]
            # per channel (acc x, y, z, gyr x, y, z): sum of sigma * dt over the current run of clipped samples
            "sat_s0", "sat_s1", "sat_s2", "sat_s3", "sat_s4", "sat_s5",
            "sat_cnt",  # samples with a clipped channel since the last reported stance
            "sat_open",  # the previous sample's clipped channels (0: no run open, nothing to advance)
            # heading variance clipped gyroscope axes added [rad^2] (kept out of P: no ZUPT can observe it, and in P
            # it let the ZUPTs turn the heading on velocity errors of other causes), and its first and second
            # moments over the distance travelled when it was added: the position variance it causes later is
            # sum_k V_k (D - D_k)^2 = D^2 S0 - 2 D S1 + S2 (D: horizontal distance travelled [m])
            "clip_s0", "clip_s1", "clip_s2", "dist",
        )
    )
}
N_FS = len(FS)

IS = {
    name: i
    for i, name in enumerate(("initialised", "in_stance", "n_done", "has_prev", "n_stances", "has_prev_stance"))
}
N_IS = len(IS)

# stance record columns
ST_COLS = ("t_start", "t_end", "n", "e", "d", "heading", "dn", "de", "dd", "peak_speed", "samples", "mag_used",
           "heading_sigma", "pos_sigma", "clipped")
N_ST = len(ST_COLS)

# parameter indices as module constants (compile-time constants for numba)
_SA = PAR["sigma_a"]
_SW = PAR["sigma_w"]
_HW = PAR["half_window_s"]
_G0 = PAR["gamma0"]
_GE = PAR["gamma_exp"]
_ITAU = PAR["intensity_tau_s"]
_IREF = PAR["intensity_ref"]
_GMIN = PAR["gamma_min"]
_GMAX = PAR["gamma_max"]
_HYS = PAR["hysteresis"]
_GRAV = PAR["gravity"]
_QA = PAR["acc_psd"]
_QG = PAR["gyr_psd"]
_QBA = PAR["ba_psd"]
_QBG = PAR["bg_psd"]
_RZ = PAR["zupt_sigma"]
_RW = PAR["zaru_sigma"]
_ZARU = PAR["zaru_on"]
_MAGON = PAR["mag_on"]
_RMAG = PAR["mag_sigma"]
_DMAG = PAR["mag_dmag"]
_DINC = PAR["mag_dinc"]
_MGATE = PAR["mag_gate"]
_AMIN = PAR["align_min_s"]
_AMAX = PAR["align_max_s"]
_MAXDT = PAR["max_dt"]
_P0T = PAR["p0_tilt"]
_P0Y = PAR["p0_yaw"]
_P0BA = PAR["p0_ba"]
_P0BG = PAR["p0_bg"]
_MINST = PAR["min_stance_s"]
_FO = PAR["first_order"]
_AGAM = PAR["align_gamma"]
_ZGAM = PAR["zaru_gamma"]
_BREST = PAR["bias_from_rest"]
_BSHR = PAR["bias_shrink_s"]
_EROS = PAR["erosion_s"]
_HDR = PAR["hdr_on"]
_HDRS = PAR["hdr_sigma"]
_HDRD = PAR["hdr_delta"]
_HDRL = PAR["hdr_min_stride"]
_HDRN = PAR["hdr_min_n"]
_HDRT = PAR["hdr_turn"]
_DOM = PAR["dom_on"]
_DOMD = PAR["dom_delta"]
_GSS = PAR["gyr_scale_sigma"]
_ZSOFT = PAR["zupt_soft"]
_ATO = PAR["align_timeout_s"]
_F_TFIRST = FS["t_first"]
_TRAP = PAR["trapezoid"]
_IMODE = PAR["intensity_mode"]
_GSF = PAR["gyr_sat_frac"]
_GSM = PAR["gyr_sat_min"]
_GSS_SAT = PAR["gyr_sat_sigma"]
_F_GPEAK = FS["gyr_peak"]
_GDEL = PAR["gyr_delay_s"]
_ASW = PAR["align_swing_rate"]
_ASMIN = PAR["align_stance_min_s"]
_P0BGW = PAR["p0_bg_walk"]
_F_MOVED = FS["moved"]
_F_TALIGN = FS["t_align"]
_GAPF = PAR["gap_factor"]
_GAPA = PAR["gap_acc_sigma"]
_GAPW = PAR["gap_gyr_sigma"]
_GAPY = PAR["gap_yaw_sigma"]
_GAPM = PAR["gap_max_s"]
_F_COAST = FS["coast"]
_F_NBR = FS["n_bridged"]
_F_NCO = FS["n_coasted"]
_F_DTN = FS["dt_n"]
_F_DTR = FS["dtr0"]
_F_DTMIN = FS["dt_min"]
_F_TOFF = FS["t_toe_off"]
_F_HFREE = FS["hdr_free"]
_F_HLAST = FS["hdr_last_h"]
_F_HOK = FS["hdr_free_ok"]
_F_HFREF = FS["hdr_free_ref"]
_F_HTPREV = FS["hdr_turn_prev"]
_F_HCORR = FS["hdr_corr"]
_F_HBG = FS["hdr_bg0"]
_SWMIN = PAR["swing_min_s"]
_SWSPD = PAR["swing_speed"]
_F_SS = FS["sat_s0"]
_F_SCNT = FS["sat_cnt"]
_F_SOPEN = FS["sat_open"]
_F_CS0 = FS["clip_s0"]
_F_CS1 = FS["clip_s1"]
_F_CS2 = FS["clip_s2"]
_F_DIST = FS["dist"]
_N_DTR = 9


@njit(cache=True, error_model="numpy")
def quat_mul_s(p, q):
    """Hamilton product of two scalar-first quaternions."""
    out = np.empty(4)
    out[0] = p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3]
    out[1] = p[0] * q[1] + p[1] * q[0] + p[2] * q[3] - p[3] * q[2]
    out[2] = p[0] * q[2] - p[1] * q[3] + p[2] * q[0] + p[3] * q[1]
    out[3] = p[0] * q[3] + p[1] * q[2] - p[2] * q[1] + p[3] * q[0]
    return out


@njit(cache=True, error_model="numpy")
def _quat_exp_t(wx, wy, wz):
    """:func:`quat_exp_s` as a tuple ``(w, x, y, z)`` (no allocation)."""
    ang = math.sqrt(wx * wx + wy * wy + wz * wz)
    if ang > 1e-8:
        k = math.sin(0.5 * ang) / ang
    else:
        k = 0.5 - ang * ang / 48.0
    return math.cos(0.5 * ang), k * wx, k * wy, k * wz


@njit(cache=True, error_model="numpy")
def quat_exp_s(wx, wy, wz):
    """Exponential map of a rotation vector [rad] (exact, 004 Sec. 2: avoids first-order divergence)."""
    out = np.empty(4)
    out[0], out[1], out[2], out[3] = _quat_exp_t(wx, wy, wz)
    return out


@njit(cache=True, inline="always", error_model="numpy")
def _quat_dcm_into(w, x, y, z, c):
    """:func:`quat_dcm_s` of ``(w, x, y, z)`` written into ``c`` (3, 3)."""
    c[0, 0] = 1 - 2 * (y * y + z * z)
    c[0, 1] = 2 * (x * y - w * z)
    c[0, 2] = 2 * (x * z + w * y)
    c[1, 0] = 2 * (x * y + w * z)
    c[1, 1] = 1 - 2 * (x * x + z * z)
    c[1, 2] = 2 * (y * z - w * x)
    c[2, 0] = 2 * (x * z - w * y)
    c[2, 1] = 2 * (y * z + w * x)
    c[2, 2] = 1 - 2 * (x * x + y * y)


@njit(cache=True, error_model="numpy")
def quat_dcm_s(q):
    """Body-to-NED DCM of a unit quaternion."""
    c = np.empty((3, 3))
    _quat_dcm_into(q[0], q[1], q[2], q[3], c)
    return c


@njit(cache=True, error_model="numpy")
def _dcm_quat_s(m):
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    q = np.empty(4)
    if tr >= m[0, 0] and tr >= m[1, 1] and tr >= m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + tr)
        q[0] = 0.25 * s
        q[1] = (m[2, 1] - m[1, 2]) / s
        q[2] = (m[0, 2] - m[2, 0]) / s
        q[3] = (m[1, 0] - m[0, 1]) / s
    elif m[0, 0] >= m[1, 1] and m[0, 0] >= m[2, 2]:
        s = 2.0 * math.sqrt(max(1e-300, 1.0 + m[0, 0] - m[1, 1] - m[2, 2]))
        q[0] = (m[2, 1] - m[1, 2]) / s
        q[1] = 0.25 * s
        q[2] = (m[0, 1] + m[1, 0]) / s
        q[3] = (m[0, 2] + m[2, 0]) / s
    elif m[1, 1] >= m[2, 2]:
        s = 2.0 * math.sqrt(max(1e-300, 1.0 + m[1, 1] - m[0, 0] - m[2, 2]))
        q[0] = (m[0, 2] - m[2, 0]) / s
        q[1] = (m[0, 1] + m[1, 0]) / s
        q[2] = 0.25 * s
        q[3] = (m[1, 2] + m[2, 1]) / s
    else:
        s = 2.0 * math.sqrt(max(1e-300, 1.0 + m[2, 2] - m[0, 0] - m[1, 1]))
        q[0] = (m[1, 0] - m[0, 1]) / s
        q[1] = (m[0, 2] + m[2, 0]) / s
        q[2] = (m[1, 2] + m[2, 1]) / s
        q[3] = 0.25 * s
    n = math.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
    if q[0] < 0:
        n = -n
    for k in range(4):
        q[k] /= n
    return q


@njit(cache=True, error_model="numpy")
def strapdown_run(t, acc, gyr, q0, v0, p0, gravity, qs, vs, ps):
    """Free-inertial mechanisation (004 eq. 1) of a whole record, the compiled twin of
    :func:`models.strapdown.strapdown_step` applied sample by sample (exact attitude, mean DCM, trapezoidal
    position); fills ``qs`` (N,4), ``vs`` (N,3), ``ps`` (N,3)."""
    n = t.shape[0]
    q = q0.copy()
    v = v0.copy()
    p = p0.copy()
    for j in range(4):
        qs[0, j] = q[j]
    for j in range(3):
        vs[0, j] = v[j]
        ps[0, j] = p[j]
    for k in range(1, n):
        dt = t[k] - t[k - 1]
        c0 = quat_dcm_s(q)
        q1 = quat_mul_s(q, quat_exp_s(gyr[k, 0] * dt, gyr[k, 1] * dt, gyr[k, 2] * dt))
        nq = math.sqrt(q1[0] * q1[0] + q1[1] * q1[1] + q1[2] * q1[2] + q1[3] * q1[3])
        for j in range(4):
            q1[j] /= nq
        c1 = quat_dcm_s(q1)
        for i in range(3):
            a_n = 0.0
            for j in range(3):
                a_n += 0.5 * (c0[i, j] + c1[i, j]) * acc[k, j]
            if i == 2:
                a_n += gravity
            v1 = v[i] + a_n * dt
            p[i] = p[i] + 0.5 * (v[i] + v1) * dt
            v[i] = v1
        q = q1
        for j in range(4):
            qs[k, j] = q[j]
        for j in range(3):
            vs[k, j] = v[j]
            ps[k, j] = p[j]


@njit(cache=True, error_model="numpy")
def triad_s(r1, r2, s1, s2):
    """TRIAD (002 Appendix A): rotation C with ``C r1 = s1`` exactly and ``C r2 ~ s2`` (body r, nav s).

    Returns the DCM, or an all-NaN matrix when either pair is (nearly) parallel.
    """
    c = np.empty((3, 3))
    tb = np.empty((3, 3))
    tn = np.empty((3, 3))
    for vec_a, vec_b, t in ((r1, r2, tb), (s1, s2, tn)):
        na = math.sqrt(vec_a[0] ** 2 + vec_a[1] ** 2 + vec_a[2] ** 2)
        cx = vec_a[1] * vec_b[2] - vec_a[2] * vec_b[1]
        cy = vec_a[2] * vec_b[0] - vec_a[0] * vec_b[2]
        cz = vec_a[0] * vec_b[1] - vec_a[1] * vec_b[0]
        nc = math.sqrt(cx * cx + cy * cy + cz * cz)
        nb = math.sqrt(vec_b[0] ** 2 + vec_b[1] ** 2 + vec_b[2] ** 2)
        if na == 0.0 or nb == 0.0 or nc < 1e-6 * na * nb:
            c[:, :] = np.nan
            return c
        t1 = vec_a / na
        t2 = np.array([cx, cy, cz]) / nc
        t[:, 0] = t1
        t[:, 1] = t2
        t[0, 2] = t1[1] * t2[2] - t1[2] * t2[1]
        t[1, 2] = t1[2] * t2[0] - t1[0] * t2[2]
        t[2, 2] = t1[0] * t2[1] - t1[1] * t2[0]
    for i in range(3):
        for j in range(3):
            c[i, j] = tn[i, 0] * tb[j, 0] + tn[i, 1] * tb[j, 1] + tn[i, 2] * tb[j, 2]
    return c


@njit(cache=True, error_model="numpy")
def _symmetrise(P):
    """In-place ``P <- (P + P^T) / 2``. Rounding leaves the updates slightly asymmetric and the filter amplified
    that part (x1000 every 5 min of walking) until P lost positive definiteness after 25 min of continuous
    walking (synthetic 62-min walk: not PSD at 1504 s, singular innovation covariance at 1557 s)."""
    n = P.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            v = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = v
            P[j, i] = v


@njit(cache=True, error_model="numpy")
def cov_predict(P, C, fn, dt, qa, qg, qba, qbg):
    """In-place ``P <- F P F^T + Q`` with ``F = I + A dt`` exploiting the sparsity of A (004 eq. 7-8).

    A has non-zero blocks dp/dv = I, dv/dphi = -[fn x], dv/dba = -C, dphi/dbg = -C. Allocates its work arrays;
    the navigator's kernel calls :func:`_cov_predict_w` with arrays made once per call.
    """
    _cov_predict_w(P, C, fn, dt, qa, qg, qba, qbg, np.empty((9, 15)), np.empty((9, 9)))


@njit(cache=True, error_model="numpy")
def _cov_predict_w(P, C, fn, dt, qa, qg, qba, qbg, B, M):
    """:func:`cov_predict` with work arrays ``B`` (9, 15) and ``M`` (9, 9) (no allocation per sample).

    ``P`` must be symmetric (every routine here leaves it so): ``P + dt (B + B^T) + dt^2 M + Q dt`` is formed
    for the upper triangle only and mirrored, so it stays exactly symmetric without a separate
    :func:`_symmetrise` pass (rows and columns 9..14 of the bias block change only on the diagonal).
    """
    f0 = fn[0]
    f1 = fn[1]
    f2 = fn[2]
    c00 = C[0, 0]
    c01 = C[0, 1]
    c02 = C[0, 2]
    c10 = C[1, 0]
    c11 = C[1, 1]
    c12 = C[1, 2]
    c20 = C[2, 0]
    c21 = C[2, 1]
    c22 = C[2, 2]
    # B = A P (rows 0..8 only; rows 9..14 of A are zero); [fn x] = [[0, -f2, f1], [f2, 0, -f0], [-f1, f0, 0]]
    for j in range(15):
        p6 = P[6, j]
        p7 = P[7, j]
        p8 = P[8, j]
        p9 = P[9, j]
        p10 = P[10, j]
        p11 = P[11, j]
        p12 = P[12, j]
        p13 = P[13, j]
        p14 = P[14, j]
        B[0, j] = P[3, j]
        B[1, j] = P[4, j]
        B[2, j] = P[5, j]
        B[3, j] = -(-f2 * p7 + f1 * p8 + c00 * p9 + c01 * p10 + c02 * p11)
        B[4, j] = -(f2 * p6 - f0 * p8 + c10 * p9 + c11 * p10 + c12 * p11)
        B[5, j] = -(-f1 * p6 + f0 * p7 + c20 * p9 + c21 * p10 + c22 * p11)
        B[6, j] = -(c00 * p12 + c01 * p13 + c02 * p14)
        B[7, j] = -(c10 * p12 + c11 * p13 + c12 * p14)
        B[8, j] = -(c20 * p12 + c21 * p13 + c22 * p14)
    dt2 = dt * dt
    # M = A P A^T = B A^T (9x9; only its upper triangle is used)
    for i in range(9):
        b6 = B[i, 6]
        b7 = B[i, 7]
        b8 = B[i, 8]
        b9 = B[i, 9]
        b10 = B[i, 10]
        b11 = B[i, 11]
        b12 = B[i, 12]
        b13 = B[i, 13]
        b14 = B[i, 14]
        M[i, 0] = B[i, 3]
        M[i, 1] = B[i, 4]
        M[i, 2] = B[i, 5]
        M[i, 3] = -(-f2 * b7 + f1 * b8 + c00 * b9 + c01 * b10 + c02 * b11)
        M[i, 4] = -(f2 * b6 - f0 * b8 + c10 * b9 + c11 * b10 + c12 * b11)
        M[i, 5] = -(-f1 * b6 + f0 * b7 + c20 * b9 + c21 * b10 + c22 * b11)
        M[i, 6] = -(c00 * b12 + c01 * b13 + c02 * b14)
        M[i, 7] = -(c10 * b12 + c11 * b13 + c12 * b14)
        M[i, 8] = -(c20 * b12 + c21 * b13 + c22 * b14)
    for i in range(9):
        for j in range(i, 9):
            v = P[i, j] + dt * (B[i, j] + B[j, i]) + dt2 * M[i, j]
            P[i, j] = v
            P[j, i] = v
        for j in range(9, 15):
            v = P[i, j] + dt * B[i, j]
            P[i, j] = v
            P[j, i] = v
    for kk in range(3):
        P[3 + kk, 3 + kk] += qa * dt
        P[6 + kk, 6 + kk] += qg * dt
        P[9 + kk, 9 + kk] += qba * dt
        P[12 + kk, 12 + kk] += qbg * dt


@njit(cache=True, error_model="numpy")
def _update_block3(P, dx, i0, z, r):
    """Joseph-form update (004 eq. 13) for a measurement ``z = dx[i0:i0+3] + noise(r^2 I)``. Allocates its work
    arrays; the navigator's kernel calls :func:`_update_block3_w` with arrays made once per call."""
    _update_block3_w(P, dx, i0, z[0], z[1], z[2], r, np.empty((15, 3)), np.empty((3, 15)), np.empty((15, 3)))


@njit(cache=True, error_model="numpy")
def _update_block3_w(P, dx, i0, z0, z1, z2, r, K, Hp, G):
    """:func:`_update_block3` for ``z = (z0, z1, z2)`` with work arrays ``K`` (15, 3), ``Hp`` (3, 15), ``G`` (15, 3).

    The innovation covariance ``S = P[i0:i0+3, i0:i0+3] + r^2 I`` is symmetric positive definite (``r > 0``), so
    its inverse is the adjugate over the determinant (closed form, no LU). The Joseph form
    ``(I - K H) P (I - K H)^T + K R K^T = P - K (H P) + (r^2 K - P1 H^T) K^T`` with ``P1 H^T = P H^T - K (H P H^T)``
    is evaluated for the upper triangle and mirrored: it is symmetric in exact arithmetic, and mirroring leaves
    ``P`` exactly symmetric as :func:`_symmetrise` did.
    """
    r2 = r * r
    s00 = P[i0, i0] + r2
    s01 = P[i0, i0 + 1]
    s02 = P[i0, i0 + 2]
    s11 = P[i0 + 1, i0 + 1] + r2
    s12 = P[i0 + 1, i0 + 2]
    s22 = P[i0 + 2, i0 + 2] + r2
    a00 = s11 * s22 - s12 * s12
    a01 = s02 * s12 - s01 * s22
    a02 = s01 * s12 - s02 * s11
    a11 = s00 * s22 - s02 * s02
    a12 = s01 * s02 - s00 * s12
    a22 = s00 * s11 - s01 * s01
    idet = 1.0 / (s00 * a00 + s01 * a01 + s02 * a02)
    i00 = a00 * idet
    i01 = a01 * idet
    i02 = a02 * idet
    i11 = a11 * idet
    i12 = a12 * idet
    i22 = a22 * idet
    for j in range(15):
        Hp[0, j] = P[i0, j]
        Hp[1, j] = P[i0 + 1, j]
        Hp[2, j] = P[i0 + 2, j]
    for i in range(15):
        p0 = Hp[0, i]
        p1 = Hp[1, i]
        p2 = Hp[2, i]
        K[i, 0] = p0 * i00 + p1 * i01 + p2 * i02
        K[i, 1] = p0 * i01 + p1 * i11 + p2 * i12
        K[i, 2] = p0 * i02 + p1 * i12 + p2 * i22
    e0 = z0 - dx[i0]
    e1 = z1 - dx[i0 + 1]
    e2 = z2 - dx[i0 + 2]
    for i in range(15):
        dx[i] += K[i, 0] * e0 + K[i, 1] * e1 + K[i, 2] * e2
    # H P H^T: the 3x3 block of P at the measured states
    h00 = Hp[0, i0]
    h01 = Hp[0, i0 + 1]
    h02 = Hp[0, i0 + 2]
    h11 = Hp[1, i0 + 1]
    h12 = Hp[1, i0 + 2]
    h22 = Hp[2, i0 + 2]
    for i in range(15):
        k0 = K[i, 0]
        k1 = K[i, 1]
        k2 = K[i, 2]
        # G = r^2 K - P1 H^T
        G[i, 0] = r2 * k0 - (Hp[0, i] - (k0 * h00 + k1 * h01 + k2 * h02))
        G[i, 1] = r2 * k1 - (Hp[1, i] - (k0 * h01 + k1 * h11 + k2 * h12))
        G[i, 2] = r2 * k2 - (Hp[2, i] - (k0 * h02 + k1 * h12 + k2 * h22))
    for i in range(15):
        k0 = K[i, 0]
        k1 = K[i, 1]
        k2 = K[i, 2]
        u0 = G[i, 0]
        u1 = G[i, 1]
        u2 = G[i, 2]
        for j in range(i, 15):
            v = P[i, j] - (k0 * Hp[0, j] + k1 * Hp[1, j] + k2 * Hp[2, j]) + (u0 * K[j, 0] + u1 * K[j, 1] + u2 * K[j, 2])
            P[i, j] = v
            P[j, i] = v


@njit(cache=True, error_model="numpy")
def _update_scalar(P, dx, h, z, r2, gate):
    """Joseph-form scalar update with row ``h`` (15,), innovation gate in sigmas; returns True if applied."""
    ph = P @ h
    s = h @ ph + r2
    innov = z - h @ dx
    if gate > 0 and innov * innov > gate * gate * s:
        return False
    k = ph / s
    dx += k * innov
    IKH = np.eye(15) - np.outer(k, h)
    P[:, :] = IKH @ P @ IKH.T + r2 * np.outer(k, k)
    _symmetrise(P)
    return True


@njit(cache=True, error_model="numpy")
def _apply_correction(x, dx):
    """Inject the error state into the nominal state and reset it (004 eq. 12). Scalar arithmetic (no
    allocation): ``q <- exp(phi) (x) q``, normalised, as :func:`quat_exp_s` and :func:`quat_mul_s` compute it."""
    for k in range(3):
        x[7 + k] += dx[k]
        x[4 + k] += dx[3 + k]
        x[10 + k] += dx[9 + k]
        x[13 + k] += dx[12 + k]
    p0, p1, p2, p3 = _quat_exp_t(dx[6], dx[7], dx[8])
    q0 = x[0]
    q1 = x[1]
    q2 = x[2]
    q3 = x[3]
    r0 = p0 * q0 - p1 * q1 - p2 * q2 - p3 * q3
    r1 = p0 * q1 + p1 * q0 + p2 * q3 - p3 * q2
    r2 = p0 * q2 - p1 * q3 + p2 * q0 + p3 * q1
    r3 = p0 * q3 + p1 * q2 - p2 * q1 + p3 * q0
    n = math.sqrt(r0 ** 2 + r1 ** 2 + r2 ** 2 + r3 ** 2)
    x[0] = r0 / n
    x[1] = r1 / n
    x[2] = r2 / n
    x[3] = r3 / n
    dx[:] = 0.0


@njit(cache=True, error_model="numpy")
def _heading_row(C):
    """Row of H mapping the error state to the heading error (004 Appendix A eq. 30, the D row)."""
    h = np.zeros(15)
    d = C[0, 0] ** 2 + C[1, 0] ** 2
    if d < 1e-9:
        d = 1e-9
    h[6] = -C[0, 0] * C[2, 0] / d
    h[7] = -C[1, 0] * C[2, 0] / d
    h[8] = 1.0
    return h


@njit(cache=True, error_model="numpy")
def _align(x, P, fs, par, has_mag, dur, rest):
    """Initial alignment from the mean rest specific force (+ field) (001 eq. 1-5, any mounting, via TRIAD).

    ``rest`` False: the samples are a walking stance (mid-walk start), whose mean rate is the foot's residual
    roll-over rather than the gyro bias; the bias then starts at zero.
    """
    n = fs[11]
    fb = np.array([fs[2] / n, fs[3] / n, fs[4] / n])
    down_b = -fb  # at rest the accelerometer reads -g_n (up)
    down_n = np.array([0.0, 0.0, 1.0])
    C = np.full((3, 3), np.nan)
    if has_mag and fs[12] > 0:
        mb = np.array([fs[8] / fs[12], fs[9] / fs[12], fs[10] / fs[12]])
        if fs[26] > 0:
            ref = np.array([fs[23], fs[24], fs[25]])
        else:
            ref = np.array([1.0, 0.0, 0.0])
        C = triad_s(down_b, mb, down_n, ref)
    if np.isnan(C[0, 0]):
        # no field: heading of the body x axis (else y axis) is set to zero
        ex = np.array([1.0, 0.0, 0.0])
        nd = math.sqrt(down_b @ down_b)
        if abs(down_b[0]) > 0.9 * nd:
            ex = np.array([0.0, 1.0, 0.0])
            C = triad_s(down_b, ex, down_n, np.array([0.0, 1.0, 0.0]))
        else:
            C = triad_s(down_b, ex, down_n, np.array([1.0, 0.0, 0.0]))
    q = _dcm_quat_s(C)
    x[0:4] = q
    x[4:10] = 0.0
    x[10:13] = 0.0
    use_b = dur / (dur + par[_BSHR]) if (par[_BREST] > 0 and rest) else 0.0
    x[13] = use_b * fs[5] / n
    x[14] = use_b * fs[6] / n
    x[15] = use_b * fs[7] / n
    P[:, :] = 0.0
    for k in range(3):
        P[9 + k, 9 + k] = par[_P0BA] ** 2
        P[12 + k, 12 + k] = par[_P0BG] ** 2 if rest else par[_P0BGW] ** 2
    P[6, 6] = par[_P0T] ** 2
    P[7, 7] = par[_P0T] ** 2
    P[8, 8] = par[_P0Y] ** 2
    if has_mag and fs[12] > 0 and fs[26] == 0:
        # expected field from the rest period (in NED, after alignment)
        mb = np.array([fs[8] / fs[12], fs[9] / fs[12], fs[10] / fs[12]])
        mn = C @ mb
        fs[23] = mn[0]
        fs[24] = mn[1]
        fs[25] = mn[2]
        fs[26] = 1.0


@njit(cache=True, error_model="numpy")
def _shoe_at(i, t, acc, gyr, hw, g, sa2, sw2):
    """SHOE statistic of sample i over the samples within +-hw [s] (at least one neighbour each side)."""
    n_all = t.shape[0]
    j0 = i - 1 if i > 0 else 0
    while j0 > 0 and t[i] - t[j0 - 1] <= hw:
        j0 -= 1
    j1 = i + 1 if i + 1 < n_all else i
    while j1 + 1 < n_all and t[j1 + 1] - t[i] <= hw:
        j1 += 1
    m0 = 0.0
    m1 = 0.0
    m2 = 0.0
    for j in range(j0, j1 + 1):
        m0 += acc[j, 0]
        m1 += acc[j, 1]
        m2 += acc[j, 2]
    nm = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
    if nm > 0:
        m0 /= nm
        m1 /= nm
        m2 /= nm
    T = 0.0
    for j in range(j0, j1 + 1):
        r0 = acc[j, 0] - g * m0
        r1 = acc[j, 1] - g * m1
        r2 = acc[j, 2] - g * m2
        T += (r0 * r0 + r1 * r1 + r2 * r2) / sa2 + (gyr[j, 0] ** 2 + gyr[j, 1] ** 2 + gyr[j, 2] ** 2) / sw2
    return T / (j1 - j0 + 1)


@njit(cache=True, error_model="numpy")
def _gyr_at(t, gyr, tq):
    """Angular rate [rad/s] at time ``tq`` [s], linear between samples (held beyond the buffer's ends)."""
    n = t.shape[0]
    if tq <= t[0]:
        return gyr[0].copy()
    if tq >= t[n - 1]:
        return gyr[n - 1].copy()
    j = np.searchsorted(t, tq) - 1
    u = (tq - t[j]) / (t[j + 1] - t[j])
    return (1.0 - u) * gyr[j] + u * gyr[j + 1]


@njit(cache=True, error_model="numpy")
def _gyr_at_into(t, gyr, tq, out, hint):
    """:func:`_gyr_at` written into ``out`` (3,) (no allocation per sample). ``hint``: an index with
    ``t[hint] < tq`` from which the bracketing interval is searched forward (the kernel's queries move forward
    a sample at a time); -1 for a binary search."""
    n = t.shape[0]
    if tq <= t[0]:
        for a in range(3):
            out[a] = gyr[0, a]
    elif tq >= t[n - 1]:
        for a in range(3):
            out[a] = gyr[n - 1, a]
    else:
        if 0 <= hint < n - 1 and t[hint] < tq:
            j = hint
            while t[j + 1] < tq:
                j += 1
        else:
            j = np.searchsorted(t, tq) - 1
        u = (tq - t[j]) / (t[j + 1] - t[j])
        for a in range(3):
            out[a] = (1.0 - u) * gyr[j, a] + u * gyr[j + 1, a]


@njit(cache=True, error_model="numpy")
def _wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


@njit(cache=True, error_model="numpy")
def _hdr_new_segment(x, fs, psi, turn):
    """End the straight segment; the stride of chord direction ``psi`` [rad] starts the next. With ``turn``
    [rad] (the foot turned on two strides running) the pull of the turn's first strides is taken back: the
    heading's and the gyro bias's (the update also moved the bias, through their covariance)."""
    fs[30] = psi
    fs[31] = 1.0
    fs[_F_HFREF] = fs[_F_HFREE]
    fs[_F_HTPREV] = 0.0
    if fs[_F_HCORR] != 0.0 and turn * fs[_F_HCORR] < 0.0:
        c = -fs[_F_HCORR]
        x[0:4] = quat_mul_s(np.array([math.cos(c / 2), 0.0, 0.0, math.sin(c / 2)]), x[0:4].copy())
        x[13:16] = fs[_F_HBG : _F_HBG + 3]
        fs[_F_HLAST] = _heading_of(x)
    fs[_F_HCORR] = 0.0


@njit(cache=True, error_model="numpy")
def _hdr(x, P, dx, fs, par):
    """Heuristic drift reduction (003 Sec. drift reduction; Borenstein's HDR): while strides keep one
    direction, the heading is pulled back to that segment's direction; a turn starts a new segment.

    A turn is a chord beyond ``hdr_delta`` of the segment's. A gradual turn's first chord may lie inside it (a
    turning stride's chord is half-way through its turn: 5.6 deg of a 45-deg turn over four strides) and was
    pulled back, 0.7 deg of that turn lost. With ``hdr_turn``, a turn whose foot also turned beyond ``hdr_turn``
    from the segment's heading on its stride and the one before, the same way, takes back the pull of its
    strides whose chord went the foot's way by at least a quarter of the foot's turn, since the foot last pointed
    along the segment (within ``hdr_turn / 2``). The foot's heading here is ``hdr_free``, the filter's without
    the pull's own corrections (what the gyroscope turned). One stance's foot yaw strays far (gdin, straight
    strides: median 2.6 deg, p95 19 deg from the segment's), two running beyond 10 deg never did there.
    """
    h = _heading_of(x)
    if fs[_F_HOK] > 0:
        fs[_F_HFREE] = fs[_F_HFREE] + _wrap(h - fs[_F_HLAST])
    else:
        fs[_F_HOK] = 1.0
        fs[31] = 0.0  # after a reset the segment starts again
    fs[_F_HLAST] = h
    dn = x[7] - fs[15]
    de = x[8] - fs[16]
    if math.sqrt(dn * dn + de * de) < par[_HDRL]:
        return
    psi = math.atan2(de, dn)
    d = _wrap(psi - fs[30])
    turn = _wrap(fs[_F_HFREE] - fs[_F_HFREF])
    thr = par[_HDRT]
    if fs[31] > 0 and abs(d) < par[_HDRD]:
        if thr > 0 and abs(turn) < 0.5 * thr:
            fs[_F_HCORR] = 0.0  # the foot points along the segment: nothing before this belongs to a turn
            fs[_F_HBG : _F_HBG + 3] = x[13:16]
        fs[_F_HTPREV] = turn
        if fs[31] == 1:
            # the segment's first stride may be the last of a turn (its chord part-way through it): the first stride
            # that agrees with it sets the reference
            fs[30] = psi
            fs[_F_HFREF] = fs[_F_HFREE]
            d = 0.0
        else:
            # the foot's reference follows slowly (gyro drift), one stray stance moves it little
            fs[_F_HFREF] = fs[_F_HFREF] + 0.1 * max(-par[_HDRD], min(par[_HDRD], turn))
        fs[31] += 1
        if fs[31] == par[_HDRN] + 1 and par[_DOM] > 0:
            # a segment just became straight: snap its reference to the nearest dominant direction
            if fs[33] == 0:
                fs[32] = fs[30]
                fs[33] = 1.0
            else:
                k = round((fs[30] - fs[32]) / (0.5 * math.pi))
                dom = fs[32] + k * 0.5 * math.pi
                dd = _wrap(fs[30] - dom)
                if abs(dd) < par[_DOMD]:
                    fs[30] = fs[30] - dd
                    d = _wrap(psi - fs[30])
        if fs[31] > par[_HDRN]:
            C = quat_dcm_s(x[0:4])
            hr = _heading_row(C)
            if _update_scalar(P, dx, hr, -d, par[_HDRS] ** 2, 0.0):
                _apply_correction(x, dx)
                h2 = _heading_of(x)
                if turn * d > 0 and abs(d) >= 0.25 * abs(turn):
                    # the chord went the way the foot turned, as a turning stride's does (half-way through its
                    # turn): a pull a turn may take back
                    fs[_F_HCORR] = fs[_F_HCORR] + _wrap(h2 - h)
                fs[_F_HLAST] = h2
        # follow slow curvature of the segment (not once it is locked to a dominant direction)
        if par[_DOM] == 0 or fs[31] <= par[_HDRN]:
            fs[30] = fs[30] + 0.1 * d
    else:
        # the foot turned on this stride and the one before, the same way: a turn, whose first strides' pull
        # is taken back
        turned = thr > 0 and abs(turn) > thr and abs(fs[_F_HTPREV]) > thr and turn * fs[_F_HTPREV] > 0
        _hdr_new_segment(x, fs, psi, turn if turned else 0.0)


@njit(cache=True, error_model="numpy")
def _mech_step(x, P, wx, wy, wz, f0, f1, f2, dt, par, C1, Cm, fn, B, M):
    """One strapdown step (004 eq. 1) over ``dt`` [s]: attitude by the exact exponential map of the rotation
    vector ``(wx, wy, wz)`` [rad, body, bias removed], velocity and position [NED] by the specific force
    ``(f0, f1, f2)`` [m/s^2, body, bias removed] rotated with the mean of the DCMs at both ends; covariance
    predicted (004 eq. 7-8) with the scale-factor term. Writes the body-to-NED DCM at the end of the step into
    ``C1`` (3, 3); ``Cm`` (3, 3), ``fn`` (3,), ``B`` (9, 15), ``M`` (9, 9) are work arrays (no allocation)."""
    g = par[_GRAV]
    q0 = x[0]
    q1 = x[1]
    q2 = x[2]
    q3 = x[3]
    _quat_dcm_into(q0, q1, q2, q3, Cm)  # C0
    if par[_FO] > 0:
        d0 = 1.0
        d1 = 0.5 * wx
        d2 = 0.5 * wy
        d3 = 0.5 * wz
    else:
        d0, d1, d2, d3 = _quat_exp_t(wx, wy, wz)
    r0 = q0 * d0 - q1 * d1 - q2 * d2 - q3 * d3
    r1 = q0 * d1 + q1 * d0 + q2 * d3 - q3 * d2
    r2 = q0 * d2 - q1 * d3 + q2 * d0 + q3 * d1
    r3 = q0 * d3 + q1 * d2 - q2 * d1 + q3 * d0
    nq = math.sqrt(r0 ** 2 + r1 ** 2 + r2 ** 2 + r3 ** 2)
    r0 /= nq
    r1 /= nq
    r2 /= nq
    r3 /= nq
    _quat_dcm_into(r0, r1, r2, r3, C1)
    for a in range(3):
        for b in range(3):
            Cm[a, b] = 0.5 * (Cm[a, b] + C1[a, b])
        fn[a] = Cm[a, 0] * f0 + Cm[a, 1] * f1 + Cm[a, 2] * f2
    vn0 = x[4]
    vn1 = x[5]
    vn2 = x[6]
    x[0] = r0
    x[1] = r1
    x[2] = r2
    x[3] = r3
    x[4] += fn[0] * dt
    x[5] += fn[1] * dt
    x[6] += (fn[2] + g) * dt
    x[7] += 0.5 * (vn0 + x[4]) * dt
    x[8] += 0.5 * (vn1 + x[5]) * dt
    x[9] += 0.5 * (vn2 + x[6]) * dt
    if dt > 0:
        _cov_predict_w(P, Cm, fn, dt, par[_QA], par[_QG], par[_QBA], par[_QBG], B, M)
        if par[_GSS] > 0:
            # scale-factor error: an angle turned by theta adds (sigma_s * theta)^2 of attitude variance
            qs = (par[_GSS] * math.sqrt(wx * wx + wy * wy + wz * wz)) ** 2
            P[6, 6] += qs
            P[7, 7] += qs
            P[8, 8] += qs


@njit(cache=True, inline="always", error_model="numpy")
def _nominal_dt(fs, dt, factor):
    """Nominal sampling interval [s] for the gap test ``dt > factor * nominal``: the median of the latest
    intervals (robust to jitter and to the gaps themselves); then ``dt`` joins them. Returns 0 while fewer
    than 3 intervals have been seen.

    The median is only worked out when ``dt`` exceeds ``factor`` times the smallest of them (otherwise it is
    no gap whatever the median, and the smallest is returned); the smallest is kept up to date as intervals
    come and go, so the common case costs a few comparisons.
    """
    n = int(fs[_F_DTN])
    m = n if n < _N_DTR else _N_DTR
    lo = fs[_F_DTMIN]
    med = 0.0
    if m >= 3:
        med = lo
        if dt > factor * lo:
            buf = fs[_F_DTR : _F_DTR + m].copy()
            buf.sort()
            med = buf[m // 2]
    j = n % _N_DTR
    out = fs[_F_DTR + j]
    fs[_F_DTR + j] = dt
    fs[_F_DTN] = n + 1
    if n == 0 or dt <= lo:
        fs[_F_DTMIN] = dt
    elif n >= _N_DTR and out <= lo:
        # the smallest left the window: find the new one
        lo = fs[_F_DTR]
        for k in range(1, _N_DTR):
            if fs[_F_DTR + k] < lo:
                lo = fs[_F_DTR + k]
        fs[_F_DTMIN] = lo
    return med


@njit(cache=True, error_model="numpy")
def _heading_of(x):
    """Heading of the body x axis [rad] of the nominal state's attitude quaternion (atan2(C21, C11))."""
    return math.atan2(2 * (x[1] * x[2] + x[0] * x[3]), 1 - 2 * (x[2] ** 2 + x[3] ** 2))


@njit(cache=True, error_model="numpy")
def _relevel(x, f_mean):
    """Roll and pitch from a still foot's mean specific force ``f_mean`` [m/s^2, body] (001 eq. 1-3): the
    attitude is turned by the smallest rotation (about a horizontal axis) that makes the specific force point
    up, as a ZUPT-KF tilt correction (004 eq. 12 with no heading part) would; the heading is not touched.

    After a long gap the attitude is wrong by what the gyroscope did not see, mostly a rotation about the
    foot's pitch axis: that axis is horizontal, so this rotation undoes it without turning the heading.
    Keeping the azimuth of a body axis instead (TRIAD with the old x axis) failed where x was near vertical
    in the swing: 30 deg of heading after one 0.5-s gap.
    """
    nf = math.sqrt(f_mean @ f_mean)
    if nf == 0.0:
        return
    u = quat_dcm_s(x[0:4]) @ (f_mean / nf)  # measured specific force direction in NED (should be up: 0, 0, -1)
    # axis u x (0, 0, -1) = (-u1, u0, 0), angle between u and up
    ax0 = -u[1]
    ax1 = u[0]
    s_ = math.sqrt(ax0 * ax0 + ax1 * ax1)
    if s_ < 1e-12:
        return
    ang = math.atan2(s_, -u[2])
    dq = quat_exp_s(ax0 / s_ * ang, ax1 / s_ * ang, 0.0)
    q = quat_mul_s(dq, x[0:4].copy())
    nq = math.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
    for k in range(4):
        x[k] = q[k] / nq


@njit(cache=True, error_model="numpy")
def _clip_runs(fs, sat, sig, dt, q):
    """Advance the per-channel sums ``sum sigma * dt`` of the current runs of clipped samples (``sat`` bits 0-5,
    ``sig`` (6,) the 1-sigma error of this sample's values, :class:`models.saturation.ClipRepair`); a channel not
    clipped ends its run. Writes the variance increments into ``q`` (6,): the error of a clipped (or repaired) value
    persists over its run, so the run's error grows with its length, ``(sum sigma dt)^2``, not with the square root
    of its sample count (independent of the sample rate)."""
    for a in range(6):
        if (sat >> a) & 1:
            s0 = fs[_F_SS + a]
            s1 = s0 + sig[a] * dt
            fs[_F_SS + a] = s1
            q[a] = s1 * s1 - s0 * s0
        else:
            fs[_F_SS + a] = 0.0
            q[a] = 0.0


@njit(cache=True, error_model="numpy")
def _clip_noise(P, C, q, fs):
    """Covariance of what clipped axes missed (``q`` (6,) variance increments, acc then gyr) along the body axis
    ``u = C e_a`` in the navigation frame: velocity for the accelerometer; for the gyroscope the horizontal part of
    ``u`` is tilt (``phi`` north/east, which the next ZUPT re-levels, correcting velocity and position through the
    covariance) and its vertical part heading, which no ZUPT observes: that part is kept aside (``clip_s*``) and
    only reported, with the position variance it causes as the foot travels on (:func:`_sigmas`)."""
    for a in range(6):
        if q[a] == 0.0:
            continue
        ax = a - 3 if a >= 3 else a
        if a < 3:
            for r in range(3):
                for c in range(3):
                    P[3 + r, 3 + c] += q[a] * C[r, ax] * C[c, ax]
            continue
        for r in range(2):
            for c in range(2):
                P[6 + r, 6 + c] += q[a] * C[r, ax] * C[c, ax]
        v = q[a] * C[2, ax] * C[2, ax]
        d = fs[_F_DIST]
        fs[_F_CS0] += v
        fs[_F_CS1] += v * d
        fs[_F_CS2] += v * d * d


@njit(cache=True, inline="always", error_model="numpy")
def _sigmas(x, P, fs):
    """1-sigma heading [rad] (004 Appendix A's heading row, :func:`_heading_row`) and horizontal position [m]: the
    covariance's, plus the heading clipped gyroscope axes lost (``clip_s0``) and the position error it has caused
    over the distance travelled since. Scalar arithmetic: it runs for every output sample."""
    w, a, b, c = x[0], x[1], x[2], x[3]
    c00 = 1.0 - 2.0 * (b * b + c * c)
    c10 = 2.0 * (a * b + w * c)
    c20 = 2.0 * (a * c - w * b)
    d = c00 * c00 + c10 * c10
    if d < 1e-9:
        d = 1e-9
    h6 = -c00 * c20 / d
    h7 = -c10 * c20 / d
    var = (h6 * h6 * P[6, 6] + h7 * h7 * P[7, 7] + P[8, 8] + 2.0 * h6 * h7 * P[6, 7] + 2.0 * h6 * P[6, 8]
           + 2.0 * h7 * P[7, 8])
    dist = fs[_F_DIST]
    extra = dist * dist * fs[_F_CS0] - 2.0 * dist * fs[_F_CS1] + fs[_F_CS2]
    return math.sqrt(max(var + fs[_F_CS0], 0.0)), math.sqrt(max(P[0, 0] + P[1, 1] + extra, 0.0))


@njit(cache=True, error_model="numpy")
def run_kernel(t, acc, gyr, mag, sat_in, sig_in, i0, final, x, P, fs, ist, par, o_pos, o_vel, o_head, o_zupt, o_stat,
               o_sat, o_hsig, o_psig, st_out):
    """Process samples ``i0..`` of a buffer; returns ``(next_index, n_stances)``.

    Parameters
    ----------
    t : (N,) float64 [s], strictly increasing; acc (N,3) [m/s^2]; gyr (N,3) [rad/s]; mag (N,3) [uT] (NaN = none).
    sat_in : (N,) uint8 clipped axes (bits 0-2 acc, 3-5 gyr); sig_in : (N, 6) 1-sigma error of their values
    (:class:`models.saturation.ClipRepair`).
    i0 : first unprocessed index; samples before it are detector history.
    final : process to the end even without the detector's look-ahead (flush).
    x : (16,) nominal state q(4) v(3) p(3) ba(3) bg(3), in/out. P : (15,15) in/out. fs, ist : float/int state.
    par : (N_PAR,) parameters. o_* : outputs per processed sample (index i - i0): position, velocity, heading,
    ZUPT flag, detector statistic, clipped axes (bits 0-2 accelerometer, 3-5 gyroscope), 1-sigma heading [rad] and
    horizontal position [m]. st_out : stance records (:data:`ST_COLS`).
    """
    n_all = t.shape[0]
    hw = par[_HW]
    g = par[_GRAV]
    sa2 = par[_SA] ** 2
    sw2 = par[_SW] ** 2
    ew = par[_EROS]
    dx = np.zeros(15)
    q_sat = np.zeros(6)
    # work arrays, made once per call: the per-sample path allocates nothing
    w_i = np.empty(3)
    w_p = np.empty(3)
    C1 = np.empty((3, 3))
    Cm = np.empty((3, 3))
    fnw = np.empty(3)
    Bw = np.empty((9, 15))
    Mw = np.empty((9, 9))
    Kw = np.empty((15, 3))
    Hw = np.empty((3, 15))
    Gw = np.empty((15, 3))
    n_st = 0
    i = i0
    while i < n_all:
        if not final and (i + 1 >= n_all or t[n_all - 1] <= t[i] + hw + ew + par[_GDEL]):
            break
        # ---- SHOE / GLRT statistic (002 eq. 1-2), eroded: max over +-erosion_s (no ZUPT at swing edges) ----
        T = _shoe_at(i, t, acc, gyr, hw, g, sa2, sw2)
        if ew > 0.0:
            j = i - 1
            while j >= 0 and t[i] - t[j] <= ew:
                v = _shoe_at(j, t, acc, gyr, hw, g, sa2, sw2)
                if v > T:
                    T = v
                j -= 1
            j = i + 1
            while j < n_all and t[j] - t[i] <= ew:
                v = _shoe_at(j, t, acc, gyr, hw, g, sa2, sw2)
                if v > T:
                    T = v
                j += 1
        # ---- gait-intensity adaptive threshold with hysteresis (002 eq. 3, adapted) ----
        dt_raw = t[i] - fs[1] if ist[3] else 0.0
        dt = dt_raw
        if dt > par[_MAXDT]:
            dt = par[_MAXDT]
        # ---- gaps in the data: an interval much longer than the nominal one (median of the latest) ----
        gap = 0  # 1: bridge it by interpolation, 2: too long to bridge (hold, re-level at the next stance)
        dt_nom = dt_raw
        if ist[3] and par[_GAPF] > 0:
            med = _nominal_dt(fs, dt_raw, par[_GAPF])
            if med > 0.0:
                dt_nom = med
                if dt_raw > par[_GAPF] * med:
                    gap = 2 if dt_raw > par[_GAPM] else 1
        decay = math.exp(-dt / par[_ITAU]) if par[_ITAU] > 0 else 0.0
        if par[_IMODE] == 2:
            # decaying peak of the specific-force magnitude [m/s^2]: heel-strike / push-off intensity
            an = math.sqrt(acc[i, 0] ** 2 + acc[i, 1] ** 2 + acc[i, 2] ** 2)
            inten = fs[0] * decay
            if an > inten:
                inten = an
            fs[0] = inten
        elif par[_IMODE] == 1:
            # exponential mean of log10(T): a smooth gait-intensity level
            lt = math.log10(T if T > 1.0 else 1.0)
            if not ist[3]:
                fs[0] = lt
            fs[0] = decay * fs[0] + (1.0 - decay) * lt
            inten = 10.0 ** fs[0]
        else:
            inten = fs[0] * decay
            if T > inten:
                inten = T
            fs[0] = inten
        gam = par[_G0]
        if par[_GE] != 0.0 and inten > 0:
            gam = par[_G0] * (inten / par[_IREF]) ** par[_GE]
        if gam < par[_GMIN]:
            gam = par[_GMIN]
        if gam > par[_GMAX]:
            gam = par[_GMAX]
        if ist[1]:
            zv = T < gam * par[_HYS]
        else:
            zv = T < gam
        k = i - i0
        o_stat[k] = T
        o_zupt[k] = zv
        # ---- range clipping (models.saturation): the axes at the sensor's full scale, their values' errors ----
        sat = sat_in[i]
        o_sat[k] = sat
        if sat:
            fs[_F_SCNT] += 1.0
        if sat or fs[_F_SOPEN] != 0.0:
            _clip_runs(fs, sat, sig_in[i], dt, q_sat)
            fs[_F_SOPEN] = float(sat)
        has_m = not (math.isnan(mag[i, 0]) or math.isnan(mag[i, 1]) or math.isnan(mag[i, 2]))
        if gap == 2 and ist[0]:
            # ---- a gap longer than gap_max_s: the foot may have taken a stride in it. Rather than integrate a
            # long wrong stride, hold the position, forget the velocity and re-level at the next stance ----
            if fs[_F_COAST] == 0:
                fs[_F_NCO] += 1
            fs[_F_COAST] = 1.0
            fs[2:13] = 0.0
            x[4:7] = 0.0
            ist[1] = 0  # a stance cut by the gap is merged into the one after it
            fs[31] = 0.0  # a new straight segment starts (heuristic drift reduction)
        if fs[_F_COAST] > 0 and ist[0]:
            # ---- coasting: attitude follows the gyro, position held; the next stance re-levels roll/pitch
            # from its mean specific force (001 eq. 1-3), the heading is kept ----
            if gap != 2 and dt > 0:
                if par[_GDEL] > 0.0:
                    _gyr_at_into(t, gyr, t[i] + par[_GDEL], w_i, i)
                else:
                    for a in range(3):
                        w_i[a] = gyr[i, a]
                dq = quat_exp_s((w_i[0] - x[13]) * dt, (w_i[1] - x[14]) * dt, (w_i[2] - x[15]) * dt)
                q = quat_mul_s(x[0:4].copy(), dq)
                x[0:4] = q / math.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
            if zv:
                if fs[11] == 0:
                    fs[13] = t[i]
                for a in range(3):
                    fs[2 + a] += acc[i, a]
                fs[11] += 1
            dur = t[i] - fs[13] if fs[11] > 0 else 0.0
            ready = fs[11] >= 3 and ((not zv and dur >= par[_MINST]) or (zv and dur >= par[_AMAX]))
            if not zv and not ready:
                fs[2:13] = 0.0
            if ready:
                _relevel(x, np.array([fs[2] / fs[11], fs[3] / fs[11], fs[4] / fs[11]]))
                x[4:7] = 0.0
                P[0:9, :] = 0.0
                P[:, 0:9] = 0.0
                for a in range(3):
                    P[a, a] = 1e-6
                    P[3 + a, 3 + a] = 1e-4
                P[6, 6] = par[_P0T] ** 2
                P[7, 7] = par[_P0T] ** 2
                P[8, 8] = par[_P0Y] ** 2
                ist[1] = 1
                fs[28] = fs[11]
                fs[19:23] = 0.0
                fs[14] = _heading_of(x)
                fs[2:13] = 0.0
                fs[_F_COAST] = 0.0
            if fs[_F_COAST] > 0 or zv:
                fs[1] = t[i]
                o_pos[k, 0] = x[7]
                o_pos[k, 1] = x[8]
                o_pos[k, 2] = x[9]
                o_vel[k, :] = 0.0
                o_head[k] = _heading_of(x)
                o_hsig[k], o_psig[k] = _sigmas(x, P, fs)
                o_zupt[k] = zv
                ist[2] += 1
                i += 1
                continue
            dt = 0.0  # re-levelled at the toe-off sample: the stance ends here, nothing to integrate
            gap = 0
        if not ist[0]:
            # ---- waiting for the initial rest: accumulate, align when it is long enough ----
            if not ist[3]:
                fs[_F_TFIRST] = t[i]
            if par[_ASW] > 0 and fs[_F_MOVED] == 0:
                if gyr[i, 0] ** 2 + gyr[i, 1] ** 2 + gyr[i, 2] ** 2 >= par[_ASW] ** 2:
                    fs[_F_MOVED] = 1.0  # the foot swings: the recording started mid-walk
            if t[i] - fs[_F_TFIRST] < par[_ATO] and fs[_F_MOVED] == 0:
                zv = T < par[_AGAM]
            o_zupt[k] = zv
            if zv:
                if fs[11] == 0:
                    fs[13] = t[i]
                for a in range(3):
                    fs[2 + a] += acc[i, a]
                    fs[5 + a] += gyr[i, a]
                fs[11] += 1
                if has_m and par[_MAGON] > 0:
                    for a in range(3):
                        fs[8 + a] += mag[i, a]
                    fs[12] += 1
            dur = t[i] - fs[13] if fs[11] > 0 else 0.0
            amin = par[_AMIN] if fs[_F_MOVED] == 0 else par[_ASMIN]
            ready = fs[11] >= 3 and ((not zv and dur >= amin) or (zv and dur >= par[_AMAX]))
            if not zv and not ready:
                fs[2:13] = 0.0
            if ready:
                # a mid-walk start aligns on the adaptive detector's first stance after the swing (001 eq. 1-5
                # on a quasi-still foot): nothing of the walk is waited out, its gyro mean is no bias estimate
                _align(x, P, fs, par, par[_MAGON] > 0, dur, fs[_F_MOVED] == 0)
                fs[_F_TALIGN] = t[i]
                ist[0] = 1
                ist[1] = 1
                ist[5] = 1
                fs[15:18] = 0.0
                fs[18] = 0.0
                fs[19:23] = 0.0
                fs[27] = fs[11]
                fs[28] = fs[11]
                fs[14] = math.atan2(2 * (x[1] * x[2] + x[0] * x[3]), 1 - 2 * (x[2] ** 2 + x[3] ** 2))
                fs[2:13] = 0.0
            if not ist[0]:
                fs[1] = t[i]
                ist[3] = 1
                o_pos[k, :] = 0.0
                o_vel[k, :] = 0.0
                o_head[k] = np.nan
                o_hsig[k] = np.nan
                o_psig[k] = np.nan
                i += 1
                continue
            if zv:
                # alignment made inside the rest: this sample is already used; stance continues
                fs[1] = t[i]
                ist[3] = 1
                o_pos[k, :] = x[7:10]
                o_vel[k, :] = x[4:7]
                o_head[k] = fs[14]
                o_hsig[k], o_psig[k] = _sigmas(x, P, fs)
                i += 1
                continue
        # ---- strapdown mechanisation (004 eq. 1) with exact exponential-map attitude update ----
        if gap == 1 and i > 0:
            # a gap: integrate it in steps of the nominal interval, rate and specific force linear between the
            # samples on either side (not one long rectangle with the last sample's values); what the line
            # misses becomes velocity and tilt variance, so the next ZUPT (004 eq. 9) takes the error out of
            # velocity and, through the covariance built up since the gap, out of position and tilt
            fs[_F_NBR] += 1
            n_sub = int(dt_raw / dt_nom + 0.5)
            if n_sub < 2:
                n_sub = 2
            if n_sub > 1000:
                n_sub = 1000
            h = dt_raw / n_sub
            t_p = fs[1]
            _quat_dcm_into(x[0], x[1], x[2], x[3], C1)
            for sub in range(1, n_sub + 1):
                u = sub / n_sub
                if par[_GDEL] > 0.0:
                    _gyr_at_into(t, gyr, t_p + sub * h + par[_GDEL], w_i, -1)
                else:
                    for a in range(3):
                        w_i[a] = (1.0 - u) * gyr[i - 1, a] + u * gyr[i, a]
                fb0 = (1.0 - u) * acc[i - 1, 0] + u * acc[i, 0] - x[10]
                fb1 = (1.0 - u) * acc[i - 1, 1] + u * acc[i, 1] - x[11]
                fb2 = (1.0 - u) * acc[i - 1, 2] + u * acc[i, 2] - x[12]
                wx = (w_i[0] - x[13]) * h
                wy = (w_i[1] - x[14]) * h
                wz = (w_i[2] - x[15]) * h
                _mech_step(x, P, wx, wy, wz, fb0, fb1, fb2, h, par, C1, Cm, fnw, Bw, Mw)
            if not (ist[1] and zv):
                # the foot was not on the ground throughout: what the line missed, per axis, is taken as a
                # constant specific-force error e (sigma gap_acc_sigma) over the missed time m = dt - dt_nom:
                # dv = e m, dp = e m^2 / 2 (so P_vv += s^2, P_pv += s^2 m / 2, P_pp += s^2 m^2 / 4, s = sigma m),
                # and a rotation error of gap_gyr_sigma * m (tilt) and gap_yaw_sigma * m (heading)
                miss = dt_raw - dt_nom
                qv = (par[_GAPA] * miss) ** 2
                qt = (par[_GAPW] * miss) ** 2
                for a in range(3):
                    P[3 + a, 3 + a] += qv
                    P[a, 3 + a] += 0.5 * miss * qv
                    P[3 + a, a] += 0.5 * miss * qv
                    P[a, a] += 0.25 * miss * miss * qv
                P[6, 6] += qt
                P[7, 7] += qt
                P[8, 8] += (par[_GAPY] * miss) ** 2
            dt = dt_raw
        else:
            # rate and specific force over (t[i-1], t[i]]: this sample's, or the mean of both ends (trapezoid)
            ip = i - 1 if (par[_TRAP] > 0 and i > 0) else i
            if par[_GDEL] > 0.0:
                # inter-sensor latency: the rate that belongs with this specific force is read gyr_delay_s later
                _gyr_at_into(t, gyr, t[i] + par[_GDEL], w_i, i)
                if ip == i:
                    for a in range(3):
                        w_p[a] = w_i[a]
                else:
                    _gyr_at_into(t, gyr, t[ip] + par[_GDEL], w_p, ip)
            else:
                for a in range(3):
                    w_i[a] = gyr[i, a]
                    w_p[a] = gyr[ip, a]
            wx = (0.5 * (w_i[0] + w_p[0]) - x[13]) * dt
            wy = (0.5 * (w_i[1] + w_p[1]) - x[14]) * dt
            wz = (0.5 * (w_i[2] + w_p[2]) - x[15]) * dt
            fb0 = 0.5 * (acc[i, 0] + acc[ip, 0]) - x[10]
            fb1 = 0.5 * (acc[i, 1] + acc[ip, 1]) - x[11]
            fb2 = 0.5 * (acc[i, 2] + acc[ip, 2]) - x[12]
            _mech_step(x, P, wx, wy, wz, fb0, fb1, fb2, dt, par, C1, Cm, fnw, Bw, Mw)
        if dt > 0:
            fs[_F_DIST] += math.sqrt(x[4] * x[4] + x[5] * x[5]) * dt  # horizontal distance travelled [m]
            if sat:
                _clip_noise(P, C1, q_sat, fs)
            if par[_GSS_SAT] > 0.0:
                # the swing's fastest rotation: a sample at the largest |rate| seen so far (above a floor) grows the
                # tilt variance. Its error is larger than the white noise model says (latency, scale factor and the
                # sensor's bandwidth all scale with the rate); the next ZUPT re-levels the tilt and corrects velocity
                # and position through P. Unrelated to clipping (models.saturation), which this preceded: without it
                # gdin's stride error grew (10 stride-truth walks, mean 0.60 -> 0.62 m; exp41 with 0.1-s gaps
                # 0.37 -> 0.43 m)
                wm = max(abs(gyr[i, 0]), abs(gyr[i, 1]), abs(gyr[i, 2]))
                if wm > fs[_F_GPEAK]:
                    fs[_F_GPEAK] = wm
                if wm >= par[_GSM] and wm >= par[_GSF] * fs[_F_GPEAK]:
                    qsat = (par[_GSS_SAT] * dt) ** 2
                    P[6, 6] += qsat
                    P[7, 7] += qsat
        fs[1] = t[i]
        ist[3] = 1
        # ---- stance bookkeeping and measurement updates ----
        if zv and not ist[1] and t[i] - fs[_F_TOFF] < par[_SWMIN] and (
                x[4] ** 2 + x[5] ** 2 + x[6] ** 2 > par[_SWSPD] ** 2):
            # a foot still moving fast just after toe-off is in mid-swing, not on the ground: stair ascent pauses
            # the foot's rotation 0.1-0.25 s into the swing at 1.3-2 m/s (gaitmap stair-up: every stride)
            zv = False
            o_zupt[k] = False
        if zv:
            if not ist[1]:
                # heel strike: start of a stance
                ist[1] = 1
                fs[13] = t[i]
                fs[28] = 0.0
                fs[19:23] = 0.0
                fs[14] = math.atan2(C1[1, 0], C1[0, 0])
            fs[28] += 1
            # ZUPT (004 eq. 9): z = 0 - v_est = dv
            _update_block3_w(P, dx, 3, -x[4], -x[5], -x[6], par[_RZ] * (1.0 + par[_ZSOFT] * T / gam), Kw, Hw, Gw)
            if par[_ZARU] > 0 and T < par[_ZGAM]:
                # ZARU (001 eq. 34-35): measured rate minus bias estimate = d(bias)
                _update_block3_w(P, dx, 12, gyr[i, 0] - x[13], gyr[i, 1] - x[14], gyr[i, 2] - x[15], par[_RW], Kw, Hw,
                                 Gw)
            _apply_correction(x, dx)
            if has_m and par[_MAGON] > 0:
                _quat_dcm_into(x[0], x[1], x[2], x[3], Cm)
                for a in range(3):
                    fs[19 + a] += Cm[a, 0] * mag[i, 0] + Cm[a, 1] * mag[i, 1] + Cm[a, 2] * mag[i, 2]
                fs[22] += 1
        else:
            sp = math.sqrt(x[4] ** 2 + x[5] ** 2 + x[6] ** 2)
            if ist[1]:
                # toe-off: the stance ends; magnetic heading update from the stance's mean field
                ist[1] = 0
                fs[_F_TOFF] = t[i]
                mag_used = 0.0
                if fs[22] > 0 and fs[26] > 0 and par[_MAGON] > 0:
                    mN = fs[19] / fs[22]
                    mE = fs[20] / fs[22]
                    mD = fs[21] / fs[22]
                    mh = math.sqrt(mN * mN + mE * mE)
                    rh = math.sqrt(fs[23] ** 2 + fs[24] ** 2)
                    mag_m = math.sqrt(mh * mh + mD * mD)
                    ref_m = math.sqrt(rh * rh + fs[25] ** 2)
                    dinc = math.atan2(mD, mh) - math.atan2(fs[25], rh)
                    # disturbance test: magnitude (002 eq. 4-5, 000 eq. 68) and inclination
                    if abs(mag_m - ref_m) < par[_DMAG] and abs(dinc) < par[_DINC] and mh > 1.0:
                        zpsi = math.atan2(fs[24], fs[23]) - math.atan2(mE, mN)
                        zpsi = _wrap(zpsi)
                        Cc = quat_dcm_s(x[0:4])
                        h = _heading_row(Cc)
                        if _update_scalar(P, dx, h, zpsi, par[_RMAG] ** 2, par[_MGATE]):
                            _apply_correction(x, dx)
                            mag_used = 1.0
                            fs[29] += 1
                dur = t[i] - fs[13]
                if dur >= par[_MINST] and ist[5] and par[_HDR] > 0:
                    _hdr(x, P, dx, fs, par)
                if dur >= par[_MINST] and n_st < st_out.shape[0]:
                    r = st_out[n_st]
                    r[0] = fs[13]
                    r[1] = t[i]
                    r[2] = x[7]
                    r[3] = x[8]
                    r[4] = x[9]
                    r[5] = fs[14]
                    if ist[5]:
                        r[6] = x[7] - fs[15]
                        r[7] = x[8] - fs[16]
                        r[8] = x[9] - fs[17]
                    else:
                        r[6] = 0.0
                        r[7] = 0.0
                        r[8] = 0.0
                    r[9] = fs[18]
                    r[10] = fs[28]
                    r[11] = mag_used
                    r[12], r[13] = _sigmas(x, P, fs)
                    r[14] = fs[_F_SCNT]
                    fs[_F_SCNT] = 0.0
                    fs[15] = x[7]
                    fs[16] = x[8]
                    fs[17] = x[9]
                    fs[18] = 0.0
                    ist[5] = 1
                    ist[4] += 1
                    n_st += 1
            if sp > fs[18]:
                fs[18] = sp
        o_pos[k, 0] = x[7]
        o_pos[k, 1] = x[8]
        o_pos[k, 2] = x[9]
        o_vel[k, 0] = x[4]
        o_vel[k, 1] = x[5]
        o_vel[k, 2] = x[6]
        # atan2(C[1, 0], C[0, 0]) of quat_dcm_s, from the quaternion directly
        o_head[k] = math.atan2(2 * (x[1] * x[2] + x[0] * x[3]), 1 - 2 * (x[2] * x[2] + x[3] * x[3]))
        o_hsig[k], o_psig[k] = _sigmas(x, P, fs)
        ist[2] += 1
        i += 1
    if final and i >= n_all and ist[0] and ist[1] and n_st < st_out.shape[0] and t[n_all - 1] - fs[13] >= par[_MINST]:
        # end of the recording inside a stance: report it (the walker stopped there)
        r = st_out[n_st]
        r[0] = fs[13]
        r[1] = t[n_all - 1]
        r[2] = x[7]
        r[3] = x[8]
        r[4] = x[9]
        r[5] = fs[14]
        r[6] = x[7] - fs[15] if ist[5] else 0.0
        r[7] = x[8] - fs[16] if ist[5] else 0.0
        r[8] = x[9] - fs[17] if ist[5] else 0.0
        r[9] = fs[18]
        r[10] = fs[28]
        r[11] = 0.0
        r[12], r[13] = _sigmas(x, P, fs)
        r[14] = fs[_F_SCNT]
        fs[_F_SCNT] = 0.0
        fs[15] = x[7]
        fs[16] = x[8]
        fs[17] = x[9]
        fs[18] = 0.0
        fs[13] = t[n_all - 1]
        fs[28] = 0.0
        ist[5] = 1
        ist[4] += 1
        n_st += 1
    return i, n_st


@njit(cache=True, error_model="numpy")
def inputs_ok(t, acc, gyr, mag, t_last):
    """True when :meth:`models.zupt_nav.ZuptNavigator.process`'s checks of its inputs pass, in one pass: ``t``
    (N,) [s] finite and strictly increasing after ``t_last`` [s], ``acc`` and ``gyr`` (N, 3) finite, each row of
    ``mag`` (N, 3) finite or all NaN. False: the checks in Python say what is wrong."""
    prev = t_last
    for i in range(t.shape[0]):
        v = t[i]
        if not (np.isfinite(v) and v > prev):
            return False
        prev = v
        for j in range(3):
            if not (np.isfinite(acc[i, j]) and np.isfinite(gyr[i, j])):
                return False
        a, b, c = mag[i, 0], mag[i, 1], mag[i, 2]
        if not ((np.isfinite(a) and np.isfinite(b) and np.isfinite(c)) or (np.isnan(a) and np.isnan(b) and np.isnan(c))):
            return False
    return True
