"""Engine configuration: one frozen, validated tree; one configuration serves every user and recording.

Every tunable of the engine lives here or in the configuration classes of the models it is built from
(:class:`models.zupt_nav.ZuptConfig`, :class:`models.heading.HeadingConfig`). Each field of the engine's own
sections carries its unit and a one-line rationale (``metadata``), from which :func:`config_table` renders
the table of ``docs/engine.md``. A value out of range is refused by name (``ValueError``). Change a value
with :meth:`EngineConfig.override`, by dotted path: ``cfg.override({"scheduler.l0_m": 20.0})``.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import math
import re
from dataclasses import dataclass, field
from typing import Any

from models.heading import HeadingConfig
from models.zupt_nav import ZuptConfig

__all__ = ["EngineConfig", "RatesConfig", "SegmentsConfig", "SchedulerConfig", "CompassConfig", "StepsConfig", "StepLengthConfig",
           "DeviationConfig", "config_table", "config_markdown"]


def _f(default: Any, unit: str, why: str, lo: float | None = 0.0, hi: float | None = None,
       choices: tuple[Any, ...] | None = None) -> Any:
    """A configuration field: default, unit, rationale and its allowed closed range (or choices)."""
    return field(default=default, metadata={"unit": unit, "why": why, "lo": lo, "hi": hi, "choices": choices})


def _validate(obj: Any) -> None:
    """Refuse a value outside its field's range, naming it."""
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        lo, hi = f.metadata.get("lo"), f.metadata.get("hi")
        choices = f.metadata.get("choices")
        if choices is not None and v not in choices:
            raise ValueError(f"{type(obj).__name__}.{f.name}: must be one of {choices}, got {v!r}")
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            continue
        name = f"{type(obj).__name__}.{f.name}"
        if not math.isfinite(float(v)):
            raise ValueError(f"{name}: must be finite, got {v!r}")
        if lo is not None and v < lo:
            raise ValueError(f"{name}: must be >= {lo}, got {v!r}")
        if hi is not None and v > hi:
            raise ValueError(f"{name}: must be <= {hi}, got {v!r}")


@dataclass(frozen=True)
class RatesConfig:
    """Sampling and upload rates the scheduler asks the device for."""

    full_rate_hz: float = _f(200.0, "Hz", "accelerometer and gyroscope while the ZUPT-KF runs: the rate its "
                             "detector and noise values were validated at (VICON, gdin)", lo=20.0)
    pdr_rate_hz: float = _f(25.0, "Hz", "accelerometer and magnetometer in Gait-DR (004 Sec. 4.3): the step "
                            "segmentation's own rate", lo=10.0)
    stand_rate_hz: float = _f(25.0, "Hz", "accelerometer standing with the gyroscope off: the lowest rate at "
                              "which the step segmentation still counts the first steps", lo=10.0)
    mag_rate_hz: float = _f(50.0, "Hz", "magnetometer while the ZUPT-KF runs (one reading per stance window)",
                            lo=1.0)
    batch_s: float = _f(1.0, "s", "upload period while the ZUPT-KF runs: its answers end examinations and "
                        "initialisations", lo=0.1)
    low_power_batch_s: float = _f(4.0, "s", "upload period with the gyroscope off in Gait-DR: fewer radio "
                                  "wake-ups and per-batch computations", lo=0.1)
    max_sample_age_s: float = _f(0.05, "s", "a gyroscope/magnetometer sample older than this pairs with no "
                                 "accelerometer sample (zero-order hold)", lo=0.001)
    stream_wait_s: float = _f(0.5, "s", "accelerometer samples wait this long for a lagging gyroscope or "
                              "magnetometer stream before they are paired for good", lo=0.0)

    def __post_init__(self) -> None:
        _validate(self)


