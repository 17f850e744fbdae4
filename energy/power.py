"""Device power profiles and energy accounting: what each component actually did over a timeline.

Energy (all in mJ; ``uA x V x s = uJ``, ``mW x s = mJ``):

- sensors: for every interval of constant configuration and every sensor,
  ``duration [s] x I(rate) [uA] x V [V]``, with ``I(rate)`` interpolated in the datasheet's current-vs-output
  data rate table and the power-down current when the sensor is off;
- computation: per navigation mode, ``samples x cost_per_sample + batches x cost_per_batch + steps x
  cost_per_step`` in microseconds measured on the benchmark machine (``pednav energy simulate
  --measure-costs``, stored with date and machine in ``compute_costs.json``), scaled by the target processor's
  slowdown relative to that machine, times its active power. Each engine (``zupt``: the always-on baseline,
  ``auto``: the scheduler) has its own costs where the file has them (:meth:`ComputeCosts.for_engine`): the
  scheduler's ZUPT-KF batches also run behaviour recognition, the Gait-DR step stream and the calibration, so
  they cost more per sample than the baseline's. The per-batch term is the fixed cost of one ``Engine.feed``
  (one upload), so a day uploaded in 4-s batches is not charged the overhead of 1-s batches;
- radio: ``bytes x energy_per_byte + requests x energy_per_request``.

The components add up to the total exactly (the total is computed as their sum in a fixed order).
Profiles are JSON files in ``energy/profiles/`` whose every figure carries its source.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from energy.device import ReplayResult

__all__ = [
    "SensorPower",
    "ProcessorPower",
    "RadioPower",
    "ComputeCosts",
    "PowerProfile",
    "Interval",
    "Timeline",
    "EnergyReport",
    "profile_names",
    "load_profile",
    "load_compute_costs",
    "account",
    "SAMPLE_BYTES",
    "REQUEST_OVERHEAD_BYTES",
    "cost_class",
    "DEFAULT_PROFILE",
]

SENSORS: tuple[str, ...] = ("acc", "gyr", "mag")
MODES: tuple[str, ...] = ("zupt", "pdr", "idle")
SAMPLE_BYTES = 6  # bytes per uploaded 3-axis sample (3 x int16, the sensors' native 16-bit output)
TIMESTAMP_BYTES = 8  # int64 ns per uploaded sample time
REQUEST_OVERHEAD_BYTES = 64  # per batch: headers, session id, stream descriptors (assumption, small)
DEFAULT_PROFILE = "foot-004"  # the foot device of 004's parts: what energy simulate and eval charge by default


@dataclass(frozen=True)
class SensorPower:
    """Supply current of one sensor vs output data rate.

    Parameters
    ----------
    part : str
        Part number.
    odr_hz : tuple of float
        Output data rates of the datasheet table [Hz], increasing.
    current_ua : tuple of float
        Supply current at those rates [uA].
    off_current_ua : float
        Power-down current [uA].
    source : str
        Datasheet name and table/page.
    verified : str
        What of ``source`` was checked against the datasheet text, and what was not (``"not checked"`` when
        the profile does not say).
    """

    part: str
    odr_hz: tuple[float, ...]
    current_ua: tuple[float, ...]
    off_current_ua: float
    source: str
    verified: str = "not checked"

    def current(self, rate_hz: float) -> float:
        """Supply current [uA] at ``rate_hz`` (0 = off); linear in the table, clamped at its ends."""
        if rate_hz <= 0:
            return float(self.off_current_ua)
        return float(np.interp(rate_hz, self.odr_hz, self.current_ua))


@dataclass(frozen=True)
class ProcessorPower:
    """Processor running the engine.

    Parameters
    ----------
    part : str
        Processor and clock.
    active_mw : float
        Power while computing [mW].
    slowdown_vs_bench : float
        How many times longer the same computation takes on this processor than on the benchmark machine.
    source : str
        Where ``active_mw`` and ``slowdown_vs_bench`` come from.
    """

    part: str
    active_mw: float
    slowdown_vs_bench: float
    source: str


@dataclass(frozen=True)
class RadioPower:
    """Uplink radio: energy per uploaded byte and per request (connection event / transaction)."""

    part: str
    uj_per_byte: float
    uj_per_request: float
    source: str


@dataclass(frozen=True)
class ComputeCosts:
    """Measured per-mode computation costs on the benchmark machine.

    Parameters
    ----------
    us_per_sample : dict of str to float
        Microseconds per accelerometer sample per mode (``zupt``, ``pdr``, ``idle``).
    us_per_step : dict of str to float
        Extra microseconds per emitted position (step/stance) per mode.
    measured : dict
        ``{"date", "machine", "command"}`` of the measurement.
    us_per_batch : dict of str to float, optional
        Extra microseconds per batch (one ``Engine.feed``, i.e. one upload) per mode: the fixed cost of a call,
        whatever its length. Empty: folded into ``us_per_sample`` at the batching it was measured with.
    engines : dict of str to ComputeCosts, optional
        Costs of one engine mode (``"zupt"``: the always-on baseline, ``"auto"``: the scheduler), used by
        :meth:`for_engine` instead of these top-level figures.
    """

    us_per_sample: dict[str, float]
    us_per_step: dict[str, float]
    measured: dict[str, str]
    us_per_batch: dict[str, float] = field(default_factory=dict)
    engines: dict[str, ComputeCosts] = field(default_factory=dict)

    def for_engine(self, mode: str) -> ComputeCosts:
        """The costs of the engine running in ``mode`` (``zupt``, ``pdr``, ``auto``); these top-level figures
        when the measurement has none of its own for it."""
        own = self.engines.get(mode)
        if own is None:
            return self
        return ComputeCosts(own.us_per_sample, own.us_per_step or self.us_per_step, self.measured, own.us_per_batch)


@dataclass(frozen=True)
class PowerProfile:
    """Everything needed to turn a timeline into energy."""

    name: str
    description: str
    supply_v: float
    sensors: dict[str, SensorPower]
    processor: ProcessorPower
    radio: RadioPower
    compute: ComputeCosts


def cost_class(gyro_on: bool, behaviour: str) -> str:
    """Navigation cost class of a batch from the state the device and engine were in for it.

    ``zupt``: gyroscope on (ZUPT-KF at the full rate: initialisation or examination); ``idle``: gyroscope
    off while the engine's behaviour is ``stand``; ``pdr``: gyroscope off otherwise (Gait-DR, de-sampled).
    The behaviour is the one the engine reported together with the configuration the batch was recorded with.
    """
    if gyro_on:
        return "zupt"
    return "idle" if behaviour == "stand" else "pdr"


@dataclass(frozen=True)
class Interval:
    """A stretch of time with one sensor configuration.

    Parameters
    ----------
    t0_s, t1_s : float
        Start and end [s].
    acc_rate_hz, gyr_rate_hz, mag_rate_hz : float
        Output data rates [Hz]; 0 = sensor off.
    """

    t0_s: float
    t1_s: float
    acc_rate_hz: float
    gyr_rate_hz: float
    mag_rate_hz: float

    def rate(self, sensor: str) -> float:
        return float(getattr(self, f"{sensor}_rate_hz"))


@dataclass
class Timeline:
    """What a device and its engine did: the input of :func:`account`.

    Parameters
    ----------
    intervals : list of Interval
        Sensor configurations over time (non-overlapping).
    samples_by_mode : dict of str to int
        Accelerometer samples processed in each navigation mode.
    steps_by_mode : dict of str to int
        Positions (steps/stances) emitted in each mode.
    bytes_sent : int
        Bytes uploaded.
    requests : int
        Upload requests (batches).
    batches_by_mode : dict of str to int, optional
        Batches (``Engine.feed`` calls) per mode, charged the per-batch compute cost.
    """

    intervals: list[Interval]
    samples_by_mode: dict[str, int] = field(default_factory=dict)
    steps_by_mode: dict[str, int] = field(default_factory=dict)
    bytes_sent: int = 0
    requests: int = 0
    batches_by_mode: dict[str, int] = field(default_factory=dict)

    @property
    def duration_s(self) -> float:
        return float(sum(iv.t1_s - iv.t0_s for iv in self.intervals))

    @property
    def steps(self) -> int:
        return int(sum(self.steps_by_mode.values()))

    @classmethod
    def from_replay(cls, res: ReplayResult, t_end_ns: int, window_ns: tuple[int, int] | None = None) -> Timeline:
        """Build the timeline of a replay (``energy.device.replay``), of the whole replay or of a time window.

        Intervals come from ``res.configs`` (batch start [ns], configuration used for that batch), the last
        one ending at ``t_end_ns``, split by ``res.spans`` where the device's sensors changed state within a
        batch (wake-on-motion). Samples per cost class (:func:`cost_class`: the batch's configuration and
        the behaviour the engine reported with it, so standing counts as ``idle`` whatever navigation mode is
        nominally active): ``acc rate x duration`` per batch, scaled so the total equals the accelerometer
        samples actually sent; batches per cost class of their configuration. Steps per mode from ``res.positions``; bytes from ``res.samples_sent``
        (``SAMPLE_BYTES + TIMESTAMP_BYTES`` per sample, ``REQUEST_OVERHEAD_BYTES`` per request).
        :func:`energy.simulate.run_engine` counts the samples and bytes of every batch exactly instead.

        ``window_ns`` ``(t0, t1)`` [ns]: only that stretch: intervals clipped to it, batches that start in it,
        positions in it; each stream's samples (accelerometer samples per cost class, bytes) as that stream's
        samples sent scaled by its rate x duration in the window over the same in the whole replay (an estimate:
        the replay does not keep the samples' times).
        """
        w0, w1 = window_ns if window_ns is not None else (-(2 ** 62), 2 ** 62)
        cfgs = list(res.configs)
        intervals = []
        est: dict[str, float] = {}
        streams = {"acc": [0.0, 0.0], "gyr": [0.0, 0.0], "mag": [0.0, 0.0]}  # rate x duration [samples]: whole, window
        batches: dict[str, int] = {}
        for i, (t0, c) in enumerate(cfgs):
            t1 = cfgs[i + 1][0] if i + 1 < len(cfgs) else int(t_end_ns)
            # the device's real sensor states in the batch (a wake-on-motion gyroscope runs for part of it)
            spans = res.spans[i] if i < len(res.spans) else [(t0, t1, c.acc_rate_hz, c.gyr_rate_hz if c.gyro_on else 0.0, c.mag_rate_hz)]
            behaviour = res.updates[i - 1].behaviour if 0 < i <= len(res.updates) else "stand"
            kb = cost_class(bool(c.gyro_on or any(sp[3] > 0 for sp in spans)), str(behaviour))
            if w0 <= t0 < w1:
                batches[kb] = batches.get(kb, 0) + 1  # every batch is one Engine.feed
            if t1 <= t0:
                continue
            for a, b, acc_hz, gyr_hz, mag_hz in spans:
                a, b = max(a, t0), min(b, t1)
                if b <= a:
                    continue
                k = cost_class(bool(c.gyro_on or gyr_hz > 0), str(behaviour))
                wa, wb = max(a, w0), min(b, w1)
                for name, hz in (("acc", acc_hz), ("gyr", gyr_hz), ("mag", mag_hz)):
                    streams[name][0] += (b - a) / 1e9 * hz
                    if wb > wa:
                        streams[name][1] += (wb - wa) / 1e9 * hz
                a, b = wa, wb
                if b <= a:
                    continue
                intervals.append(Interval(a / 1e9, b / 1e9, acc_hz, gyr_hz, mag_hz))
                est[k] = est.get(k, 0.0) + (b - a) / 1e9 * acc_hz
        n_acc = int(res.samples_sent.get("acc", 0))
        scale = n_acc / (streams["acc"][0] or 1.0)
        samples = {m: int(round(v * scale)) for m, v in est.items()}
        steps: dict[str, int] = {}
        for p in res.positions:
            if w0 <= p.t_ns < w1:
                steps[p.mode] = steps.get(p.mode, 0) + 1
        if window_ns is None:
            n_samples = int(sum(res.samples_sent.values()))
        else:  # each stream's samples sent, in the window's share of its rate x duration
            n_samples = int(round(sum(res.samples_sent.get(k, 0) * (w / whole if whole > 0 else 0.0)
                                      for k, (whole, w) in streams.items())))
        requests = int(sum(batches.values())) if window_ns is not None else int(res.batches)
        nbytes = n_samples * (SAMPLE_BYTES + TIMESTAMP_BYTES) + requests * REQUEST_OVERHEAD_BYTES
        return cls(intervals, samples, steps, nbytes, requests, batches)


@dataclass(frozen=True)
class EnergyReport:
    """Energy per component [mJ]; ``total_mj`` is exactly the sum of ``components_mj`` in key order."""

    components_mj: dict[str, float]
    total_mj: float
    compute_us_by_mode: dict[str, float]
    duration_s: float
    steps: int

    @property
    def sensors_mj(self) -> float:
        return self.components_mj["acc"] + self.components_mj["gyr"] + self.components_mj["mag"]

    def compute_mj_per_step(self) -> float:
        return self.components_mj["compute"] / self.steps if self.steps else float("nan")

    def to_dict(self) -> dict[str, Any]:
        return {
            "components_mj": dict(self.components_mj),
            "sensors_mj": self.sensors_mj,
            "compute_mj": self.components_mj["compute"],
            "radio_mj": self.components_mj["radio"],
            "total_mj": self.total_mj,
            "mean_power_mw": self.total_mj / self.duration_s if self.duration_s > 0 else float("nan"),
            "compute_us_by_mode": dict(self.compute_us_by_mode),
            "duration_s": self.duration_s,
            "steps": self.steps,
        }


def account(timeline: Timeline, profile: PowerProfile) -> EnergyReport:
    """Energy of a timeline on a device profile (see the module docstring for the equations)."""
    v = profile.supply_v
    comp: dict[str, float] = {}
    for s in SENSORS:
        sp = profile.sensors[s]
        # uA x V x s = uJ -> /1000 = mJ
        comp[s] = sum((iv.t1_s - iv.t0_s) * sp.current(iv.rate(s)) * v for iv in timeline.intervals) / 1000.0
    cc = profile.compute
    us_by_mode: dict[str, float] = {}
    for m, n in timeline.samples_by_mode.items():
        if n and m not in cc.us_per_sample:
            raise ValueError(f"compute costs: no measured cost per sample for mode {m!r} ({cc.measured.get('date', '?')})")
    for m in sorted(set(timeline.samples_by_mode) | set(timeline.steps_by_mode) | set(timeline.batches_by_mode)):
        us_by_mode[m] = (timeline.samples_by_mode.get(m, 0) * cc.us_per_sample.get(m, 0.0)
                         + timeline.batches_by_mode.get(m, 0) * cc.us_per_batch.get(m, 0.0)
                         + timeline.steps_by_mode.get(m, 0) * cc.us_per_step.get(m, 0.0))
    target_s = sum(us_by_mode.values()) * 1e-6 * profile.processor.slowdown_vs_bench
    comp["compute"] = target_s * profile.processor.active_mw  # mW x s = mJ
    comp["radio"] = (timeline.bytes_sent * profile.radio.uj_per_byte + timeline.requests * profile.radio.uj_per_request) / 1000.0
    total = 0.0
    for k in ("acc", "gyr", "mag", "compute", "radio"):
        total += comp[k]
    return EnergyReport(comp, total, us_by_mode, timeline.duration_s, timeline.steps)


# ---------------------------------------------------------------------------------------------- loading
def _profiles_dir() -> Path:
    return Path(str(resources.files("energy") / "profiles"))


def profile_names() -> list[str]:
    """Device profiles available in ``energy/profiles`` (files other than ``compute_costs.json``)."""
    return sorted(p.stem for p in _profiles_dir().glob("*.json") if p.stem != "compute_costs")


def _costs_of(d: dict[str, Any], key: str) -> dict[str, float]:
    """``{mode: float}`` of one cost table (an absent table or ``null`` entries are left out)."""
    return {k: float(v) for k, v in (d.get(key) or {}).items() if v is not None}


def load_compute_costs(path: str | Path | None = None) -> ComputeCosts:
    """Measured per-mode costs (default ``energy/profiles/compute_costs.json``).

    Files written before the per-batch term and the per-engine tables existed (only ``us_per_sample`` and
    ``us_per_step``) load with both empty: everything is then charged per sample.
    """
    d = json.loads(Path(path or _profiles_dir() / "compute_costs.json").read_text())
    measured = {k: str(v) for k, v in d["measured"].items()}
    engines = {
        str(mode): ComputeCosts(_costs_of(e, "us_per_sample"), _costs_of(e, "us_per_step"), measured,
                                _costs_of(e, "us_per_batch"))
        for mode, e in (d.get("engines") or {}).items()
    }
    return ComputeCosts(
        us_per_sample=_costs_of(d, "us_per_sample"),
        us_per_step=_costs_of(d, "us_per_step"),
        measured=measured,
        us_per_batch=_costs_of(d, "us_per_batch"),
        engines=engines,
    )


def load_profile(name_or_path: str | Path, compute: ComputeCosts | None = None) -> PowerProfile:
    """Load a device profile by name (``energy/profiles/NAME.json``) or path.

    Raises ``ValueError`` naming the missing field when a figure has no source.
    """
    p = Path(name_or_path)
    if not p.suffix:
        p = _profiles_dir() / f"{name_or_path}.json"
    d = json.loads(p.read_text())
    sensors = {}
    for s in SENSORS:
        sd = d["sensors"][s]
        if not sd.get("source"):
            raise ValueError(f"{p.name}: sensors.{s}.source is missing")
        table = sorted((float(r), float(i)) for r, i in sd["odr_current_ua"])
        sensors[s] = SensorPower(
            part=sd["part"],
            odr_hz=tuple(r for r, _ in table),
            current_ua=tuple(i for _, i in table),
            off_current_ua=float(sd["off_current_ua"]),
            source=sd["source"],
            verified=str((sd.get("verified") or {}).get("status", "not checked")),
        )
    pr, ra = d["processor"], d["radio"]
    for key, sub in (("processor", pr), ("radio", ra)):
        if not sub.get("source"):
            raise ValueError(f"{p.name}: {key}.source is missing")
    return PowerProfile(
        name=d["name"],
        description=d.get("description", ""),
        supply_v=float(d["supply_v"]),
        sensors=sensors,
        processor=ProcessorPower(pr["part"], float(pr["active_mw"]), float(pr["slowdown_vs_bench"]), pr["source"]),
        radio=RadioPower(ra["part"], float(ra["uj_per_byte"]), float(ra["uj_per_request"]), ra["source"]),
        compute=compute or load_compute_costs(),
    )
