"""``pednav bench phone``: the step-and-heading pipeline's cost and its MARG filter against the widely used peers,
all measured in the same run (ratios only mean something on a shared, noisy machine).

- Per-step cost: CPU time inside ``feed``/``flush`` per emitted position, of the step-and-heading engine
  (always-on and energy-aware) on a phone recording (an IPIN 2023 trial from ``PEDNAV_DATA``, else the synthetic
  ``phone-walk``), and of the ZUPT-KF (``Engine("zupt")``) on a foot recording (a VICON trial, else the synthetic
  foot ``walk``), one position per stance (a stride).
- The MARG filter (:class:`models.marg.MargFilter`) against ``ahrs``'s Madgwick ``updateMARG`` (Python) and
  ``imufusion`` (Fusion, the C AHRS), one sample at a time, on the same phone recording: microseconds per gyroscope
  sample (the peers are stepped at the gyroscope's times with the latest accelerometer and magnetometer samples;
  the MARG filter also takes every accelerometer and magnetometer sample as its own event), and accuracy where it
  matters: the landmark errors of the IPIN trials when each filter's forward-axis heading (plus the declination)
  heads the engine's own steps and step lengths (the Android phone's own rotation vector as a fourth heading).
- The step-and-heading engine's compute costs per accelerometer sample and cost class (``zupt`` = gyroscope on,
  ``pdr`` = off, ``idle`` = standing; the classes of :func:`energy.power.cost_class`), which the energy accounting
  charges (``--write-costs`` stores them as ``engines.phone`` in ``energy/profiles/compute_costs.json``).
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per measurement (best is kept)")
    parser.add_argument("--trials", type=int, default=4, help="IPIN trials for the heading accuracy comparison (0: all)")
    parser.add_argument("--peer-samples", type=int, default=6000, help="gyroscope samples fed to each peer for speed")
    parser.add_argument("--write-costs", action="store_true",
                        help="store the measured compute costs as engines.phone in energy/profiles/compute_costs.json")


def _phone_recordings(n: int) -> tuple[str, list[Any]]:
    from clients.datasets import dataset_dir
    from clients.importers import list_recordings, load

    d = dataset_dir("ipin2023-t3-phone")
    if d is not None:
        files = list_recordings(d)
        if files:
            pick = files if n <= 0 else files[:: max(1, len(files) // n)][:n]
            return "ipin2023-t3-phone", [load(f) for f in pick]
    from clients.phone_synth import synthesize_phone

    return "synthetic phone-walk", [synthesize_phone("phone-walk", seed=s) for s in range(max(1, min(n, 2)))]


def _foot_batch() -> tuple[str, Any]:
    from clients.datasets import dataset_dir

    d = dataset_dir("vicon")
    if d is not None:
        from clients.evaluation.harness import load_vicon_trial, vicon_files

        files = vicon_files(d)
        if files:
            rec = load_vicon_trial(files[len(files) // 4])
            return f"vicon/{rec.name}", rec.batch
    from clients.synth import synthesize

    return "synthetic walk", synthesize("walk").batch


def _cpu_per_position(make: Any, batches: list[Any], repeat: int) -> tuple[float, int]:
    """Best-of-``repeat`` thread CPU time [us] inside feed/flush per emitted position, and the positions."""
    best, n_pos = math.inf, 0
    for k in range(max(1, repeat) + 1):
        eng = make()
        n, cpu = 0, 0.0
        for b in batches:
            c0 = time.thread_time()
            u = eng.feed(b)
            cpu += time.thread_time() - c0
            n += len(u.positions)
        c0 = time.thread_time()
        n += len(eng.flush().positions)
        cpu += time.thread_time() - c0
        if k == 0:
            continue  # warm-up: compilation, caches
        best, n_pos = min(best, cpu), n
    return best / max(n_pos, 1) * 1e6, n_pos


def _zoh(t_src: np.ndarray, v: np.ndarray, t: np.ndarray) -> np.ndarray:
    i = np.clip(np.searchsorted(t_src, t, side="right") - 1, 0, len(t_src) - 1)
    return v[i]


def _forward_azimuth(q_wxyz: np.ndarray) -> np.ndarray:
    """Forward-axis azimuth [rad] of body -> NED quaternions (w, x, y, z): ``atan2(-C[0,0], C[1,0])``."""
    w, x, y, z = q_wxyz[:, 0], q_wxyz[:, 1], q_wxyz[:, 2], q_wxyz[:, 3]
    c00 = 1 - 2 * (y * y + z * z)
    c10 = 2 * (x * y + w * z)
    return np.arctan2(-c00, c10)


def _peers(rec: Any, n_max: int | None) -> dict[str, tuple[np.ndarray, np.ndarray, float]]:
    """Each filter's forward azimuth over a recording: ``{name: (t_ns, azimuth, us per gyroscope sample)}``
    (the declination is added later; the peers' own north is magnetic)."""
    from models.marg import MargConfig, MargFilter, merge_streams

    b = rec.batch
    tg = b.gyr_t_ns if n_max is None else b.gyr_t_ns[:n_max]
    out: dict[str, tuple[np.ndarray, np.ndarray, float]] = {}
    t_end = int(tg[-1])
    acc = (b.acc_t_ns[b.acc_t_ns <= t_end], b.acc[b.acc_t_ns <= t_end])
    mag = (b.mag_t_ns[b.mag_t_ns <= t_end], b.mag[b.mag_t_ns <= t_end])
    t, k, v = merge_streams(acc, (tg, b.gyr[: len(tg)]), mag)
    ts = (t - t[0]) * 1e-9
    f = MargFilter(MargConfig())
    f.process(ts[:100], k[:100], v[:100])  # compile outside the timing
    f = MargFilter(MargConfig())
    c0 = time.perf_counter()
    q = f.process(ts, k, v)
    us = (time.perf_counter() - c0) / len(tg) * 1e6
    g = k == 1
    out["marg"] = (t[g], _forward_azimuth(q[g]), us)
    a_g = _zoh(acc[0], acc[1], tg)
    m_g = _zoh(mag[0], mag[1], tg)
    w_g = b.gyr[: len(tg)]
    dt = np.diff(tg, prepend=tg[0] - int(np.median(np.diff(tg)))) * 1e-9
    from ahrs.filters import Madgwick

    mad = Madgwick(frequency=1.0 / float(np.median(dt)))
    qm = np.zeros((len(tg), 4))
    qc = np.array([1.0, 0.0, 0.0, 0.0])
    c0 = time.perf_counter()
    for i in range(len(tg)):
        mad.Dt = float(dt[i])
        qc = mad.updateMARG(qc, w_g[i], a_g[i], m_g[i])
        qm[i] = qc
    out["ahrs_madgwick"] = (tg, _forward_azimuth(qm), (time.perf_counter() - c0) / len(tg) * 1e6)
    try:
        import imufusion
    except ImportError:
        return out
    s = imufusion.AhrsSettings()
    s.convention = imufusion.CONVENTION_NED
    s.gain, s.gyroscope_range, s.acceleration_rejection, s.magnetic_rejection = 0.5, 2000, 10, 10
    s.sample_rate = int(round(1.0 / float(np.median(dt))))
    fu = imufusion.Ahrs()
    fu.set_settings(s)
    qf = np.zeros((len(tg), 4))
    w_deg = np.degrees(w_g)
    a_g1 = a_g / 9.80665
    c0 = time.perf_counter()
    for i in range(len(tg)):
        fu.set_sample_period(float(dt[i]))
        fu.update(w_deg[i], a_g1[i], m_g[i])
        qf[i] = fu.get_quaternion()
    out["imufusion"] = (tg, _forward_azimuth(qf), (time.perf_counter() - c0) / len(tg) * 1e6)
    return out


def _heading_errors(recs: list[Any]) -> dict[str, Any]:
    """Landmark errors of the IPIN trials with each filter's heading on the engine's steps."""
    from clients.evaluation.ipin import _declination, landmark_errors, run_phone
    from energy.phone_engine import PhoneEngineConfig

    k0 = PhoneEngineConfig().step_length.weinberg_k
    res: dict[str, list[float]] = {}
    for rec in recs:
        if rec.truth is None or rec.truth.t_ns is None:
            continue
        run = run_phone(rec, "always-on", k0)
        _, decl = _declination(rec)
        T, L = rec.truth.t_ns, rec.truth.positions[:, :2]
        tracks = {"engine": run.ne}
        for name, (t, az, _) in _peers(rec, None).items():
            head = np.interp(run.t_ns.astype(float), t.astype(float), np.unwrap(az)) + decl
            tracks[name] = np.cumsum(np.column_stack([run.step_m * np.cos(head), run.step_m * np.sin(head)]), axis=0)
        ahrs = rec.aux.get("ahrs")
        if ahrs is not None:
            q = np.asarray(ahrs["quat_xyz"], dtype=float)
            w = np.sqrt(np.clip(1.0 - np.sum(q * q, axis=1), 0.0, 1.0))
            xe, xn = 1 - 2 * (q[:, 1] ** 2 + q[:, 2] ** 2), 2 * (q[:, 0] * q[:, 1] + w * q[:, 2])
            az = np.arctan2(-xn, xe)
            head = np.interp(run.t_ns.astype(float), np.asarray(ahrs["t_ns"], dtype=float), np.unwrap(az)) + decl
            tracks["android_rotation_vector"] = np.cumsum(np.column_stack([run.step_m * np.cos(head),
                                                                           run.step_m * np.sin(head)]), axis=0)
        for name, ne in tracks.items():
            res.setdefault(name, []).append(landmark_errors(T, L, run.t_ns, ne, run.step_m).mean_err_m)
    return {name: {"median_mean_err_m": float(np.median(v)), "mean_err_m": [round(x, 3) for x in v]} for name, v in res.items()}


def _compute_costs(recs: list[Any], repeat: int) -> dict[str, Any]:
    """Per cost class: CPU [us] per accelerometer sample inside PhoneEngine.feed (energy-aware replay, 1-s batches),
    least of ``repeat`` per batch."""
    from energy.device import DeviceEmulator
    from energy.phone_engine import PhoneEngine
    from energy.power import cost_class

    cpu: dict[str, float] = {}
    samples: dict[str, int] = {}
    batches: dict[str, int] = {}
    for rec in recs:
        best: list[float] | None = None
        classes: list[str] = []
        n_acc: list[int] = []
        for _ in range(max(1, repeat) + 1):
            eng = PhoneEngine("auto")
            dev = DeviceEmulator(rec.batch)
            t0, t_end = int(rec.batch.t_start_ns), int(rec.batch.t_end_ns)
            times, cls, na = [], [], []
            behaviour = "stand"
            while t0 <= t_end:
                cfg = eng.sensor_config
                b = dev.emit(t0, min(t0 + 1_000_000_000, t_end + 1), cfg)
                c0 = time.thread_time()
                u = eng.feed(b)
                times.append(time.thread_time() - c0)
                cls.append(cost_class(cfg.gyro_on, behaviour))
                na.append(len(b.acc_t_ns))
                behaviour = u.behaviour
                t0 += 1_000_000_000
            best = times if best is None else [min(a, c) for a, c in zip(best, times)]
            classes, n_acc = cls, na
        assert best is not None
        for c, t, n in zip(classes, best, n_acc):
            cpu[c] = cpu.get(c, 0.0) + t * 1e6
            samples[c] = samples.get(c, 0) + n
            batches[c] = batches.get(c, 0) + 1
    per = {c: round(cpu[c] / samples[c], 4) for c in cpu if samples[c]}
    return {"us_per_sample": per, "us_per_batch": {c: 0.0 for c in per},
            "measured_on": {c: {"batches": batches[c], "samples": samples[c], "cpu_us": round(cpu[c], 1)} for c in cpu}}


def _write_costs(costs: dict[str, Any], data: str) -> str:
    from importlib import resources

    path = Path(str(resources.files("energy") / "profiles" / "compute_costs.json"))
    d = json.loads(path.read_text())
    d.setdefault("engines", {})["phone"] = {
        **costs,
        "measured": {"date": time.strftime("%Y-%m-%d"), "machine": f"{platform.machine()} {platform.platform()}, "
                     f"python {platform.python_version()}", "command": "pednav bench phone --write-costs", "data": data,
                     "note": "step-and-heading engine (PhoneEngine auto, 1-s batches): thread CPU inside feed per "
                             "accelerometer sample and cost class, least of the repeats per batch; per-batch and "
                             "per-step costs folded in"},
    }
    path.write_text(json.dumps(d, indent=2) + "\n")
    return str(path)


def run(args: argparse.Namespace) -> dict[str, Any]:
    from energy.engine import Engine
    from energy.phone_engine import PhoneEngine

    data, recs = _phone_recordings(args.trials)
    foot_name, foot = _foot_batch()
    phone_batches = recs[0].batch.split_seconds(1.0)
    on_us, on_n = _cpu_per_position(lambda: PhoneEngine("always-on"), phone_batches, args.repeat)
    auto_us, auto_n = _cpu_per_position(lambda: PhoneEngine("auto"), phone_batches, args.repeat)
    zupt_us, zupt_n = _cpu_per_position(lambda: Engine(mode="zupt"), foot.split_seconds(1.0), args.repeat)
    speed = _peers(recs[0], args.peer_samples)
    out: dict[str, Any] = {
        "data": f"{data}/{recs[0].name}", "foot_data": foot_name,
        "phone_always_on_us_per_step": round(on_us, 2), "phone_auto_us_per_step": round(auto_us, 2),
        "zupt_us_per_step": round(zupt_us, 2), "phone_steps": on_n, "zupt_positions": zupt_n,
        "phone_vs_zupt_per_step": round(on_us / zupt_us, 3),
        "marg_us_per_gyro_sample": round(speed["marg"][2], 3),
        "peer_madgwick_marg_us_per_sample": round(speed["ahrs_madgwick"][2], 3),
        "marg_speedup_vs_madgwick": round(speed["ahrs_madgwick"][2] / speed["marg"][2], 2),
    }
    if "imufusion" in speed:
        out["peer_imufusion_us_per_sample"] = round(speed["imufusion"][2], 3)
        out["marg_speed_vs_imufusion"] = round(speed["imufusion"][2] / speed["marg"][2], 3)
    if recs[0].truth is not None and data.startswith("ipin"):
        out["heading_accuracy"] = _heading_errors(recs)
    costs = _compute_costs(recs[:2], args.repeat)
    out["compute_costs"] = costs
    if args.write_costs:
        out["compute_costs_written"] = _write_costs(costs, data)
    return out