@dataclass(frozen=True)
class SegmentsConfig:
    """How runs of gyroscope samples become ZUPT-KF segments and where they restart."""

    gyro_gap_s: float = _f(0.25, "s", "a longer gap in gyroscope samples ends a segment (the gyroscope was off)")
    gyro_off_s: float = _f(0.075, "s", "... so does a shorter one with accelerometer rows inside it (below the "
                           "80-ms turn-on time: a wake-on-motion device powered it down)")
    rest_gyr_rad_s: float = _f(1.0, "rad/s", "a restarting segment waits for a still foot: |w| below this")
    rest_acc_ms2: float = _f(1.5, "m/s^2", "... and ||a| - g| below this")
    rest_s: float = _f(0.08, "s", "... for this long (40 ms let a quiet moment of a swing pass at 100 Hz: "
                       "gdin exp37 resampled, 17.7 m stride error)", lo=0.005)
    lead_max_s: float = _f(2.0, "s", "a segment the device started from a still foot integrates back to it "
                           "over at most this")

    def __post_init__(self) -> None:
        _validate(self)


@dataclass(frozen=True)
class SchedulerConfig:
    """The energy-aware state machine (004 Tables 1-3) and the gyroscope on demand."""

    l0_m: float = _f(40.0, "m", "ZUPT-KF distance of an initialisation before Gait-DR (004 Table 2, L0; "
                     "004's n = 40 steps order)")
    t0_s: float = _f(30.0, "s", "interval between step-length examinations in Gait-DR (004 Table 1, T0)",
                     lo=1.0)
    exam_timeout_s: float = _f(10.0, "s", "an examination without a ZUPT-KF stride after this long is given up",
                               lo=1.0)
    exam_strides_to_fail: int = _f(2, "strides", "consecutive examination strides outside 3 sigma before a "
                                   "re-initialisation (004: one; one more costs ~1 s of gyroscope, a "
                                   "re-initialisation 20-30 s)", lo=1)
    exam_max_strides: int = _f(4, "strides", "an examination of an unconfirmed stored deviation goes on over "
                               "turning strides (no observation) up to this many", lo=1)
    exam_sigmas: float = _f(3.0, "sigma", "examination bound for the step length (004 Table 3) and the "
                            "heading deviation (KF II innovation)", lo=0.5)
    pattern_strides: int = _f(5, "strides", "median cadence window of 004 Table 2 (ii): a walking pattern "
                              "the step model was not fitted on", lo=1)
    pattern_init_strides: int = _f(6, "strides", "ZUPT-KF strides of a new walking pattern before its "
                                   "model is refitted", lo=1)
    cross_track_pct: float = _f(5.0, "% of distance", "heading budget: the gyroscope is requested when the "
                                "cross-track drift over the next 100 m that the heading estimator's forecast "
                                "uncertainty with the gyroscope off would cause exceeds it", lo=0.01)
    release_strides: int = _f(3, "strides", "consecutive strides within the heading budget before the "
                              "gyroscope is released", lo=1)
    wake_threshold_ms2: float = _f(0.5, "m/s^2", "wake-on-motion: per-axis departure from the still "
                                   "reference (>= 10x the still foot's noise on gdin, far below a heel-off)",
                                   lo=0.01)
    sleep_after_s: float = _f(1.0, "s", "wake-on-motion: inactivity before the device powers the gyroscope "
                              "down (longer than any stance of a walk)", lo=0.1)
    run_wake_margin: float = _f(1.4, "-", "run wake: the device's high-g interrupt fires above this times the "
                                "largest per-axis |a| of the person's walking strides (VICON walks <= 36.1, "
                                "runs median 41.0 m/s^2)", lo=1.0)

    def __post_init__(self) -> None:
        _validate(self)


