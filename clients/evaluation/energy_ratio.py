"""Energy and accuracy of an engine mode against the always-on baseline, on the same real recording.

``pednav eval vicon|gdin|gaitmap ... --mode auto|pdr`` and ``pednav eval recordings`` replay every recording twice
in one run: in the evaluated mode, and through ``Engine(mode="zupt")``, the always-on baseline (ZUPT-KF at the
full rate, gyroscope, accelerometer and magnetometer on throughout; DESIGN.md). Each replay's
:class:`energy.power.Timeline` (:meth:`~energy.power.Timeline.from_replay`: what the emulated device did) is
charged on one :class:`energy.power.PowerProfile` by :func:`energy.power.account`:

- sensors: each sensor's powered time at the rate it delivered (``energy.device.DeviceEmulator``'s spans). The
  gyroscope's turn-on (``energy.device.GYRO_TURN_ON_S``) is inside its charged time: a gyroscope the engine
  switches on is charged from the start of the batch whose configuration switched it on, one woken by motion
  from its activity sample (it delivers a turn-on time later);
- computation: accelerometer samples and batches per cost class (``zupt``/``pdr``/``idle``) times the stored
  costs measured for that engine (``energy/profiles/compute_costs.json``, ``engines.<mode>``; ``pdr``, which has
  no table of its own, is charged the ``auto`` engine's: the same engine class with the same cost classes);
- radio: the bytes uploaded in the byte model of :mod:`energy.power` and one request per batch.

``energy_ratio`` = the evaluated replay's total / the baseline's; ``accuracy_ratio`` = the dataset's own metric
of the evaluated replay / the baseline's (:data:`ACCURACY_METRICS`: ARMSE for VICON; the stride mean error where
gdin has a footprint per stride, else the loop closure; the stride-length error for gaitmap). A ratio whose
denominator is missing or zero is ``None``.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from clients.evaluation import metrics

if TYPE_CHECKING:
    from clients.evaluation.harness import EngineRun
    from energy.power import ComputeCosts, EnergyReport, PowerProfile, Timeline

__all__ = [
    "ACCURACY_METRICS",
    "ENERGY_KEYS",
    "EnergyAccounting",
    "accuracy_metric",
    "compare",
    "gyro_intervals",
    "summarise_worst",
    "add_summary",
    "metric_counts",
]

# the dataset's own metric, in order of preference (the first one both replays have is used)
ACCURACY_METRICS: dict[str, tuple[str, ...]] = {
    "vicon": ("armse_2d_m",),
    "gdin": ("stride_mean_err_m", "loop_closure_pct"),
    "gaitmap": ("stride_length_mean_abs_err_m",),
}
ENERGY_KEYS: tuple[str, ...] = ("energy_ratio", "gyro_on_fraction", "accuracy_ratio")  # summarised with "worst"
BASELINE = ("the same recording replayed through Engine(mode='zupt') in the same run: ZUPT-KF at the full rate, "
            "gyroscope, accelerometer and magnetometer on throughout, charged on the same profile")


@dataclass(frozen=True)
class EnergyAccounting:
    """Charges replays on one device profile with the stored per-engine computation costs.

    Parameters
    ----------
    profile : energy.power.PowerProfile
        Device profile (sensors, processor, radio) and its stored computation costs (``profile.compute``).
    """

    profile: PowerProfile

    @classmethod
    def load(cls, name: str | None = None) -> EnergyAccounting:
        """The profile ``energy/profiles/NAME.json`` or a path (None: :data:`energy.power.DEFAULT_PROFILE`, the foot
        device ``pednav energy simulate`` charges by default). ``ValueError`` naming the profile when unknown."""
        from energy.power import DEFAULT_PROFILE, load_profile, profile_names

        name = name or DEFAULT_PROFILE
        try:
            return cls(load_profile(name))
        except FileNotFoundError:
            raise ValueError(f"--power-profile {name}: no such profile (known: {', '.join(profile_names())}; "
                             "or a path to a profile JSON)") from None

    def costs(self, mode: str) -> tuple[ComputeCosts, str]:
        """Computation costs charged to an engine in ``mode`` (:meth:`energy.power.ComputeCosts.for_engine`; ``pdr``
        without a table of its own: the ``auto`` engine's) and which table of the cost file they are."""
        cc = self.profile.compute
        table = "auto" if mode == "pdr" and mode not in cc.engines else mode
        if table not in cc.engines:
            return cc, "top level (no engine table)"
        return cc.for_engine(table), f"engines.{table}"

    def report(self, timeline: Timeline, mode: str) -> EnergyReport:
        """Energy [mJ] of a replay of an engine in ``mode`` (:func:`energy.power.account`)."""
        from energy.power import account

        return account(timeline, replace(self.profile, compute=self.costs(mode)[0]))

    def describe(self, modes: Sequence[str]) -> dict[str, Any]:
        """What the JSON says about the profile, the computation costs and the baseline."""
        p = self.profile
        return {
            "power_profile": {
                "name": p.name,
                "description": p.description,
                "parts": {**{s: sp.part for s, sp in p.sensors.items()}, "processor": p.processor.part,
                          "radio": p.radio.part},
            },
            "compute_costs": {
                "source": "stored: energy/profiles/compute_costs.json",
                "measured": dict(p.compute.measured),
                "tables": {m: self.costs(m)[1] for m in dict.fromkeys([*modes, "zupt"])},
            },
            "energy_baseline": BASELINE,
            "radio_bytes": "byte model of energy.power: 6 B per 3-axis sample + 8 B time stamp, 64 B per request",
        }


def accuracy_metric(dataset: str, row: dict[str, Any], ref: dict[str, Any]) -> str | None:
    """The first metric of :data:`ACCURACY_METRICS` that both rows have (None: neither truth exists)."""
    for k in ACCURACY_METRICS.get(dataset, ()):
        if row.get(k) is not None and ref.get(k) is not None:
            return k
    return None


def _ratio(a: float | None, b: float | None) -> float | None:
    if a is None or b is None or not np.isfinite(a) or not np.isfinite(b) or b == 0:
        return None
    return float(a) / float(b)


def gyro_intervals(timeline: Timeline, t_start_ns: int) -> list[list[float]]:
    """``[[t_on_s, t_off_s], ...]``: the stretches the gyroscope was powered, from the recording's start [s]."""
    out: list[list[float]] = []
    t0 = t_start_ns / 1e9
    for iv in timeline.intervals:
        if iv.gyr_rate_hz <= 0:
            continue
        a, b = iv.t0_s - t0, iv.t1_s - t0
        if out and abs(out[-1][1] - a) < 1e-9:
            out[-1][1] = b
        else:
            out.append([a, b])
    return [[round(a, 3), round(b, 3)] for a, b in out]


def _switch_ons(timeline: Timeline) -> int:
    """Times the gyroscope went from off to powered within the recording."""
    on = [iv.gyr_rate_hz > 0 for iv in timeline.intervals if iv.t1_s > iv.t0_s]
    return int(sum(1 for a, b in zip(on, on[1:]) if b and not a))


def compare(accounting: EnergyAccounting, mode: str, run: EngineRun, ref: EngineRun, dataset: str | None = None,
            row: dict[str, Any] | None = None, ref_row: dict[str, Any] | None = None) -> dict[str, Any]:
    """Fields a row of a ``--mode auto|pdr`` evaluation gains: energy and accuracy against the baseline.

    Parameters
    ----------
    accounting : EnergyAccounting
    mode : str
        Mode of ``run``.
    run, ref : EngineRun
        The evaluated replay and the baseline's (``zupt``) replay of the same recording, both with a timeline.
    dataset : str, optional
        Key of :data:`ACCURACY_METRICS`; None: no accuracy (a recording without truth).
    row, ref_row : dict, optional
        The metric rows of both replays.

    Returns
    -------
    dict
        ``energy_ratio``, ``gyro_on_fraction``, ``accuracy_ratio`` and ``accuracy_metric`` (None without truth),
        and ``energy``: both totals and their components [mJ], the gyroscope's switch-ons, and the baseline's
        value of the accuracy metric.
    """
    if run.timeline is None or ref.timeline is None:
        raise ValueError("energy accounting needs the replays' timelines (harness.run_engine)")
    e, b = accounting.report(run.timeline, mode), accounting.report(ref.timeline, "zupt")
    key = accuracy_metric(dataset, row or {}, ref_row or {}) if dataset else None
    out: dict[str, Any] = {
        "energy_ratio": _ratio(e.total_mj, b.total_mj),
        "gyro_on_fraction": float(run.gyro_on_fraction),
        "accuracy_ratio": _ratio((row or {}).get(key), (ref_row or {}).get(key)) if key else None,
        "accuracy_metric": key,
        "energy": {
            "total_mj": e.total_mj,
            "baseline_total_mj": b.total_mj,
            "components_mj": dict(e.components_mj),
            "baseline_components_mj": dict(b.components_mj),
            "duration_s": e.duration_s,
            "gyro_switch_ons": _switch_ons(run.timeline),
        },
    }
    if key:
        out["energy"]["zupt_reference"] = {key: (ref_row or {}).get(key)}
    return out


def summarise_worst(values: Sequence[float | None]) -> dict[str, Any]:
    """:func:`clients.evaluation.metrics.summarise` plus ``worst`` (the largest: more energy, more gyroscope and a
    larger error ratio are all worse)."""
    v = [float(x) for x in values if x is not None and np.isfinite(x)]
    return {**metrics.summarise(v), "worst": max(v) if v else None}


def add_summary(summary: dict[str, Any], rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """``summary`` with ``{"mean", "median", "worst", "n"}`` of each of :data:`ENERGY_KEYS` over ``rows`` (those
    the summary is made of)."""
    out = dict(summary)
    for k in ENERGY_KEYS:
        out[k] = summarise_worst([r.get(k) for r in rows])
    return out


def metric_counts(rows: Sequence[dict[str, Any]]) -> dict[str, int]:
    """How many rows compared accuracy by each metric (``"None"``: no truth for any)."""
    return dict(Counter(str(r.get("accuracy_metric")) for r in rows if "energy_ratio" in r))
