"""The streaming engine: one object per (user, device) session (DESIGN.md, "The engine contract").

``Engine.feed(batch)`` synchronises the sensor streams on the accelerometer's time axis, recognises behaviour,
and runs the navigation mode that the scheduler (:mod:`energy.scheduler`) chooses: the ZUPT-aided MARG Kalman
filter while the gait is being calibrated, calibrated gait dead reckoning afterwards (004 Sections 2, 4).
It returns the new positions, events and the sensor configuration the device must use next. The complete state
serialises to bytes (:meth:`Engine.to_bytes`) through the safe codec of :mod:`energy.codec`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from energy import codec
from energy.config import EngineConfig
from energy.gait_dr import GaitPipeline
from energy.profile import BehaviourCalibration, Profile
from energy.scheduler import Scheduler
from energy.types import Event, Position, SensorConfig, Update
from models.batch import BatchError, SensorBatch
from models.behaviour import BehaviourRecognizer
from models.zupt_nav import NavOutput, ZuptNavigator

__all__ = ["Engine", "EngineConfig", "EngineMode", "Trace"]  # EngineConfig re-exported from energy.config

EngineMode = Literal["zupt", "pdr", "auto"]
_MODES: tuple[str, ...] = ("zupt", "pdr", "auto")
_STATE_VERSION = 1
_GYRO_GAP_S = 0.25  # a longer gap in gyroscope samples (gyro was off) re-seats the ZUPT-KF
_LABEL_KEEP_S = 60.0  # behaviour decisions kept behind the newest sample (>> any detector look-ahead)


@dataclass
class Trace:
    """Per processed accelerometer sample output, kept only when the engine was built with ``trace=True``.

    Attributes
    ----------
    t_ns : ndarray of int64, shape (n,)
    pos : ndarray, shape (n, 3)
        NED position [m].
    behaviour : ndarray of str, shape (n,)
    mode : ndarray of str, shape (n,)
    gyro_on : ndarray of bool, shape (n,)
        Whether a gyroscope sample was paired with the accelerometer sample.
    """

    _t: list[np.ndarray] = field(default_factory=list)
    _pos: list[np.ndarray] = field(default_factory=list)
    _beh: list[np.ndarray] = field(default_factory=list)
    _mode: list[np.ndarray] = field(default_factory=list)
    _gyro: list[np.ndarray] = field(default_factory=list)

    def append(self, t_ns: np.ndarray, pos: np.ndarray, behaviour: np.ndarray, mode: np.ndarray, gyro_on: np.ndarray) -> None:
        if len(t_ns):
            self._t.append(t_ns)
            self._pos.append(pos)
            self._beh.append(behaviour)
            self._mode.append(mode)
            self._gyro.append(gyro_on)

    @staticmethod
    def _cat(parts: list[np.ndarray], empty: np.ndarray) -> np.ndarray:
        return np.concatenate(parts) if parts else empty

    @property
    def t_ns(self) -> np.ndarray:
        return self._cat(self._t, np.zeros(0, dtype=np.int64))

    @property
    def pos(self) -> np.ndarray:
        return self._cat(self._pos, np.zeros((0, 3)))

    @property
    def behaviour(self) -> np.ndarray:
        return self._cat(self._beh, np.zeros(0, dtype="<U5"))

    @property
    def mode(self) -> np.ndarray:
        return self._cat(self._mode, np.zeros(0, dtype="<U4"))

    @property
    def gyro_on(self) -> np.ndarray:
        return self._cat(self._gyro, np.zeros(0, dtype=bool))


class _StreamPairing:
    """Pairs gyroscope/magnetometer samples with accelerometer samples by causal zero-order hold.

    For an accelerometer sample at ``t`` the paired value is the latest sample of the stream at or before ``t``,
    if it is at most ``max_age_ns`` old; otherwise the row is NaN (stream off or gap). Only samples at or before
    ``t`` are used, so the pairing does not depend on where the batches were cut.
    """

    def __init__(self, max_age_ns: int) -> None:
        self.max_age_ns = int(max_age_ns)
        self.t = np.zeros(0, dtype=np.int64)
        self.v = np.zeros((0, 3))

    def push(self, t: np.ndarray, v: np.ndarray) -> None:
        if len(t):
            if len(self.t) and t[0] <= self.t[-1]:
                keep = t > self.t[-1]
                t, v = t[keep], v[keep]
            self.t = np.concatenate([self.t, t])
            self.v = np.concatenate([self.v, v])

    def pair(self, t_acc: np.ndarray) -> np.ndarray:
        out = np.full((len(t_acc), 3), np.nan)
        if len(self.t) == 0 or len(t_acc) == 0:
            return out
        idx = np.searchsorted(self.t, t_acc, side="right") - 1
        ok = idx >= 0
        ok[ok] &= (t_acc[ok] - self.t[idx[ok]]) <= self.max_age_ns
        out[ok] = self.v[idx[ok]]
        # keep the last sample at or before the newest accelerometer sample, and everything after it
        last = max(int(np.searchsorted(self.t, t_acc[-1], side="right")) - 1, 0)
        self.t, self.v = self.t[last:], self.v[last:]
        return out

    def get_state(self) -> dict[str, Any]:
        return {"max_age_ns": self.max_age_ns, "t": self.t, "v": self.v}

    @classmethod
    def from_state(cls, d: dict[str, Any]) -> _StreamPairing:
        obj = cls(d["max_age_ns"])
        obj.t = np.asarray(d["t"], dtype=np.int64)
        obj.v = np.asarray(d["v"], dtype=np.float64).reshape(-1, 3)
        return obj


class _LabelHistory:
    """Recent behaviour decisions, to label samples and stances by the decision in force at their time."""

    def __init__(self) -> None:
        self.t: list[float] = []
        self.labels: list[str] = []

    def add(self, t_s: float, label: str) -> None:
        self.t.append(float(t_s))
        self.labels.append(label)

    def prune(self, before_s: float) -> None:
        """Forget decisions superseded before ``before_s`` (keeps the one in force then)."""
        cut = int(np.searchsorted(np.asarray(self.t), before_s, side="right")) - 1
        if cut > 0:
            del self.t[:cut], self.labels[:cut]

    def at(self, t_s: float) -> str:
        i = int(np.searchsorted(np.asarray(self.t), t_s, side="right")) - 1
        return self.labels[i] if i >= 0 else "stand"

    def at_many(self, t_s: np.ndarray) -> np.ndarray:
        if not self.t:
            return np.full(len(t_s), "stand")
        i = np.searchsorted(np.asarray(self.t), t_s, side="right") - 1
        lab = np.asarray(self.labels + ["stand"])
        return lab[np.where(i >= 0, i, len(self.labels))]

    def get_state(self) -> dict[str, Any]:
        return {"t": list(self.t), "labels": list(self.labels)}

    @classmethod
    def from_state(cls, d: dict[str, Any]) -> _LabelHistory:
        obj = cls()
        obj.t, obj.labels = [float(x) for x in d["t"]], [str(x) for x in d["labels"]]
        return obj


class Engine:
    """One navigation session: feed batches, get positions, events and the next sensor configuration.

    Parameters
    ----------
    mode : {"zupt", "pdr", "auto"}
        ``zupt``: ZUPT-KF all the time at the full rate. ``pdr``: the 004 scheme, ZUPT-KF for the first L0
        metres, then calibrated Gait-DR with the gyroscope off at ``pdr_rate_hz``. ``auto``: the full
        energy-aware scheduler (behaviour gating, examination every T0, re-calibration).
    config : EngineConfig, optional
    profile : dict, optional
        Per-user calibration profile (:mod:`energy.profile`); a calibrated behaviour skips the initialisation.
    trace : bool
        Keep per-sample output in :attr:`trace` (evaluation, plots). Not part of the serialised state.
    """

    def __init__(
        self,
        mode: EngineMode = "auto",
        config: EngineConfig | None = None,
        profile: dict[str, Any] | None = None,
        trace: bool = False,
    ) -> None:
        if mode not in _MODES:
            raise ValueError(f"mode: expected one of {_MODES}, got {mode!r}")
        self.mode: EngineMode = mode
        self.config = config or EngineConfig()
        self.trace = Trace() if trace else None
        self._t0_ns: int | None = None
        self._last_acc_t: int | None = None
        max_age = int(self.config.max_sample_age_s * 1e9)
        self._gyr = _StreamPairing(max_age)
        self._mag = _StreamPairing(max_age)
        self._sched = Scheduler(mode, self.config, Profile.from_dict(profile) if profile else Profile())
        self._nav = ZuptNavigator()
        self._behaviour = BehaviourRecognizer()
        self._labels = _LabelHistory()
        self._gait = GaitPipeline(self.config.pdr_rate_hz) if mode != "zupt" else None
        self._last_gyr_s = -np.inf

    # ------------------------------------------------------------------ contract
    @property
    def sensor_config(self) -> SensorConfig:
        """The configuration the device must use for its next batch."""
        return self._sched.sensor_config()

    def profile_dict(self) -> dict[str, Any]:
        """The (possibly updated) per-user calibration profile, JSON-serialisable."""
        return self._sched.profile.to_dict()

    def feed(self, batch: SensorBatch) -> Update:
        """Consume one batch; see the module docstring.

        Raises
        ------
        models.batch.BatchError
            Malformed batch (non-finite values, timestamps not increasing, implausible units, or
            accelerometer samples older than ones already processed).
        """
        batch.validate()
        t_acc, acc = batch.acc_t_ns, batch.acc
        if len(t_acc) and self._last_acc_t is not None and t_acc[0] <= self._last_acc_t:
            raise BatchError("acc_t_ns", f"sample at {int(t_acc[0])} ns is not after the last one processed ({self._last_acc_t} ns)")
        self._gyr.push(*batch.stream("gyr"))
        self._mag.push(*batch.stream("mag"))
        if len(t_acc) == 0:
            return self._update([], [])
        if self._t0_ns is None:
            self._t0_ns = int(t_acc[0])
        self._last_acc_t = int(t_acc[-1])
        gyr = self._gyr.pair(t_acc)
        mag = self._mag.pair(t_acc)
        return self._process(t_acc, acc, gyr, mag, final=False)

    def flush(self) -> Update:
        """End of the session: process what the detectors' look-ahead still holds."""
        return self._process(np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), final=True)

    # ------------------------------------------------------------------ processing
    def _process(self, t_acc: np.ndarray, acc: np.ndarray, gyr: np.ndarray, mag: np.ndarray, final: bool) -> Update:
        events: list[Event] = []
        positions: list[Position] = []
        t0 = self._t0_ns if self._t0_ns is not None else 0
        t_s = (t_acc - t0) / 1e9
        for td, label in self._behaviour.process(t_s, acc):
            self._labels.add(td, label)
            events += self._sched.on_behaviour(label, td, t0 + int(round(td * 1e9)))
        gait = self._gait
        if gait is not None and len(t_s):
            gait.feed(t_s, acc, mag)
        t_switch = np.inf
        if self._sched.working == "zupt":
            has_gyr = ~np.isnan(gyr[:, 0])
            if final:
                out = self._nav.flush()
            else:
                ts, a_, g_, m_ = t_s[has_gyr], acc[has_gyr], gyr[has_gyr], mag[has_gyr]
                gaps = np.flatnonzero(np.diff(np.r_[self._last_gyr_s, ts]) > _GYRO_GAP_S)
                parts = []
                for lo, hi in zip(np.r_[0, gaps], np.r_[gaps, len(ts)]):
                    if hi <= lo:
                        continue
                    if lo in gaps and self._nav.initialised:
                        self._nav.reset(self._nav.position, self._nav.heading)  # gyro was off (standing): re-seat
                    mm = m_[lo:hi]
                    parts.append(self._nav.process(ts[lo:hi], a_[lo:hi], g_[lo:hi], mm if np.any(~np.isnan(mm[:, 0])) else None))
                if len(ts):
                    self._last_gyr_s = float(ts[-1])
                out = NavOutput.concatenate(parts)
            for st in out.stances:
                label = self._labels.at(st.t_end_s)
                d = st.step_length
                t_ns = t0 + int(round(st.t_end_s * 1e9))
                p = st.position
                positions.append(Position(t_ns, float(p[0]), float(p[1]), float(p[2]), float(st.heading), label, "zupt", d, True))
                events += self._sched.on_zupt_distance(d, t_ns)
                if gait is None:
                    continue
                gait.learn(st, label)
                if self._sched.ready_for_pdr() and gait.ready(label):
                    fits = gait.fit(label)
                    self._store_calibration(label, fits)
                    gait.start(np.asarray(p, dtype=float), float(st.heading), st.t_end_s)
                    events += self._sched.on_calibrated(st.t_end_s, t_ns)
                    t_switch = st.t_end_s
                    break
            if self.trace is not None and len(out.t_s):
                keep = out.t_s <= t_switch
                n = int(np.count_nonzero(keep))
                self.trace.append(
                    t0 + np.round(out.t_s[keep] * 1e9).astype(np.int64), out.pos[keep], self._labels.at_many(out.t_s[keep]),
                    np.full(n, "zupt"), np.ones(n, dtype=bool),
                )
        if gait is not None and self._sched.working == "pdr":
            steps = gait.reckon(self._labels.at)
            for step, ev in steps:
                t_ns = t0 + int(round(step.t_s * 1e9))
                pos = step.position
                positions.append(Position(t_ns, pos[0], pos[1], pos[2], step.direction, step.behaviour, "pdr", step.length, False))
            if self.trace is not None and steps:
                self.trace.append(
                    np.array([t0 + int(round(s.t_s * 1e9)) for s, _ in steps], dtype=np.int64),
                    np.array([s.position for s, _ in steps]), np.array([s.behaviour for s, _ in steps]),
                    np.full(len(steps), "pdr"), np.zeros(len(steps), dtype=bool),
                )
        if len(t_s):
            self._labels.prune(float(t_s[-1]) - _LABEL_KEEP_S)
        return self._update(positions, events)

    def _store_calibration(self, behaviour: str, fits: dict) -> None:
        """Put what the initialisation learned into the per-user profile (handed out by profile_dict)."""
        b = behaviour if behaviour in ("walk", "run") else "walk"
        gait = self._gait
        assert gait is not None
        pooled = fits.get(b, {})
        kf = gait.kf2[b]
        self._sched.profile.behaviours[b] = BehaviourCalibration(
            step_model={"calibrator": gait.cal.get_state()},
            sigma_d_m=float(pooled.get("sigma_d", float("nan"))),
            heading_deviation_rad=kf.deviation,
            heading_deviation_var=kf.variance,
            n_steps=int(pooled.get("n", 0)),
            calibrated=True,
        )

    def _update(self, positions: list[Position], events: list[Event]) -> Update:
        return Update(positions, events, self.sensor_config, self._sched.behaviour, self._sched.working)

    # ------------------------------------------------------------------ state
    def get_state(self) -> dict[str, Any]:
        return {
            "version": _STATE_VERSION,
            "mode": self.mode,
            "config": self.config.to_dict(),
            "t0_ns": self._t0_ns,
            "last_acc_t": self._last_acc_t,
            "gyr": self._gyr.get_state(),
            "mag": self._mag.get_state(),
            "sched": self._sched.get_state(),
            "nav": self._nav.get_state(),
            "behaviour": self._behaviour.get_state(),
            "labels": self._labels.get_state(),
            "gait": None if self._gait is None else self._gait.get_state(),
            "last_gyr_s": self._last_gyr_s,
        }

    @classmethod
    def from_state(cls, d: dict[str, Any], trace: bool = False) -> Engine:
        if d.get("version") != _STATE_VERSION:
            raise ValueError(f"engine state version {d.get('version')!r} is not {_STATE_VERSION}")
        obj = cls(mode=d["mode"], config=EngineConfig.from_dict(d["config"]), trace=trace)
        obj._t0_ns = d["t0_ns"]
        obj._last_acc_t = d["last_acc_t"]
        obj._gyr = _StreamPairing.from_state(d["gyr"])
        obj._mag = _StreamPairing.from_state(d["mag"])
        obj._sched = Scheduler.from_state(d["sched"])
        obj._nav = ZuptNavigator.from_state(d["nav"])
        obj._behaviour = BehaviourRecognizer.from_state(d["behaviour"])
        obj._labels = _LabelHistory.from_state(d["labels"])
        obj._gait = None if d["gait"] is None else GaitPipeline.from_state(d["gait"])
        obj._last_gyr_s = float(d["last_gyr_s"])
        return obj

    def to_bytes(self) -> bytes:
        """Complete state as bytes (safe codec, no pickle)."""
        return codec.dumps(self.get_state())

    @classmethod
    def from_bytes(cls, blob: bytes, trace: bool = False) -> Engine:
        return cls.from_state(codec.loads(blob), trace=trace)