@dataclass(frozen=True)
class CompassConfig:
    """Online magnetometer calibration against the ZUPT-KF (:class:`models.compass.MagCalibrator`)."""

    soft_iron: bool = _f(False, "-", "fit soft iron in the linear stance fit (the swings' joint fit adds it "
                         "where it is observable)")
    min_stances: int = _f(15, "stances", "stances before a calibration is used", lo=6)
    min_heading_spread_rad: float = _f(math.radians(60.0), "rad", "circular spread of the stances' headings "
                                       "before hard iron and field separate", lo=0.0, hi=math.pi)
    mag_tol: float = _f(0.12, "-", "disturbance gate: relative field magnitude against the fitted field "
                        "(002 eq. 4)", lo=0.0)
    dip_tol_rad: float = _f(math.radians(8.0), "rad", "disturbance gate: dip angle against the fitted field "
                            "(002 eq. 5)", lo=0.0)
    max_heading_rms_rad: float = _f(math.radians(5.0), "rad", "a calibration is trusted within this RMS "
                                    "disagreement with the ZUPT-KF (synthetic clean field 1.8 deg, every gdin "
                                    "indoor walk 10-33 deg)", lo=0.0)
    settled_mag_tol: float = _f(0.025, "-", "a trusted calibration takes only stances whose field magnitude is "
                                "its reference's within this (relative; clean synthetic fields <= 1.9 %): steel "
                                "edges that pass the gate pull the field and the hard iron towards the steel",
                                lo=0.0)
    settled_dip_tol_rad: float = _f(math.radians(3.0), "rad", "... and whose dip is within this", lo=0.0)
    soft_iron_std: float = _f(0.1, "-", "ridge prior of the soft-iron elements")
    hard_iron_std_ut: float = _f(100.0, "uT", "prior of the horizontal hard iron (parts carry tens of uT)")
    vertical_hard_iron_std_ut: float = _f(10.0, "uT", "prior of the vertical hard iron, which level stances "
                                          "cannot tell from the field's vertical part")
    min_swing: int = _f(40, "samples", "swing field samples before they join the fit", lo=1)
    alignment_std_rad: float = _f(math.radians(5.0), "rad", "prior of the magnetometer-accelerometer axis "
                                  "misalignment")

    def __post_init__(self) -> None:
        _validate(self)


@dataclass(frozen=True)
class StepsConfig:
    """Accelerometer-only step segmentation (:class:`models.steps.StepSegmenter`), run at ``pdr_rate_hz``."""

    window_s: float = _f(0.12, "s", "trailing window of the quietness statistic (a stance lasts 0.1-0.4 s)")
    stance_threshold: float = _f(1.5, "m/s^2", "a stretch is quiet below this statistic (sensor noise scale)")
    swing_min: float = _f(5.0, "m/s^2", "a stance is a step only after |a| - g exceeded this since the last one")
    refractory_frac: float = _f(0.6, "-", "candidates closer than this fraction of the stride period compete")
    min_period_s: float = _f(0.35, "s", "shortest step period (a sprint's stride is ~0.5 s)")
    max_period_s: float = _f(2.5, "s", "a longer gap means a rest preceded the step")
    fir_cutoff_hz: float = _f(8.0, "Hz", "Hamming-window FIR low-pass of the features (004 Sec. 2.2)")
    fir_length_s: float = _f(0.16, "s", "... and its length")
    swing_frac: float = _f(0.45, "-", "a new stride needs this fraction of the period between stances")
    min_swing_s: float = _f(0.25, "s", "... and at least this")
    context_s: float = _f(0.3, "s", "look-back/look-ahead for the impacts around a candidate")
    level_s: float = _f(1.5, "s", "look-back of the recent step energy")
    rel_threshold: float = _f(0.35, "-", "candidates are quieter than this fraction of the step energy")
    k_duration: float = _f(50.0, "m/s^2 per s", "score weight of a quiet stretch's duration")
    duration_cap_s: float = _f(0.3, "s", "... which saturates here")
    k_quiet: float = _f(2.0, "-", "score weight of the candidate's quietness")
    period_min_s: float = _f(0.5, "s", "lower bound of the running stride-period estimate")
    period_max_s: float = _f(1.5, "s", "upper bound of the running stride-period estimate")
    default_period_s: float = _f(1.0, "s", "stride period assumed until three have been measured")
    long_stance_s: float = _f(0.6, "s", "a quiet stretch longer than this (standing) is a candidate at once")
    max_latency_s: float = _f(1.0, "s", "hard bound on a step event's delay behind its onset (chunk invariance "
                              "is tested against it)", lo=0.1)

    def __post_init__(self) -> None:
        _validate(self)


