"""Duty-cycle simulation: the energy-aware scheduler vs the always-on baseline on one synthetic recording.

Both engines replay the same recording through :func:`energy.device.replay` (a device obeying the engine's
sensor configuration: gyroscope samples dropped when it is off, accelerometer de-sampled when the rate is
lowered). Each replay becomes a :class:`energy.power.Timeline` and is accounted on a device profile. The
baseline is ``Engine(mode="zupt")`` at 200 Hz with all sensors on (004's ZUPT-KF).

Computation is measured, not assumed (004 Table 9): every ``Engine.feed`` of both runs is timed with the
thread's CPU clock (``time.thread_time_ns``, insensitive to other processes on a shared machine) by
:class:`MeteredEngine`, and attributed to the cost class of the sensor configuration the device used for that
batch: ``zupt`` (gyroscope on, ZUPT-KF at the full rate), ``pdr`` (gyroscope off, Gait-DR at the de-sampled
rate) or ``idle`` (standing: the lowest accelerometer rate). The compute energy of a run is its own measured
CPU time per class, scaled to the target processor. ``compute_reduction_pct`` is the 004 Table 9 figure: the
scheduler's measured computation per step vs the baseline's, both measured in the same process run.
With stored costs (``measure=False``, ``--stored-costs``) each engine is charged the costs
:func:`measure_compute_costs` measured for it with the batching of this simulation (the scheduler's 4-s
uploads once the gyroscope is off): per accelerometer sample plus per batch (the fixed cost of one
``Engine.feed``), per cost class. :func:`component_meter` additionally splits the time by engine component
(behaviour recognition, ZUPT-KF, Gait-DR stream, calibration, dead reckoning, input checks) so the report says
where the computation goes; with measured costs it meters a separate replay, so that its own clock reads are
not charged as the engine's computation.

Radio: the bytes of every uploaded batch as encoded by ``encode`` (the CLI passes the SDK's msgpack float32
encoder, i.e. the bytes the project's client really sends, its per-body framing included), plus one request
per batch. By default each device batches as long as its engine's ``SensorConfig.batch_s`` says (the scheduler
asks for longer uploads once the gyroscope is off and Gait-DR navigates); ``batch_seconds`` fixes it instead.

New or returning user: without ``user_profile`` the scheduler initialises every behaviour during the day (a new
user's first day); with the profile it handed out after an earlier day (:func:`learn_profile`), calibrated
behaviours resume in Gait-DR after one examination stride (the returning user, the product's normal case).

Position error: the positions (one per stance/step) are compared with the synthetic truth at the same
instants, after the one rotation about the origin that best matches the estimate's first 10 m to the
truth (the estimate's initial heading is arbitrary without a compass fix); same procedure for both engines.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import platform
import time
from dataclasses import dataclass, field
from datetime import date
from typing import TYPE_CHECKING, Any, Callable, Iterator, Sequence

import numpy as np

from energy.power import (
    REQUEST_OVERHEAD_BYTES,
    SAMPLE_BYTES,
    TIMESTAMP_BYTES,
    ComputeCosts,
    EnergyReport,
    Interval,
    PowerProfile,
    Timeline,
    account,
    cost_class,
)

if TYPE_CHECKING:
    from energy.device import ReplayResult
    from models.batch import SensorBatch

__all__ = [
    "RunResult",
    "BatchRecord",
    "MeteredEngine",
    "component_meter",
    "model_bytes",
    "cost_class",
    "position_errors",
    "step_errors",
    "run_engine",
    "simulate",
    "measure_compute_costs",
    "learn_profile",
]

COST_CLASSES: tuple[str, ...] = ("zupt", "pdr", "idle")
Encoder = Callable[["SensorBatch"], int]


def model_bytes(batch: SensorBatch) -> int:
    """Upload size [bytes] of a batch in the default byte model of :mod:`energy.power`.

    ``SAMPLE_BYTES + TIMESTAMP_BYTES`` per sample of every stream plus ``REQUEST_OVERHEAD_BYTES`` per request.
    """
    from models.batch import STREAMS

    n = sum(len(batch.stream(s)[0]) for s in STREAMS)
    return n * (SAMPLE_BYTES + TIMESTAMP_BYTES) + REQUEST_OVERHEAD_BYTES


@dataclass
class BatchRecord:
    """What one ``Engine.feed`` (or the final ``flush``) cost.

    Attributes
    ----------
    t0_ns : int
        Time of the batch's first accelerometer sample [ns] (-1 for an empty batch or the flush).
    cls : str
        Cost class (:func:`cost_class`).
    n_acc : int
        Accelerometer samples in the batch.
    n_samples : int
        Samples of all streams in the batch.
    nbytes : int
        Upload size of the batch [bytes] (0 for the flush, which uploads nothing).
    cpu_ns : int
        Thread CPU time spent inside the call [ns].
    """

    t0_ns: int
    cls: str
    n_acc: int
    n_samples: int
    nbytes: int
    cpu_ns: int


class _ComponentMeter:
    """Exclusive thread-CPU time per (engine component, cost class); see :func:`component_meter`."""

    def __init__(self) -> None:
        self.cls = "zupt"
        self.ns: dict[tuple[str, str], int] = {}
        self._stack: list[list[int]] = []  # [start, time spent in nested metered calls]

    def wrap(self, name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        def timed(*args: Any, **kw: Any) -> Any:
            frame = [time.thread_time_ns(), 0]
            self._stack.append(frame)
            try:
                return fn(*args, **kw)
            finally:
                self._stack.pop()
                total = time.thread_time_ns() - frame[0]
                key = (name, self.cls)
                self.ns[key] = self.ns.get(key, 0) + total - frame[1]
                if self._stack:
                    self._stack[-1][1] += total

        return timed


_COMPONENTS: tuple[tuple[str, str, str, str], ...] = (
    # (component, module, class, method)
    ("behaviour", "models.behaviour", "BehaviourRecognizer", "process"),
    ("zupt_kf", "models.zupt_nav", "ZuptNavigator", "process"),
    ("zupt_kf", "models.zupt_nav", "ZuptNavigator", "flush"),
    ("zupt_kf", "models.zupt_nav", "ZuptNavigator", "reset"),
    ("zupt_kf", "models.zupt_nav", "ZuptNavigator", "restart"),
    ("gait_stream", "energy.gait_dr", "GaitPipeline", "feed"),
    ("gait_calibration", "energy.gait_dr", "GaitPipeline", "learn"),
    ("gait_calibration", "energy.gait_dr", "GaitPipeline", "ready"),
    ("gait_calibration", "energy.gait_dr", "GaitPipeline", "fit"),
    ("gait_reckon", "energy.gait_dr", "GaitPipeline", "reckon"),
    ("compass_fit", "models.compass", "MagCalibrator", "fit"),
    ("input_checks", "models.batch", "SensorBatch", "validate"),
    ("stream_pairing", "energy.engine", "_StreamPairing", "push"),
    ("stream_pairing", "energy.engine", "_StreamPairing", "pair"),
)


@contextlib.contextmanager
def component_meter() -> Iterator[_ComponentMeter]:
    """Time the engine's components while the block runs (measurement only; originals restored on exit).

    Wraps the methods listed in ``_COMPONENTS`` with an exclusive thread-CPU timer (time in a nested metered
    call is counted once, in the inner component). Whatever ``Engine.feed`` spends outside them (scheduler,
    label history, events and positions) is the ``engine_other`` remainder computed by :func:`run_engine`.
    """
    import importlib

    meter = _ComponentMeter()
    saved = []
    for comp, mod, cls, meth in _COMPONENTS:
        klass = getattr(importlib.import_module(mod), cls, None)
        orig = None if klass is None else klass.__dict__.get(meth)
        if orig is None:  # the engine no longer has this method: nothing to time
            continue
        saved.append((klass, meth, orig))
        setattr(klass, meth, meter.wrap(comp, orig))
    try:
        yield meter
    finally:
        for klass, meth, orig in reversed(saved):
            setattr(klass, meth, orig)


class MeteredEngine:
    """An engine as :func:`energy.device.replay` sees it, with every call metered.

    Parameters
    ----------
    engine : energy.engine.Engine
        The engine to drive.
    encode : callable, optional
        ``batch -> bytes uploaded`` (default :func:`model_bytes`).
    meter : _ComponentMeter, optional
        Told the cost class of each batch so component times are split by class.

    Notes
    -----
    The cost class of a batch (:func:`cost_class`) comes from the configuration the device used for it, i.e.
    the engine's ``sensor_config`` just before ``feed`` (``replay`` reads it, emits the batch with it, then
    feeds), and the behaviour the engine reported with that configuration (the previous update's).
    """

    def __init__(self, engine: Any, encode: Encoder | None = None, meter: _ComponentMeter | None = None) -> None:
        self.engine = engine
        self.encode = encode or model_bytes
        self.meter = meter
        self.records: list[BatchRecord] = []
        self._behaviour = "stand"  # an engine starts standing

    @property
    def sensor_config(self) -> Any:
        return self.engine.sensor_config

    @property
    def trace(self) -> Any:
        return self.engine.trace

    def _run(self, fn: Callable[[], Any], cls: str, t0: int, n_acc: int, n_samples: int, nbytes: int) -> Any:
        if self.meter is not None:
            self.meter.cls = cls
        c0 = time.thread_time_ns()
        out = fn()
        self.records.append(BatchRecord(t0, cls, n_acc, n_samples, nbytes, time.thread_time_ns() - c0))
        return out

    def feed(self, batch: SensorBatch) -> Any:
        from models.batch import STREAMS

        # a wake-on-motion gyroscope may run although the configuration had it off: the batch's gyroscope samples decide
        cls = cost_class(self.engine.sensor_config.gyro_on or len(batch.stream("gyr")[0]) > 0, self._behaviour)
        n = sum(len(batch.stream(s)[0]) for s in STREAMS)
        t0 = int(batch.acc_t_ns[0]) if len(batch) else -1
        upd = self._run(lambda: self.engine.feed(batch), cls, t0, len(batch), n, int(self.encode(batch)))
        self._behaviour = str(upd.behaviour)
        return upd

    def flush(self) -> Any:
        cls = self.records[-1].cls if self.records else "zupt"
        return self._run(self.engine.flush, cls, -1, 0, 0, 0)

    def cpu_us_by_class(self) -> dict[str, float]:
        out: dict[str, float] = {}
        for r in self.records:
            out[r.cls] = out.get(r.cls, 0.0) + r.cpu_ns / 1e3
        return out

    def samples_by_class(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for r in self.records:
            if r.n_acc:
                out[r.cls] = out.get(r.cls, 0) + r.n_acc
        return out

    def batches_by_class(self) -> dict[str, int]:
        """``Engine.feed`` calls (uploads) per cost class; the final flush is not a batch."""
        out: dict[str, int] = {}
        for r in self.records:
            if _is_batch(r):
                out[r.cls] = out.get(r.cls, 0) + 1
        return out


def _is_batch(r: BatchRecord) -> bool:
    """A record of an ``Engine.feed`` (an upload), not of the final ``flush`` (which uploads nothing)."""
    return r.t0_ns != -1 or r.nbytes > 0

ALIGN_RADIUS_M = 10.0  # m, the part of the path used to fit the heading alignment


@dataclass
class RunResult:
    """One engine over one recording: replay, timeline, energy, errors and measured computation.

    Attributes
    ----------
    cpu_us_by_class : dict of str to float
        Thread CPU time inside the engine per cost class [us], this run.
    samples_by_class : dict of str to int
        Accelerometer samples per cost class.
    component_us : dict of str to dict of str to float
        ``{component: {cost class: us}}`` (empty unless metered by components).
    records : list of BatchRecord
        One per ``feed`` and the final ``flush``.
    interval_classes : list of str
        Cost class of each interval of ``timeline.intervals``.
    step_errors : dict
        :func:`step_errors` of the reported positions against the truth, the ``strides_corrected`` jumps
        left out.
    """

    mode: str
    replay: ReplayResult
    timeline: Timeline
    energy: EnergyReport
    errors: dict[str, float]
    cpu_us_by_class: dict[str, float] = field(default_factory=dict)
    samples_by_class: dict[str, int] = field(default_factory=dict)
    component_us: dict[str, dict[str, float]] = field(default_factory=dict)
    records: list[BatchRecord] = field(default_factory=list)
    interval_classes: list[str] = field(default_factory=list)
    step_errors: dict[str, dict[str, float]] = field(default_factory=dict)


def position_errors(t_ns: np.ndarray, est_ne: np.ndarray, truth_t_ns: np.ndarray, truth_ne: np.ndarray) -> dict[str, float]:
    """Horizontal errors of estimated positions against the truth at the same times.

    Parameters
    ----------
    t_ns : ndarray of int64, shape (K,)
        Times of the estimates [ns].
    est_ne : ndarray, shape (K, 2)
        Estimated north/east [m] (origin at the first stance).
    truth_t_ns : ndarray of int64, shape (N,)
        Truth sample times [ns].
    truth_ne : ndarray, shape (N, 2)
        Truth north/east [m].

    Returns
    -------
    dict
        ``mean_m``, ``rms_m``, ``final_m`` (last position), ``max_m`` and ``align_deg`` (fitted rotation).
    """
    if len(t_ns) == 0:
        return {"mean_m": float("nan"), "rms_m": float("nan"), "final_m": float("nan"), "max_m": float("nan"), "align_deg": 0.0}
    idx = np.clip(np.searchsorted(truth_t_ns, t_ns), 0, len(truth_t_ns) - 1)
    tru = truth_ne[idx] - truth_ne[idx[0]]
    est = est_ne - est_ne[0]
    # Least-squares rotation (2-D Procrustes without scale) of est onto tru over the first metres: the positions
    # until the truth first leaves ALIGN_RADIUS_M of the start. A later return near the start carries the
    # error accumulated meanwhile and must not set the alignment (held-out day seed 3: the baseline's path,
    # back near its start three times, was turned by 106 deg where its first 10 m asked 89 deg; mean error
    # 17.1 m for a walk whose heading was within 5 deg of the truth's).
    far = np.flatnonzero(np.linalg.norm(tru, axis=1) > ALIGN_RADIUS_M)
    m = np.arange(len(tru)) < (far[0] if far.size else len(tru))
    h = np.sum(est[m, 0] * tru[m, 1] - est[m, 1] * tru[m, 0])
    c = np.sum(est[m, 0] * tru[m, 0] + est[m, 1] * tru[m, 1])
    ang = float(np.arctan2(h, c)) if (abs(h) + abs(c)) > 0 else 0.0
    rot = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
    e = np.linalg.norm(est @ rot.T - tru, axis=1)
    return {
        "mean_m": float(np.mean(e)),
        "rms_m": float(np.sqrt(np.mean(e**2))),
        "final_m": float(e[-1]),
        "max_m": float(np.max(e)),
        "align_deg": float(np.degrees(ang)),
    }


def step_errors(t_ns: np.ndarray, est_ne: np.ndarray, modes: Sequence[str], truth_t_ns: np.ndarray,
                truth_ne: np.ndarray, align_deg: float = 0.0,
                jump_t_ns: Sequence[int] | np.ndarray | None = None) -> dict[str, dict[str, float]]:
    """Per navigation mode: how far each reported step's direction and length are from the truth's.

    A step is the displacement between two consecutive reported positions, charged to the mode of the second;
    it is compared with the truth's displacement between the same times where both are at least a stride
    (truth >= 0.5 m, estimate >= 0.3 m: starts, stops and shuffles left out). Unlike the position error, where
    a heading error and a step-length error can cancel along a path, this says how good each step is.

    A step that holds a jump of the position which is no step (``jump_t_ns``: the engine's ``strides_corrected``,
    which moves the current position by the re-placed Gait-DR strides' change without re-sending them) is left
    out of every mode: the jump is made after the position at its time was reported, so the step from the
    position at or before the jump's time to the next one holds it, i.e. the step whose interval
    ``[t_prev, t_next)`` contains the jump's time (synthetic mixed day, seed 0: a 0.55-m jump in a 1.6-m ZUPT-KF
    stride read 13 deg of direction error).

    Parameters
    ----------
    t_ns : ndarray of int64, shape (K,)
        Times of the reported positions [ns].
    est_ne : ndarray, shape (K, 2)
        Reported north/east [m].
    modes : sequence of str, length K
        Navigation mode of each reported position (``"zupt"``, ``"pdr"``).
    truth_t_ns : ndarray of int64, shape (N,)
        Truth sample times [ns].
    truth_ne : ndarray, shape (N, 2)
        Truth north/east [m].
    align_deg : float
        Rotation of the estimate onto the truth [deg] (:func:`position_errors`' ``align_deg``).
    jump_t_ns : sequence of int, optional
        Times [ns] of position jumps that are no step (the ``strides_corrected`` events' ``t_ns``); None: none.

    Returns
    -------
    dict
        ``{mode: {"steps", "direction_err_deg", "length_err_pct", "jumps_left_out"}}``: the number of steps
        compared, their mean absolute direction error weighted by the true step length [deg], mean absolute
        relative length error [%], and the number of this mode's steps that would have been compared but were
        left out because they hold a jump (0 without ``jump_t_ns``).
    """
    out: dict[str, dict[str, float]] = {}
    if len(t_ns) < 2:
        return out
    idx = np.clip(np.searchsorted(truth_t_ns, t_ns), 0, len(truth_t_ns) - 1)
    est = np.diff(np.asarray(est_ne, dtype=np.float64).reshape(-1, 2), axis=0)
    tru = np.diff(np.asarray(truth_ne, dtype=np.float64)[idx], axis=0)
    le, lt = np.hypot(est[:, 0], est[:, 1]), np.hypot(tru[:, 0], tru[:, 1])
    ang = np.arctan2(est[:, 1], est[:, 0]) + math.radians(align_deg) - np.arctan2(tru[:, 1], tru[:, 0])
    d_err = np.degrees(np.abs(np.angle(np.exp(1j * ang))))
    m_of = np.asarray(modes[1:], dtype=object)
    ok = (lt >= 0.5) & (le >= 0.3)
    jump = np.zeros(len(est), dtype=bool)
    if jump_t_ns is not None and len(jump_t_ns):
        t = np.asarray(t_ns, dtype=np.int64)
        for tj in np.asarray(jump_t_ns, dtype=np.int64):
            jump |= (t[:-1] <= tj) & (tj < t[1:])  # step i runs from position i to i + 1
    for mode in sorted(set(m_of.tolist())):
        sel = ok & ~jump & (m_of == mode)
        if np.any(sel):
            out[str(mode)] = {"steps": int(np.sum(sel)),
                              "direction_err_deg": float(np.sum(d_err[sel] * lt[sel]) / np.sum(lt[sel])),
                              "length_err_pct": float(100.0 * np.mean(np.abs(le[sel] / lt[sel] - 1.0))),
                              "jumps_left_out": int(np.sum(ok & jump & (m_of == mode)))}
    return out


def run_engine(
    mode: str,
    batch: SensorBatch,
    profile: PowerProfile,
    truth_t_ns: np.ndarray,
    truth_pos: np.ndarray,
    batch_seconds: float | None = 1.0,
    measure: bool = True,
    encode: Encoder | None = None,
    components: bool = False,
    user_profile: dict[str, Any] | None = None,
    config: Any = None,
) -> RunResult:
    """Replay ``batch`` through a fresh ``Engine(mode=mode)`` and account its energy on ``profile``.

    Parameters
    ----------
    mode : {"auto", "zupt", "pdr"}
    batch : SensorBatch
        Native-rate recording.
    profile : PowerProfile
        Device profile; its ``compute`` costs are used only when ``measure`` is False.
    truth_t_ns, truth_pos : ndarray
        Truth times [ns] and NED positions [m].
    batch_seconds : float or None
        Upload batch duration [s]; None: as long as the engine's ``SensorConfig.batch_s`` says.
    measure : bool
        Account the computation this run actually took (thread CPU time per cost class, see the module
        docstring). False: use the stored costs of ``profile.compute`` for this engine mode
        (:meth:`energy.power.ComputeCosts.for_engine`: per sample, per batch and per step; deterministic).
    encode : callable, optional
        ``batch -> uploaded bytes`` (default :func:`model_bytes`).
    components : bool
        Also split the CPU time by engine component (:func:`component_meter`).
    user_profile : dict, optional
        Per-user calibration profile handed to the engine (a returning user, see :func:`learn_profile`).
    """
    from energy.device import replay
    from energy.engine import Engine

    ctx = component_meter() if components else contextlib.nullcontext()
    with ctx as meter:
        eng = MeteredEngine(Engine(mode=mode, config=config, profile=user_profile), encode, meter)
        res = replay(eng, batch, batch_seconds=batch_seconds)  # type: ignore[arg-type]
    t_end = int(batch.t_end_ns or 0)
    intervals, classes = [], []
    for i, (t0, c) in enumerate(res.configs):
        t1 = res.configs[i + 1][0] if i + 1 < len(res.configs) else t_end
        # what the device really did in the batch (a wake-on-motion gyroscope is charged from its wake only)
        for a, b, acc_hz, gyr_hz, mag_hz in res.spans[i]:
            a, b = max(a, t0), min(b, t1)
            if b > a:
                intervals.append(Interval(a / 1e9, b / 1e9, acc_hz, gyr_hz, mag_hz))
                classes.append(eng.records[i].cls)  # one record per feed, in the order of res.configs
    steps: dict[str, int] = {}
    for p in res.positions:
        steps[p.mode] = steps.get(p.mode, 0) + 1
    samples = eng.samples_by_class()
    cpu = eng.cpu_us_by_class()
    nbytes = sum(r.nbytes for r in eng.records)
    tl = Timeline(intervals, samples, steps, nbytes, int(res.batches), eng.batches_by_class())
    if measure:
        # Each class's measured CPU time spread over its samples: account() then charges exactly the time taken
        # (the flush, which carries no samples, is in the time of the class of the last batch).
        costs = ComputeCosts(
            us_per_sample={k: cpu.get(k, 0.0) / max(samples.get(k, 0), 1) for k in set(cpu) | set(samples)},
            us_per_step={},
            measured={"date": date.today().isoformat(), "machine": _machine(), "command": "this run (thread CPU time)"},
        )
        rep = account(tl, dataclasses.replace(profile, compute=costs))
    else:
        rep = account(tl, dataclasses.replace(profile, compute=profile.compute.for_engine(mode)))
    t = np.array([p.t_ns for p in res.positions], dtype=np.int64)
    ne = np.array([[p.north, p.east] for p in res.positions], dtype=float).reshape(-1, 2)
    errs = position_errors(t, ne, truth_t_ns, truth_pos[:, :2])
    # the position jumps of re-placed Gait-DR strides are no step (step_errors)
    jumps = [e.t_ns for u in res.updates for e in u.events if e.kind == "strides_corrected"]
    steps_err = step_errors(t, ne, [p.mode for p in res.positions], truth_t_ns, truth_pos[:, :2], errs["align_deg"],
                            jumps)
    comp: dict[str, dict[str, float]] = {}
    if meter is not None:
        for (name, k), ns in meter.ns.items():
            comp.setdefault(name, {})[k] = comp.get(name, {}).get(k, 0.0) + ns / 1e3
        for k, us in cpu.items():
            inside = sum(v.get(k, 0.0) for v in comp.values())
            comp.setdefault("engine_other", {})[k] = us - inside
    return RunResult(mode, res, tl, rep, errs, cpu, samples, comp, eng.records, classes, steps_err)


def learn_profile(batch: SensorBatch, batch_seconds: float | None = 1.0, config: Any = None) -> dict[str, Any]:
    """The per-user calibration profile the scheduler hands out after one session on ``batch``.

    A returning user (the product's normal case) starts the next session with it: calibrated behaviours
    resume in Gait-DR after one examination stride instead of a full L0 initialisation (004 Table 2).
    """
    from energy.device import replay
    from energy.engine import Engine

    eng = Engine(mode="auto", config=config)
    replay(eng, batch, batch_seconds=batch_seconds)
    return eng.profile_dict()


def _warm_up(batch: SensorBatch, batch_seconds: float | None, seconds: float = 120.0) -> None:
    """Run both engines over the first ``seconds`` of ``batch`` so one-off costs (numba compilation of the
    ZUPT-KF kernel, imports, caches) are not charged to the measured run as if they were per-sample work."""
    from energy.device import replay
    from energy.engine import Engine

    t0 = int(batch.t_start_ns or 0)
    piece = batch.time_slice(t0, t0 + int(seconds * 1e9))
    if len(piece):
        for mode in ("zupt", "auto"):
            replay(Engine(mode=mode), piece, batch_seconds=batch_seconds)


def _machine() -> str:
    return f"{platform.machine()} {platform.processor() or platform.platform()}, {os.cpu_count()} cpus, python {platform.python_version()}"


def energy_by_class(r: RunResult, profile: PowerProfile) -> dict[str, dict[str, float]]:
    """Split a run's energy [mJ] by cost class (``zupt``, ``pdr``, ``idle``) and component.

    Sensors: the intervals of each class (:func:`cost_class` of the interval's batch);
    computation: the class's measured CPU time (or its stored per-sample cost); radio: the bytes and requests
    of the class's batches. Also ``time_s`` per class. The classes add up to the run's totals.
    """
    v = profile.supply_v
    out: dict[str, dict[str, float]] = {}

    def row(k: str) -> dict[str, float]:
        return out.setdefault(k, {"time_s": 0.0, "acc": 0.0, "gyr": 0.0, "mag": 0.0, "compute": 0.0, "radio": 0.0})

    for iv, k in zip(r.timeline.intervals, r.interval_classes):
        d = row(k)
        d["time_s"] += iv.t1_s - iv.t0_s
        for sname in ("acc", "gyr", "mag"):
            d[sname] += (iv.t1_s - iv.t0_s) * profile.sensors[sname].current(iv.rate(sname)) * v / 1000.0
    for k, us in r.energy.compute_us_by_mode.items():
        row(k)["compute"] += us * 1e-6 * profile.processor.slowdown_vs_bench * profile.processor.active_mw
    for rec in r.records:
        d = row(rec.cls)
        is_request = rec.t0_ns != -1 or rec.nbytes > 0  # the flush uploads nothing
        d["radio"] += (rec.nbytes * profile.radio.uj_per_byte + (profile.radio.uj_per_request if is_request else 0.0)) / 1000.0
    for d in out.values():
        d["total"] = d["acc"] + d["gyr"] + d["mag"] + d["compute"] + d["radio"]
    return out


def simulate(
    profile: PowerProfile,
    batch: SensorBatch,
    truth_t_ns: np.ndarray,
    truth_pos: np.ndarray,
    truth_steps: int,
    batch_seconds: float | None = 1.0,
    measure: bool = True,
    encode: Encoder | None = None,
    components: bool = True,
    repeats: int = 1,
    user_profile: dict[str, Any] | None = None,
    config: Any = None,
) -> dict[str, Any]:
    """Scheduler (``auto``) vs always-on baseline (``zupt``) on one recording with truth; ``config`` the
    scheduler's :class:`energy.config.EngineConfig` (default: the defaults).

    Parameters
    ----------
    profile : PowerProfile
        Device profile for the accounting.
    batch : SensorBatch
        Native-rate recording (e.g. ``clients.synth.synthesize("mixed-day").batch``).
    truth_t_ns : ndarray of int64, shape (N,)
        Truth times [ns].
    truth_pos : ndarray, shape (N, 3)
        Truth NED positions [m].
    truth_steps : int
        Number of true strides (denominator of the compute per step).
    batch_seconds : float or None
        Upload batch duration [s]; None: each device batches as long as its engine's ``SensorConfig.batch_s``
        says (the baseline's is always 1 s).
    measure : bool
        Charge the computation measured in this run (default); False uses the stored costs of
        ``profile.compute`` (deterministic, for tests).
    encode : callable, optional
        ``batch -> uploaded bytes`` (default :func:`model_bytes`).
    components : bool
        Split the CPU time by engine component. With ``measure`` the split comes from one more replay of each
        engine, metered by :func:`component_meter`; the timed replays that are charged run without the meter
        (its two clock reads per metered call added ~15 us to a standing batch, ~10 % of the idle class, and
        3-4 % to the baseline).
    repeats : int
        With ``measure``: replay each engine this many times, interleaved, and keep for each the run with the
        least total CPU time (timing noise on a shared machine only ever adds time). Positions and sensor
        schedules are identical across repeats (the engine is deterministic).
    user_profile : dict, optional
        Calibration profile of a returning user for the scheduler (:func:`learn_profile`); the baseline
        ZUPT-KF needs none. None: a new user (the scheduler initialises every behaviour on this day).

    Returns
    -------
    dict
        The core of ``pednav energy simulate --json`` (DESIGN.md): per-run energy components [mJ] in total and
        per cost class, ``energy_ratio`` (scheduler/baseline), ``gyro_on_fraction``, ``compute_reduction_pct``
        (computation per true step, scheduler vs baseline, 004 Table 9), the per-step cost of each mode,
        the computation per engine component, position errors of both and the targets with pass/fail.
    """
    if measure:
        _warm_up(batch, batch_seconds)
    runs: dict[str, RunResult] = {}
    metered: dict[str, RunResult] = {}
    for _ in range(max(int(repeats), 1) if measure else 1):
        for m in ("auto", "zupt"):
            # measured: the charged replays run without the component meter (its overhead is not the engine's)
            r = run_engine(m, batch, profile, truth_t_ns, truth_pos, batch_seconds, measure, encode,
                           components and not measure, user_profile if m == "auto" else None,
                           config if m == "auto" else None)
            if m not in runs or sum(r.cpu_us_by_class.values()) < sum(runs[m].cpu_us_by_class.values()):
                runs[m] = r
    if measure and components:
        for m in ("auto", "zupt"):
            metered[m] = run_engine(m, batch, profile, truth_t_ns, truth_pos, batch_seconds, measure, encode, True,
                                    user_profile if m == "auto" else None, config if m == "auto" else None)
            runs[m].component_us = metered[m].component_us
    sched, base = runs["auto"], runs["zupt"]
    steps = max(int(truth_steps), 1)

    def run_doc(r: RunResult) -> dict[str, Any]:
        e = r.energy
        us = float(sum(e.compute_us_by_mode.values()))
        return {
            "mode": r.mode,
            "energy_mj": {
                "sensors": e.sensors_mj,
                "acc": e.components_mj["acc"],
                "gyr": e.components_mj["gyr"],
                "mag": e.components_mj["mag"],
                "compute": e.components_mj["compute"],
                "radio": e.components_mj["radio"],
                "total": e.total_mj,
            },
            "energy_by_class_mj": energy_by_class(r, profile),
            "mean_power_mw": e.total_mj / e.duration_s if e.duration_s > 0 else None,
            "compute_source": "measured in this run (thread CPU time)" if measure else (
                f"stored costs (energy/profiles/compute_costs.json, engine {r.mode!r}: per sample"
                f"{' and per batch' if profile.compute.for_engine(r.mode).us_per_batch else ''})"),
            "compute_us_bench": us,
            "compute_us_per_step": us / steps,
            "compute_us_by_class": dict(e.compute_us_by_mode),
            "compute_us_per_sample_by_class": {
                k: v / r.timeline.samples_by_mode[k] for k, v in e.compute_us_by_mode.items() if r.timeline.samples_by_mode.get(k)
            },
            "compute_us_by_component": {c: dict(v) for c, v in sorted(r.component_us.items())},
            **({"compute_us_by_component_source": "a separate replay with the component meter (its overhead "
                "included there, not in the charged compute_us_by_class)",
                "compute_us_by_class_metered": dict(metered[r.mode].cpu_us_by_class)} if r.mode in metered else {}),
            "samples_by_class": dict(r.timeline.samples_by_mode),
            "batches_by_class": dict(r.timeline.batches_by_mode),
            "steps_by_mode": dict(r.timeline.steps_by_mode),
            "bytes_sent": r.timeline.bytes_sent,
            "requests": r.timeline.requests,
            "gyro_on_fraction": float(r.replay.gyro_on_fraction),
            "mean_rate_hz": float(r.replay.mean_rate_hz),
            "positions": len(r.replay.positions),
            "position_error": r.errors,
            "step_errors": r.step_errors,
        }

    ratio = sched.energy.total_mj / base.energy.total_mj
    us_s = sum(sched.energy.compute_us_by_mode.values())
    us_b = sum(base.energy.compute_us_by_mode.values())
    cr = 100.0 * (1.0 - us_s / us_b)
    # Mode against mode (004 Table 5): Gait-DR's computation per Gait-DR step in the scheduler run vs the
    # ZUPT-KF's per stride at 200 Hz in the baseline run (same process, same recording).
    pdr_steps = sched.timeline.steps_by_mode.get("pdr", 0)
    pdr_us_step = sched.energy.compute_us_by_mode.get("pdr", 0.0) / pdr_steps if pdr_steps else float("nan")
    zupt_us_step = us_b / steps
    mode_cr = 100.0 * (1.0 - pdr_us_step / zupt_us_step) if pdr_steps else float("nan")
    err_ratio = sched.errors["mean_m"] / base.errors["mean_m"] if base.errors["mean_m"] > 0 else float("inf")
    return {
        "duration_s": float((int(batch.t_end_ns or 0) - int(batch.t_start_ns or 0)) / 1e9),
        "truth_steps": int(truth_steps),
        "truth_path_m": float(np.sum(np.linalg.norm(np.diff(truth_pos[:, :2], axis=0), axis=1))),
        "profile": profile.name,
        "compute_costs_measured": (
            {"date": date.today().isoformat(), "machine": _machine(),
             "how": f"thread CPU time of every Engine.feed, least of {max(int(repeats), 1)} interleaved runs per engine"}
            if measure
            else dict(profile.compute.measured)
        ),
        "scheduler": run_doc(sched),
        "baseline": run_doc(base),
        "energy_ratio": ratio,
        "gyro_on_fraction": float(sched.replay.gyro_on_fraction),
        "compute_reduction_pct": cr,
        "compute_per_step_us": {"scheduler": us_s / steps, "baseline_zupt_200hz": us_b / steps},
        "mode_cost_per_step_us": {"gait_dr": pdr_us_step, "zupt_kf_200hz": zupt_us_step, "reduction_pct": mode_cr},
        "position_error_m": {"scheduler": sched.errors["mean_m"], "baseline": base.errors["mean_m"], "ratio": err_ratio},
        "targets": {
            "energy_ratio_le_0.25": bool(ratio <= 0.25),
            "compute_reduction_ge_80pct": bool(cr >= 80.0),  # whole day, scheduler vs baseline per step
            "mode_compute_reduction_ge_80pct": bool(mode_cr >= 80.0),  # Gait-DR vs ZUPT-KF per step (004 Table 9)
            "position_error_ratio_le_1.5": bool(err_ratio <= 1.5),
        },
    }


def _split_costs(n_acc: np.ndarray, cpu_us: np.ndarray) -> tuple[float, float]:
    """``(us per sample, us per batch)`` of one cost class from its batches' sample counts and CPU times [us].

    Least squares of ``cpu = a * n + b`` over the batches; with an intercept the fitted costs add up to the
    measured total exactly. The two terms are separable only when the batches' lengths differ (the scheduler
    uploads 1-s and 4-s batches, :attr:`energy.types.SensorConfig.batch_s`): with fewer than two lengths of at
    least 3 batches each, or a negative term, everything is charged per sample (``b = 0``, ``a`` = total /
    samples: exact at the batching measured).
    """
    total, samples = float(cpu_us.sum()), int(n_acc.sum())
    folded = (total / samples if samples else 0.0, 0.0)
    values, counts = np.unique(n_acc, return_counts=True)
    # sample counts of one batch length vary by a few samples (rate changes, the first and last batch): group
    # them by length within 10 %
    groups: list[int] = []
    for v, c in zip(values.tolist(), counts.tolist()):
        if groups and v <= 1.1 * groups[-2]:
            groups[-1] += c
        else:
            groups += [v, c]
    if sum(1 for c in groups[1::2] if c >= 3) < 2:
        return folded
    a, b = np.linalg.lstsq(np.c_[n_acc, np.ones(len(n_acc))], cpu_us, rcond=None)[0]
    if a < 0 or b < 0:
        return folded
    return float(a), float(b)


def measure_compute_costs(day: SensorBatch, repeats: int = 3, batch_seconds: float | None = None) -> dict[str, Any]:
    """Measure per-class engine cost on this machine, in the ``compute_costs.json`` form.

    Replays ``day`` (a mixed scenario) through ``Engine("zupt")`` (the always-on baseline) and
    ``Engine("auto")`` (the scheduler) with :class:`MeteredEngine`: thread CPU time of every ``feed``,
    attributed to the cost class of the batch's sensor configuration. Each engine uploads as
    :func:`simulate` has it upload by default (``batch_seconds`` None: as long as its ``SensorConfig.batch_s``
    says, 4 s once the gyroscope is off and Gait-DR navigates, else 1 s), so the costs are those of the day the
    accounting charges them to. Every batch keeps the least of its ``repeats`` CPU times (the engine is
    deterministic: the same batches each time; timing noise on a shared machine only ever adds time); the two
    engines' replays alternate.

    Per cost class: ``us_per_sample`` (top level) is the class's total CPU time per accelerometer sample at
    that batching (the single figure of older files: ``zupt`` the baseline's, ``pdr``/``idle`` the
    scheduler's); ``engines.<mode>`` splits each engine's classes into a per-sample and a per-batch cost
    (:func:`_split_costs`), which :func:`energy.power.account` charges when accounting that engine.
    """
    from energy.device import replay
    from energy.engine import Engine

    _warm_up(day, batch_seconds)
    engines: dict[str, dict[str, Any]] = {}
    flat: dict[str, float] = {}
    engine_classes = (("zupt", ("zupt",)), ("auto", ("pdr", "idle")))
    replays: dict[str, list[list[BatchRecord]]] = {mode: [] for mode, _top in engine_classes}
    for _ in range(repeats):  # the engines interleaved: a change of the machine's load reaches both
        for mode, _top in engine_classes:
            eng = MeteredEngine(Engine(mode=mode))
            replay(eng, day, batch_seconds=batch_seconds)  # type: ignore[arg-type]
            replays[mode].append(eng.records)
    for mode, top in engine_classes:
        runs = replays[mode]
        shape = [(r.cls, r.n_acc) for r in runs[0]]
        if any([(r.cls, r.n_acc) for r in rr] != shape for rr in runs):
            raise RuntimeError(f"Engine({mode!r}) replayed differently between repeats: not deterministic")
        cpu = np.min(np.array([[r.cpu_ns for r in rr] for rr in runs], dtype=np.float64), axis=0) / 1e3
        cls = np.array([c for c, _ in shape])
        n = np.array([k for _, k in shape], dtype=np.int64)
        fed = np.array([_is_batch(r) for r in runs[0]])
        per_sample: dict[str, float | None] = {}
        per_batch: dict[str, float | None] = {}
        seen: dict[str, dict[str, float]] = {}
        for k in COST_CLASSES:
            m = (cls == k) & fed
            if not n[m].sum():
                per_sample[k] = per_batch[k] = None
                continue
            # the flush (no samples) is charged with the class of the last batch, as in the simulated day
            total = float(cpu[cls == k].sum())
            a, b = _split_costs(n[m], cpu[m] * total / float(cpu[m].sum()))
            per_sample[k], per_batch[k] = round(a, 4), round(b, 2)
            seen[k] = {"batches": int(m.sum()), "samples": int(n[m].sum()), "cpu_us": round(total, 1)}
            if k in top:
                flat[k] = total / float(n[m].sum())
        engines[mode] = {"us_per_sample": per_sample, "us_per_batch": per_batch, "measured_on": seen}
    batching = (f"fixed {batch_seconds} s batches" if batch_seconds else
                "each engine's own batching (SensorConfig.batch_s: the scheduler 4 s with the gyroscope off and "
                "Gait-DR navigating, else 1 s; the baseline 1 s), as `pednav energy simulate` replays the day")
    return {
        # None = the engine never ran in that class during the measurement (accounting refuses to guess).
        "us_per_sample": {m: (round(flat[m], 3) if m in flat else None) for m in COST_CLASSES},
        "us_per_step": {"zupt": 0.0, "pdr": 0.0, "idle": 0.0},
        "engines": engines,
        "measured": {
            "date": date.today().isoformat(),
            "machine": _machine(),
            "load_average": " ".join(f"{x:.2f}" for x in os.getloadavg()) if hasattr(os, "getloadavg") else "n/a",
            "command": "pednav energy simulate --measure-costs (energy.simulate.measure_compute_costs: synthetic "
            f"'mixed-day' seed 0, Engine('zupt') and Engine('auto'), {batching}, least of {repeats} per batch)",
            "note": "thread CPU time inside Engine.feed, attributed per batch to the cost class of the sensor "
            "configuration the batch was recorded with. us_per_sample: a class's total per accelerometer sample at "
            "that batching (zupt from the baseline engine, pdr/idle from the scheduler). engines.<mode>: each "
            "engine's own costs, split into per accelerometer sample and per batch (one Engine.feed; least squares "
            "over the day's batches, null = class not seen; per batch 0 where all its batches had one length: "
            "folded into per sample; measured_on: batches, samples and CPU time behind them); the accounting "
            "charges these. Per-step costs folded into the other terms",
        },
    }
