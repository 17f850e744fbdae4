"""Step-length models and their online calibration against ZUPT-KF step distances.

Models (``d`` in metres, one step = one stance-to-stance interval of the instrumented foot):

* ``"eq15"`` — 004 eq. (15) walking: ``d = K0 + K1 f^-1/2 + K2 f^-1 + K3 (a_bar - g)``;
* ``"eq15_run"`` — 004 eq. (15) running: ``d = K4 cbrt(a_bar)``;
* ``"weinberg"`` — 000 eq. (35): ``d = K (a_max - a_min)^(1/4)``;
* ``"height_freq"`` — 003 eq. (28): ``d = h (j f + l) + q``; for one user ``h`` is fixed, so ``h l`` and
  ``q`` are not separately identifiable: the prior keeps them apart.

``a~`` is the Hamming-window FIR filtered specific-force magnitude [m/s^2] (004 Section 2.2), ``a_bar`` its
mean over the step, ``f`` the step frequency [Hz] (see :mod:`models.steps`).

The walking term K3 acts on ``a_bar``: 004 writes it ``max(a_bar_k)`` with ``a_bar_k`` "the mean value of
a~_k", the symbol the running form uses too. It was first read as the peak ``max(a~)``, which carries little
of the stride at a given cadence: over the gdin per-stride recordings (exp31-43, truth strides, cadence
terms regressed out) the partial correlation of the true stride with the peak is -0.21..+0.82 (the same at
the native rate and at 25 Hz), with the mean +0.33..+0.92 on 9 of 10 (exp34 ~0). A K3 fitted on the peak
followed the noise of ~30 calibration strides (K3 -0.017..+0.024 m per m/s^2) and moved every Gait-DR
stride by 1-2 % where the walk's peaks drifted (exp41, exp42). The regressor is ``a_bar - g`` (zero for a
still foot): with the intercept this only re-parametrises K0, but it keeps K0's prior about the stride
instead of about ``K3 g``.

Calibration (004 Section 2.3 and 5): pairs (features, d_KF) collected while the ZUPT-KF runs are fitted by
Huber-weighted iteratively re-weighted least squares with a Gaussian prior on the coefficients (so a
calibration walk at one pace, where the regressors of eq. 15 are nearly collinear, stays well-posed).
Separate models per behaviour and per walking pattern: step-frequency bands of width ``2 * band_hz``
(004: +-0.2 Hz). The prior precision ``sigma_d`` (004 Table 3) and the 3-sigma examination go with each
fitted model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models.stats import median
from models.steps import G0

__all__ = ["MODELS", "FORM", "MAX_PAIRS", "CADENCE_GAP_HZ", "StepFeatures", "regressors", "default_prior", "robust_fit", "sigma_d",
           "StepLengthCalibrator"]

MODELS: tuple[str, ...] = ("eq15", "eq15_run", "weinberg", "height_freq")
FORM = "eq15-abar"  # regressor form the stored fits were made with (states without it: eq. 15 on the peak)
# Calibration pairs kept per behaviour (the newest): 10x the ~30 strides of a 40-m initialisation (L0), enough
# for the per-band fits of two or three walking patterns, and it bounds the state and the profile (~12 kB per
# behaviour); a sliding window also follows a gait that changes slowly over weeks of use.
MAX_PAIRS = 300
# Largest gap [Hz] between fitted cadences that a model interpolates across (StepLengthCalibrator.cadence_ranges):
# the strides of one pace spread by a few hundredths of a Hz; the synthetic paces lie 0.11-0.13 Hz apart, and a
# slow and a fast walk fitted without the pace between them leave a gap of 0.1-0.2 Hz (held-out synthetic days).
# 0.15 left seed 2's walk 9 % long; 0.05 also re-initialised a 1.2-s pace between 1.32-s and 1.16-s fitted ones
# (mixed day, seed 10).
CADENCE_GAP_HZ = 0.1


@dataclass(frozen=True)
class StepFeatures:
    """Inputs of the step-length models.

    Attributes
    ----------
    f_s : float
        Step frequency [Hz].
    acc_mean, acc_max, acc_min : float
        Mean, maximum, minimum of the FIR-filtered specific-force magnitude over the step [m/s^2].
    """

    f_s: float
    acc_mean: float
    acc_max: float
    acc_min: float


def regressors(model: str, x: StepFeatures, height_m: float = 1.75) -> np.ndarray:
    """Regressor row of a linear-in-coefficients step-length model.

    Parameters
    ----------
    model : str
        One of :data:`MODELS`.
    x : StepFeatures
        Step features.
    height_m : float
        User height [m] (``"height_freq"`` only).

    Returns
    -------
    ndarray, shape (p,)
    """
    f = max(x.f_s, 1e-3)
    if model == "eq15":
        return np.array([1.0, f ** -0.5, 1.0 / f, x.acc_mean - G0])  # 004 eq. (15), walking
    if model == "eq15_run":
        return np.array([np.cbrt(x.acc_mean)])  # 004 eq. (15), running
    if model == "weinberg":
        return np.array([max(x.acc_max - x.acc_min, 0.0) ** 0.25])  # 000 eq. (35)
    if model == "height_freq":
        return np.array([height_m * f, height_m, 1.0])  # 003 eq. (28): h (j f + l) + q
    raise ValueError(f"unknown step-length model {model!r}; expected one of {MODELS}")


def _regressor_list(model: str, x: StepFeatures, height_m: float) -> list[float]:
    """:func:`regressors` as plain floats (the per-step prediction path; no array overhead)."""
    f = max(x.f_s, 1e-3)
    if model == "eq15":
        return [1.0, f ** -0.5, 1.0 / f, x.acc_mean - G0]  # 004 eq. (15), walking
    if model == "eq15_run":
        return [math.copysign(abs(x.acc_mean) ** (1.0 / 3.0), x.acc_mean)]  # 004 eq. (15), running
    if model == "weinberg":
        return [max(x.acc_max - x.acc_min, 0.0) ** 0.25]  # 000 eq. (35)
    if model == "height_freq":
        return [height_m * f, height_m, 1.0]  # 003 eq. (28)
    raise ValueError(f"unknown step-length model {model!r}; expected one of {MODELS}")


def default_prior(model: str) -> tuple[np.ndarray, np.ndarray]:
    """Generic (population) coefficients and their prior standard deviations.

    Physically motivated, not fitted to any evaluation recording. A foot-mounted stride is ~1.3 m at a
    stride frequency of ~0.85 Hz, and over walking paces the stride grows about in proportion to the cadence
    (stride ~ sqrt(speed) and speed = stride x frequency), i.e. ``dd/df ~ d/f ~ 1.5 m/Hz`` there. For 004
    eq. (15) that shape is ``K0 + K2 / f`` with ``K2 = -1.5 * 0.85^2 = -1.08`` and ``K0 = 1.3 + 1.08 / 0.85 =
    2.57``. Standard deviations: K0 loose (the person's level), K1 and K2 0.3 (about 30 % of the slope: people
    differ), K3 (on the mean filtered acceleration ``a_bar``) mean 0, std 0.2 m per m/s^2: at a given cadence
    the swing's accelerations grow with the stride, and if all of ``a_bar - g`` (~3.5 m/s^2 at a 1.3 m
    stride) did, ``dd/da_bar`` would be ~0.35; half of that is the scale. A calibration walk spans a narrow
    range of paces, so its strides fix the level but hardly the
    slope, and the prior decides how the model extrapolates: the earlier constant-speed prior (``d ~ 1.3 / f``,
    longer strides at a slower cadence, K3 0.05) over-predicted the later, slower strides of gdin walks.
    A tighter shape prior (0.1) fitted gdin better still but overrode clear data (a 0.7-1.3 Hz calibration
    with the opposite slope was fitted with 0.33 m rms error), so it was not taken.

    Returns
    -------
    mean, std : ndarray, shape (p,)
    """
    if model == "eq15":
        return np.array([2.57, 0.0, -1.08, 0.0]), np.array([1.0, 0.3, 0.3, 0.2])
    if model == "eq15_run":
        return np.array([0.7]), np.array([1.0])
    if model == "weinberg":
        return np.array([0.6]), np.array([1.0])
    if model == "height_freq":
        return np.array([0.3, 0.55, 0.0]), np.array([0.5, 0.2, 0.3])
    raise ValueError(f"unknown step-length model {model!r}; expected one of {MODELS}")


def robust_fit(x: np.ndarray, y: np.ndarray, prior_mean: np.ndarray, prior_std: np.ndarray,
               huber_k: float = 1.345, iterations: int = 20) -> np.ndarray:
    """Huber IRLS with a Gaussian prior on the coefficients.

    Minimises ``sum_i rho((y_i - x_i c) / s) + sum_j ((c_j - m_j) / sd_j)^2 / 2`` with ``s`` the robust
    (MAD) residual scale.

    Parameters
    ----------
    x : ndarray, shape (n, p)
        Regressors.
    y : ndarray, shape (n,)
        Reference step lengths d_KF [m].
    prior_mean, prior_std : ndarray, shape (p,)
        Prior on the coefficients.
    huber_k : float
        Huber threshold in units of the residual scale.

    Returns
    -------
    ndarray, shape (p,)
        Coefficients.
    """
    x = np.asarray(x, dtype=np.float64).reshape(len(y), -1)
    y = np.asarray(y, dtype=np.float64)
    m = np.asarray(prior_mean, dtype=np.float64)
    lam = 1.0 / np.asarray(prior_std, dtype=np.float64) ** 2
    w = np.ones_like(y)
    c = m.copy()
    s = 0.05  # m, initial residual scale
    dlam, lam_m = np.diag(lam), lam * m
    for _ in range(iterations):
        xw = x * (w / s**2)[:, None]  # the same product both normal-equation terms used to compute on their own
        c_new = np.linalg.solve(xw.T @ x + dlam, xw.T @ y + lam_m)
        r = y - x @ c_new
        s = max(1.4826 * median(np.abs(r - median(r))), 0.005)
        u = np.abs(r) / s
        w = np.where(u <= huber_k, 1.0, huber_k / np.maximum(u, 1e-12))
        done = float(np.max(np.abs(c_new - c))) <= 1e-10  # = np.allclose(c_new, c, rtol=0, atol=1e-10)
        c = c_new
        if done:
            break
    return c


def sigma_d(d_kf: np.ndarray, d_sl: np.ndarray) -> float:
    """Prior precision of a calibrated step-length model, 004 Table 3: ``sqrt(sum (d_KF - d_SL)^2 / (n-1))``."""
    d_kf = np.asarray(d_kf, dtype=np.float64)
    d_sl = np.asarray(d_sl, dtype=np.float64)
    n = d_kf.size
    if n < 2:
        return float("nan")
    return float(np.sqrt(np.sum((d_kf - d_sl) ** 2) / (n - 1)))


def _fit_state(v: dict) -> dict:
    """A fit entry as plain data (``acc_mean_range`` only where kept: fits stored before it hold no a_bar)."""
    out = {"coef": [float(c) for c in v["coef"]], "sigma_d": float(v["sigma_d"]), "n": int(v["n"])}
    if "acc_mean_range" in v:
        out["acc_mean_range"] = [float(x) for x in v["acc_mean_range"]]
    return out


class StepLengthCalibrator:
    """Online step-length calibration per behaviour and walking pattern (004 eq. 15, Table 3).

    Parameters
    ----------
    model : str
        Walking model, one of :data:`MODELS`.
    run_model : str
        Model of behaviour ``"run"`` when ``model == "eq15"``: ``"eq15"`` (default: the walking form, fitted on
        the running strides) or ``"eq15_run"`` (004's ``K4 cbrt(a_bar)``). The one-coefficient cube root has a
        fixed elasticity of 1/3 and no cadence term; the gdin strides labelled running (1.0-1.3 Hz) span
        1.5-3.1 m while ``a_bar`` grows by x1.7, so it over-predicted the slower ones (exp35's Gait-DR strides
        at 1.0 Hz: 1.92 m for 1.58 m true, 23 %). States without the key used ``"eq15_run"``.
    band_hz : float
        Half-width of a walking-pattern step-frequency band [Hz] (004: 0.2).
    min_pairs : int
        Pairs a band needs before it gets its own model (otherwise the behaviour's pooled model).
    height_m : float
        User height [m] (``"height_freq"``).
    sigma_floor : float
        Lower bound on sigma_d [m] so a tiny calibration set cannot make the examination hair-trigger.
    band_prior_scale : float
        A band's model is fitted with the behaviour's pooled fit as prior mean and ``band_prior_scale`` times
        the generic prior standard deviations (hierarchical shrinkage: a band with few, nearly collinear
        steps stays close to the pooled model instead of extrapolating on its own). ``inf`` = independent.
    max_pairs : int
        Calibration pairs kept per behaviour, the newest (``MAX_PAIRS``): every ZUPT-KF stride adds one, and
        the pairs live in the engine state the server stores after every upload and in the profile a user
        carries from session to session (unbounded, 25 kB per hour of ZUPT-KF walking).
    """

    def __init__(self, model: str = "eq15", band_hz: float = 0.2, min_pairs: int = 8, height_m: float = 1.75,
                 sigma_floor: float = 0.03, band_prior_scale: float = 0.5, run_model: str = "eq15",
                 max_pairs: int = MAX_PAIRS) -> None:
        if model not in MODELS or run_model not in ("eq15", "eq15_run"):
            raise ValueError(f"unknown step-length model {model!r}/{run_model!r}; expected one of {MODELS}")
        self.model = model
        self.run_model = run_model
        self.band_hz = float(band_hz)
        self.min_pairs = int(min_pairs)
        self.height_m = float(height_m)
        self.sigma_floor = float(sigma_floor)
        self.band_prior_scale = float(band_prior_scale)
        self.max_pairs = int(max_pairs)
        if self.max_pairs < self.min_pairs:
            raise ValueError(f"max_pairs ({self.max_pairs}) must be at least min_pairs ({self.min_pairs})")
        self._pairs: dict[str, list[list[float]]] = {}  # behaviour -> [[f, mean, max, min, d_kf], ...]
        self._fits: dict[str, dict] = {}  # key -> {"coef": [...], "sigma_d": s, "n": n}

    def model_for(self, behaviour: str) -> str:
        """Model used for a behaviour (running: :attr:`run_model` when the walking model is eq. 15)."""
        return self.run_model if (behaviour == "run" and self.model == "eq15") else self.model

    def band(self, f_s: float) -> int:
        """Walking-pattern band index of a step frequency [Hz] (bands of width ``2 band_hz``)."""
        return int(math.floor(f_s / (2.0 * self.band_hz)))

    def add(self, behaviour: str, x: StepFeatures, d_kf: float) -> None:
        """Record one calibration pair: features of a step and the ZUPT-KF distance of that step [m]."""
        if not (np.isfinite(d_kf) and np.isfinite(x.f_s)):
            return
        pairs = self._pairs.setdefault(behaviour, [])
        pairs.append([x.f_s, x.acc_mean, x.acc_max, x.acc_min, float(d_kf)])
        self._bound(behaviour)

    def _bound(self, behaviour: str) -> None:
        """Drop a behaviour's oldest pairs beyond ``max_pairs``; its pooled fit's ``n`` (the pairs it used are
        the first ``n``) counts only those kept."""
        pairs = self._pairs.get(behaviour, [])
        extra = len(pairs) - self.max_pairs
        if extra <= 0:
            return
        del pairs[:extra]
        e = self._fits.get(behaviour)
        if e is not None:
            e["n"] = max(int(e["n"]) - extra, 0)

    def n_pairs(self, behaviour: str) -> int:
        """Calibration pairs gathered for a behaviour."""
        return len(self._pairs.get(behaviour, []))

    def fit(self, behaviour: str) -> dict:
        """Fit the pooled and the per-band models of a behaviour; returns ``{key: {coef, sigma_d, n}}``."""
        rows = np.asarray(self._pairs.get(behaviour, []), dtype=np.float64).reshape(-1, 5)
        model = self.model_for(behaviour)
        m, sd = default_prior(model)
        out: dict[str, dict] = {}
        groups = {f"{behaviour}": np.ones(len(rows), bool)}
        bands = np.array([self.band(f) for f in rows[:, 0]], dtype=int) if len(rows) else np.zeros(0, int)
        for b in sorted(set(bands.tolist())):
            sel = bands == b
            if sel.sum() >= self.min_pairs:
                groups[f"{behaviour}/{b}"] = sel
        pooled = None
        for key, sel in groups.items():  # the pooled fit comes first (dict order)
            r = rows[sel]
            if len(r) == 0:
                continue
            x = np.array([regressors(model, StepFeatures(*q[:4]), self.height_m) for q in r])
            if pooled is None or not np.isfinite(self.band_prior_scale):
                coef = robust_fit(x, r[:, 4], m, sd)
                pooled = coef if pooled is None else pooled
            else:
                coef = robust_fit(x, r[:, 4], pooled, self.band_prior_scale * sd)
            sig = sigma_d(r[:, 4], x @ coef)  # 004 Table 3
            out[key] = {"coef": coef.tolist(), "sigma_d": max(sig, self.sigma_floor) if np.isfinite(sig)
                        else float("nan"), "n": int(len(r)),
                        "acc_mean_range": [float(r[:, 1].min()), float(r[:, 1].max())]}
        for k in [k for k in self._fits if k == behaviour or k.startswith(behaviour + "/")]:
            del self._fits[k]
        self._fits.update(out)
        return out

    def cadence_range(self, behaviour: str, period_res_s: float = 0.0) -> tuple[float, float] | None:
        """Lowest and highest step frequency [Hz] the behaviour's fitted model has seen (:meth:`cadence_ranges`'
        outer ends; None when not fitted)."""
        ranges = self.cadence_ranges(behaviour, period_res_s)
        return None if ranges is None else (ranges[0][0], ranges[-1][1])

    def cadence_ranges(self, behaviour: str, period_res_s: float = 0.0,
                       gap_hz: float = CADENCE_GAP_HZ) -> list[tuple[float, float]] | None:
        """Step frequencies [Hz] the behaviour's fitted model has seen, as ranges (None when not fitted).

        The cadences of the pairs its pooled fit used, split where two neighbours lie more than ``gap_hz`` (or
        three cadence resolution steps, ``3 f^2 period_res_s``) apart: a model fitted on a slow and a fast walk
        has seen neither cadence between them, and it interpolated the walk there 9 % long, within its
        examination's 3 sigma (held-out synthetic day, seed 2: 0.74 and 0.98 Hz fitted, 0.87 Hz walked). Each
        range is widened by half the resolution of a step period measured to ``period_res_s`` [s]
        (``f^2 period_res_s / 2``: a cadence within half a resolution step of a fitted one is the same walking
        pattern). Outside these ranges the model extrapolates along the prior's shape (004 Section 4.2: a
        changed step frequency may leave the calibrated model inaccurate).
        """
        e = self._fits.get(behaviour)
        pairs = self._pairs.get(behaviour, [])
        if e is None or not pairs or int(e["n"]) <= 0:
            return None  # not fitted, or every pair the fit used has since been dropped (max_pairs)
        f = sorted(q[0] for q in pairs[: int(e["n"])])
        ranges = [[f[0], f[0]]]
        for a, b in zip(f[:-1], f[1:]):
            if b - a > max(gap_hz, 3.0 * b * b * period_res_s):
                ranges.append([b, b])
            else:
                ranges[-1][1] = b
        return [(lo - 0.5 * lo * lo * period_res_s, hi + 0.5 * hi * hi * period_res_s) for lo, hi in ranges]

    def _entry(self, behaviour: str, f_s: float) -> dict | None:
        return self._fits.get(f"{behaviour}/{self.band(f_s)}") or self._fits.get(behaviour)

    def calibrated(self, behaviour: str) -> bool:
        """True when a fitted model exists for the behaviour."""
        return behaviour in self._fits

    def predict(self, behaviour: str, x: StepFeatures) -> tuple[float, float]:
        """Step length [m] and its sigma_d [m] (NaN sigma when only the generic prior is available)."""
        model = self.model_for(behaviour)
        e = self._entry(behaviour, x.f_s)
        coef = e["coef"] if e else default_prior(model)[0].tolist()
        if model == "eq15" and e and "acc_mean_range" in e and coef[3] < 0.0:
            # a K3 fitted negative over the calibration strides' narrow range of a_bar would place a more vigorous
            # stride shorter beyond it: the demo's first running stride, still labelled walk (a_bar 24 against the
            # walk's 13-14 m/s^2), got 0.87 m for 2.15 m. Beyond that range it is held at the range's edge (the
            # cadence terms, held by the prior's shape, still extrapolate); a positive K3 extrapolates (clamping
            # it too: mixed day new users 1.93 / 2.12 -> 2.21 / 2.23 m, gdin pdr distance 0.83 -> 0.92 %)
            lo, hi = e["acc_mean_range"]
            x = StepFeatures(x.f_s, min(max(x.acc_mean, lo), hi), x.acc_max, x.acc_min)
        d = math.fsum(c * r for c, r in zip(coef, _regressor_list(model, x, self.height_m)))
        return d, (float(e["sigma_d"]) if e else float("nan"))

    def examine(self, d_kf: float, d_sl: float, behaviour: str = "walk", f_s: float | None = None) -> bool:
        """004 Table 3 examination: True (model still valid) when ``|d_KF - d_SL| <= 3 sigma_d``."""
        return self.examination(d_kf, d_sl, behaviour, f_s)[0]

    def examination(self, d_kf: float, d_sl: float, behaviour: str = "walk",
                    f_s: float | None = None) -> tuple[bool, float, float]:
        """004 Table 3 examination with its numbers, for the scheduler's decision and for logging.

        Parameters
        ----------
        d_kf : float
            ZUPT-KF step distance [m].
        d_sl : float
            Step-length model prediction for the same step [m].
        behaviour : str
            Behaviour whose model is examined.
        f_s : float, optional
            Step frequency [Hz]: selects the walking-pattern band's model (pooled model otherwise).

        Returns
        -------
        passed : bool
            ``|d_KF - d_SL| <= 3 sigma_d`` (False when no fitted model exists).
        z : float
            ``(d_KF - d_SL) / sigma_d`` (NaN without a fitted model).
        sigma : float
            sigma_d used [m] (NaN without a fitted model).
        """
        e = self._entry(behaviour, f_s) if f_s is not None else self._fits.get(behaviour)
        if e is None or not np.isfinite(e["sigma_d"]):
            return False, float("nan"), float("nan")
        sig = float(e["sigma_d"])
        z = (float(d_kf) - float(d_sl)) / sig
        return abs(z) <= 3.0, z, sig

    def get_state(self) -> dict:
        """Plain-data state (this is the per-user calibration profile content)."""
        return {"model": self.model, "run_model": self.run_model, "form": FORM, "band_hz": self.band_hz, "min_pairs": self.min_pairs,
                "height_m": self.height_m, "sigma_floor": self.sigma_floor, "band_prior_scale": self.band_prior_scale,
                "max_pairs": self.max_pairs,
                "pairs": {k: [list(map(float, r)) for r in v] for k, v in self._pairs.items()},
                "fits": {k: _fit_state(v) for k, v in self._fits.items()}}

    @classmethod
    def from_state(cls, d: dict) -> StepLengthCalibrator:
        """Rebuild from :meth:`get_state` output."""
        obj = cls(d["model"], float(d["band_hz"]), int(d["min_pairs"]), float(d["height_m"]),
                  float(d["sigma_floor"]),
                  float(d.get("band_prior_scale", math.inf)),  # older profiles: independent bands
                  str(d.get("run_model", "eq15_run")),  # older profiles: 004's running form
                  int(d.get("max_pairs", MAX_PAIRS)))
        obj._pairs = {k: [list(map(float, r)) for r in v] for k, v in d["pairs"].items()}
        obj._fits = {k: _fit_state(v) for k, v in d["fits"].items()}
        for b in list(obj._pairs):  # profiles stored before the bound
            obj._bound(b)
        if d.get("form") != FORM:
            obj.refit_stale()
        return obj

    def refit_stale(self) -> None:
        """Refit the behaviours' models from their stored pairs (fits made with an older regressor form).

        Each behaviour is refitted on the pairs its pooled fit used (the first ``n``), so the result is what
        the current form would have fitted at that moment.
        """
        for b in sorted({k.split("/")[0] for k in self._fits}):
            pairs = self._pairs.get(b, [])
            n = int(self._fits[b]["n"]) if b in self._fits else len(pairs)
            for k in [k for k in self._fits if k == b or k.startswith(b + "/")]:
                del self._fits[k]
            if n > 0 and pairs:
                self._pairs[b] = pairs[:n]
                self.fit(b)
                self._pairs[b] = pairs