@dataclass(frozen=True)
class StepLengthConfig:
    """Step-length models and their calibration (004 eq. 15, Table 3)."""

    model: str = _f("eq15", "-", "004 eq. (15) for walking (K0..K3); others for comparison", lo=None,
                    choices=("eq15", "eq15_run", "weinberg", "height_freq"))
    run_model: str = _f("eq15", "-", "running strides: the walking form fitted on them (eq15) or 004's "
                        "K4 cbrt(a) (eq15_run, which over-predicted gdin's slower runs by 23 %)", lo=None,
                        choices=("eq15", "eq15_run"))
    min_pairs: int = _f(8, "strides", "ZUPT-KF strides before a model is fitted", lo=3)
    band_hz: float = _f(0.2, "Hz", "half-width of a walking-pattern cadence band (004: 0.2)", lo=0.01)
    sigma_floor_m: float = _f(0.03, "m", "smallest sigma_d of 004 Table 3 (ZUPT-KF stride noise)", lo=0.0)
    band_prior_scale: float = _f(0.5, "-", "a band's model shrinks towards the pooled one with this times the "
                                 "generic prior's spread", lo=0.0)
    height_m: float = _f(1.75, "m", "user height for the height/frequency model", lo=0.5)
    min_stride_m: float = _f(0.3, "m", "shorter ZUPT-KF displacements are shuffles, not calibration strides")
    pause_period: float = _f(1.25, "-", "a stride of a walking pattern's re-placement this many times longer than "
                             "the pattern's median holds a stop and gets the median stride (strides scatter by "
                             "3 %, two paces lie 10-15 % apart)", lo=1.0)
    recent_strides: int = _f(8, "strides", "latest ZUPT-KF strides whose median places steps before a model "
                             "is fitted", lo=1)

    def __post_init__(self) -> None:
        _validate(self)


@dataclass(frozen=True)
class DeviationConfig:
    """KF II, the gait heading deviation (004 eq. 17-21)."""

    r_obs_rad: float = _f(math.radians(4.0), "rad", "per-stride spread of gamma - psi (R^II)", lo=1e-6)
    q_rate: float = _f(1e-10, "rad^2/s^3", "process noise of the deviation rate (004 eq. 17, w1)")
    q_dev: float = _f(1e-6, "rad^2/s", "process noise of the deviation (004 eq. 18, w2)")
    p0_rate_rad_s: float = _f(math.radians(0.05), "rad/s", "initial std of the deviation rate")
    gate_sigma: float = _f(4.0, "sigma", "observations beyond this are rejected (turn strides); 0 = no gate")
    turn_gate_rad: float = _f(math.radians(10.0), "rad", "strides turning more than this observe nothing "
                              "(eq. 20's chord mixes two directions)", lo=0.0)
    boot_updates: int = _f(3, "strides", "KF II updates before Gait-DR may place steps", lo=1)

    def __post_init__(self) -> None:
        _validate(self)


@dataclass(frozen=True)
class EngineConfig:
    """The engine's configuration tree.

    Attributes
    ----------
    rates, segments, scheduler, compass, steps, step_length, deviation
        Sections above.
    zupt : ZuptConfig
        The ZUPT-aided Kalman filter and its stance detector.
    heading : HeadingConfig
        The walking-heading estimator.
    pdr_conventional : bool
        Evaluation baseline "conventional PDR" (004 Table 6: generic step model, no heading deviation).
    """

    rates: RatesConfig = field(default_factory=RatesConfig)
    segments: SegmentsConfig = field(default_factory=SegmentsConfig)
    scheduler: SchedulerConfig = field(default_factory=SchedulerConfig)
    compass: CompassConfig = field(default_factory=CompassConfig)
    steps: StepsConfig = field(default_factory=StepsConfig)
    step_length: StepLengthConfig = field(default_factory=StepLengthConfig)
    deviation: DeviationConfig = field(default_factory=DeviationConfig)
    zupt: ZuptConfig = field(default_factory=ZuptConfig)
    heading: HeadingConfig = field(default_factory=HeadingConfig)
    pdr_conventional: bool = False

    def __post_init__(self) -> None:
        self.zupt.validate()

    def override(self, values: dict[str, Any]) -> EngineConfig:
        """A copy with ``{"section.field": value}`` changed (validated; an unknown path is refused by name)."""
        if not values:
            return self
        out: EngineConfig = self
        for path, value in values.items():
            parts = path.split(".")
            out = _replace_path(out, parts, value, path)
        return out

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def changes(self) -> dict[str, Any]:
        """``{"section.field": value}`` of the settings that differ from the defaults (what an engine state
        stores: the whole tree is 3 kB, the usual difference none); ``EngineConfig().override`` restores it."""
        if self is _default():  # the usual case, without hashing the whole frozen tree for the cache below
            return {}
        return dict(_changes(self))

    def _changes(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        _flatten(self.to_dict(), "", out)
        ref: dict[str, Any] = {}
        _flatten(_default().to_dict(), "", ref)
        return {k: v for k, v in out.items() if ref.get(k) != v}

    @classmethod
    def default(cls) -> EngineConfig:
        """The default configuration, built and validated once (frozen: safe to share)."""
        return _default()

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> EngineConfig:
        flat: dict[str, Any] = {}
        _flatten(d, "", flat)
        return cls().override(flat)


@functools.lru_cache(maxsize=1)
def _default() -> EngineConfig:
    return EngineConfig()


@functools.lru_cache(maxsize=16)
def _changes(config: EngineConfig) -> dict[str, Any]:
    """:meth:`EngineConfig.changes`, once per configuration (every stored engine state asks for it)."""
    return {} if config is _default() else config._changes()


def _replace_path(obj: Any, parts: list[str], value: Any, path: str) -> Any:
    names = {f.name for f in dataclasses.fields(obj)}
    if parts[0] not in names:
        raise ValueError(f"EngineConfig: unknown setting {path!r} ({type(obj).__name__} has {sorted(names)})")
    if len(parts) == 1:
        return dataclasses.replace(obj, **{parts[0]: value})
    return dataclasses.replace(obj, **{parts[0]: _replace_path(getattr(obj, parts[0]), parts[1:], value, path)})


def _flatten(d: dict[str, Any], prefix: str, out: dict[str, Any]) -> None:
    for k, v in d.items():
        if isinstance(v, dict):
            _flatten(v, f"{prefix}{k}.", out)
        else:
            out[f"{prefix}{k}"] = v


def _docstring_fields(cls: type) -> dict[str, tuple[str, str]]:
    """``{name: (unit, text)}`` from a NumPy-style "Attributes" section (units in square brackets)."""
    out: dict[str, tuple[str, str]] = {}
    doc = inspect.getdoc(cls) or ""
    name = None
    for line in doc.splitlines():
        m = re.match(r"^(\w+) : ", line)
        if m:
            name = m.group(1)
            out[name] = ("", "")
        elif name and line.startswith("    "):
            unit, text = out[name]
            out[name] = (unit, (text + " " + line.strip()).strip())
        elif not line.strip():
            name = None
    for k, (_, text) in out.items():
        m = re.search(r"\[([^\]]+)\]", text)
        out[k] = (m.group(1) if m else "-", text)
    return out


def config_table(config: EngineConfig | None = None) -> list[tuple[str, str, str, str]]:
    """Rows ``(path, value, unit, rationale)`` of every field of the tree (for ``docs/engine.md``): the
    engine's sections from their fields' metadata, the models' configurations from their docstrings."""
    rows: list[tuple[str, str, str, str]] = []

    def walk(obj: Any, prefix: str) -> None:
        doc = _docstring_fields(type(obj))
        for f in dataclasses.fields(obj):
            v = getattr(obj, f.name)
            if dataclasses.is_dataclass(v):
                walk(v, f"{prefix}{f.name}.")
                continue
            unit, why = f.metadata.get("unit"), f.metadata.get("why")
            if unit is None:
                unit, why = doc.get(f.name, ("", f"see {type(obj).__name__}"))
            rows.append((f"{prefix}{f.name}", f"{v:.6g}" if isinstance(v, float) else repr(v), unit, why))

    walk(config or EngineConfig(), "")
    return rows


def _cell(text: str) -> str:
    """Text for a Markdown table cell (a bar inside it, as in ``|a|``, would end the cell)."""
    return text.replace("|", "\\|")


def config_markdown(config: EngineConfig | None = None) -> str:
    """The configuration table as Markdown."""
    lines = ["| setting | value | unit | why |", "| --- | --- | --- | --- |"]
    lines += [f"| `{p}` | {v} | {_cell(u)} | {_cell(w)} |" for p, v, u, w in config_table(config)]
    return "\n".join(lines) + "\n"
