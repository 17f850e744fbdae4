"""``pednav energy simulate``: duty-cycle simulation of a mixed day, scheduler vs always-on baseline."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

__all__ = ["register"]

PREVIOUS_DAY_SEED_OFFSET = 1000  # --user returning: the profile comes from the same scenario with seed + this


def _simulate(args: argparse.Namespace) -> int:
    from clients.synth import IMU_ERRORS, synthesize
    from energy.power import load_profile
    from energy.simulate import learn_profile, measure_compute_costs, simulate

    if args.measure_costs:
        # each engine uploads as it does in the simulated day (or in fixed batches with --batch-seconds)
        costs = measure_compute_costs(synthesize("mixed-day", seed=0).batch, repeats=max(args.repeats, 1),
                                      batch_seconds=args.batch_seconds)
        out = Path(__file__).resolve().parent.parent.parent / "energy" / "profiles" / "compute_costs.json"
        out.write_text(json.dumps(costs, indent=2) + "\n")
        print(f"wrote {out}", file=sys.stderr)
    from clients.commands.eval import _settings
    from energy.config import EngineConfig

    try:
        config = EngineConfig.default().override(_settings(args.set))
    except (ValueError, TypeError) as exc:
        print(f"pednav energy simulate: --set: {exc}", file=sys.stderr)
        return 2
    profile = load_profile(args.profile)
    errors = IMU_ERRORS[args.imu_errors]
    check_scenario(args.scenario)
    rec = synthesize(args.scenario, seed=args.seed, errors=errors)
    truth = rec.truth
    assert truth is not None and truth.t_ns is not None and truth.positions is not None
    doc: dict = {"scenario": args.scenario, "seed": args.seed, "user": args.user, "imu_errors": args.imu_errors,
                 "settings": config.changes()}
    user_profile = None
    if args.user == "returning":
        # An earlier day of the same synthetic person (another seed: other strides, noise and field), not this
        # day's data: the profile the scheduler handed out at the end of that session.
        prev_seed = args.seed + PREVIOUS_DAY_SEED_OFFSET
        user_profile = learn_profile(synthesize(args.scenario, seed=prev_seed, errors=errors).batch, args.batch_seconds,
                                     config)
        doc["user_profile_from"] = {"scenario": args.scenario, "seed": prev_seed, "calibrated": sorted(
            b for b, c in user_profile.get("behaviours", {}).items() if c.get("calibrated"))}
    doc["batching"] = (f"fixed {args.batch_seconds} s" if args.batch_seconds else
                       "as the engine's SensorConfig.batch_s says (the baseline's is 1 s)")
    doc["radio_bytes"] = "SDK msgpack upload body, float32 values (clients.sdk.encode_batch), one request per batch"
    doc.update(
        simulate(
            profile, rec.batch, truth.t_ns, truth.positions, len(truth.extra["step_t_s"]), args.batch_seconds,
            measure=not args.stored_costs, encode=_upload_bytes, repeats=args.repeats, user_profile=user_profile,
            config=config,
        )
    )
    if args.plot:
        _plot(args.plot, rec, args.batch_seconds, user_profile)
    if args.json:
        print(json.dumps(doc, indent=2))
        return 0
    rows = [("", "scheduler", "baseline")]
    for k in ("acc", "gyr", "mag", "sensors", "compute", "radio", "total"):
        rows.append((f"{k} [mJ]", f"{doc['scheduler']['energy_mj'][k]:.1f}", f"{doc['baseline']['energy_mj'][k]:.1f}"))
    rows.append(("gyro on fraction", f"{doc['scheduler']['gyro_on_fraction']:.3f}", f"{doc['baseline']['gyro_on_fraction']:.3f}"))
    rows.append(("mean acc rate [Hz]", f"{doc['scheduler']['mean_rate_hz']:.1f}", f"{doc['baseline']['mean_rate_hz']:.1f}"))
    rows.append(
        ("mean position error [m]", f"{doc['position_error_m']['scheduler']:.2f}", f"{doc['position_error_m']['baseline']:.2f}")
    )
    for mode, name in (("zupt", "ZUPT-KF"), ("pdr", "Gait-DR")):
        cells = [doc[run]["step_errors"].get(mode) for run in ("scheduler", "baseline")]
        rows.append((f"{name} step dir err [deg]", *(f"{c['direction_err_deg']:.2f}" if c else "-" for c in cells)))
        rows.append((f"{name} step len err [%]", *(f"{c['length_err_pct']:.2f}" if c else "-" for c in cells)))
    print(f"{args.scenario} (seed {args.seed}, {doc['duration_s']:.0f} s, {doc['truth_steps']} strides), {args.user} user, profile {profile.name}, "
          f"IMU errors {args.imu_errors}")
    for r in rows:
        print(f"{r[0]:<26}{r[1]:>12}{r[2]:>12}")
    print(f"energy ratio {doc['energy_ratio']:.3f}   compute reduction {doc['compute_reduction_pct']:.1f} %   "
          f"error ratio {doc['position_error_m']['ratio']:.2f}")
    m = doc["mode_cost_per_step_us"]
    print(f"per step: Gait-DR {m['gait_dr']:.0f} us vs ZUPT-KF at 200 Hz {m['zupt_kf_200hz']:.0f} us "
          f"({m['reduction_pct']:.1f} % less), {doc['scheduler']['compute_source']}")
    print("scheduler energy by class [mJ]:")
    for k, d in sorted(doc["scheduler"]["energy_by_class_mj"].items()):
        print(f"  {k:<6} {d['time_s']:7.1f} s  acc {d['acc']:7.1f}  gyr {d['gyr']:8.1f}  mag {d['mag']:6.1f}  "
              f"compute {d['compute']:7.1f}  radio {d['radio']:6.1f}  total {d['total']:8.1f}")
    for run in ("scheduler", "baseline"):
        comp = doc[run]["compute_us_by_component"]
        if comp:
            tot = sum(sum(v.values()) for v in comp.values()) or 1.0
            parts = sorted(((sum(v.values()), c) for c, v in comp.items()), reverse=True)
            print(f"{run} CPU by component: " + ", ".join(f"{c} {100 * x / tot:.0f} %" for x, c in parts))
    return 0


def _upload_bytes(batch: object) -> int:
    """Bytes of one upload as the SDK sends it (msgpack body, float32 values)."""
    from clients.sdk import encode_batch

    return len(encode_batch(batch, "msgpack", "<f4")[0])  # type: ignore[arg-type]


def _plot(path: str, rec: object, batch_seconds: float | None, user_profile: dict | None) -> None:
    """Mode / behaviour / gyroscope timelines of the scheduler on the scenario (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from energy.device import replay
    from energy.engine import Engine

    eng = Engine(mode="auto", profile=user_profile, trace=True)
    res = replay(eng, rec.batch, batch_seconds=batch_seconds)  # type: ignore[attr-defined]
    tr = res.trace
    t_origin = int(rec.batch.t_start_ns)  # type: ignore[attr-defined]
    t = (tr.t_ns - t_origin) / 1e9
    truth_b = rec.truth.extra["behaviour"]  # type: ignore[attr-defined]
    tt = (rec.truth.t_ns - t_origin) / 1e9  # type: ignore[attr-defined]
    # the sensors as the device ran them (a wake-on-motion gyroscope starts within a batch)
    spans = [s for batch in res.spans for s in batch]
    tg = np.array([(s[0] - t_origin) / 1e9 for s in spans])
    gyro_on = np.array([float(s[3] > 0) for s in spans])
    acc_rate = np.array([s[2] for s in spans])
    cats = ["stand", "walk", "run", "other"]
    fig, ax = plt.subplots(4, 1, figsize=(11, 7), sharex=True)
    ax[0].plot(tt, [cats.index(b) for b in truth_b], "k-", lw=1, label="truth")
    ax[0].plot(t, [cats.index(str(b)) if str(b) in cats else -1 for b in tr.behaviour], "r.", ms=1, label="recognised")
    ax[0].set_yticks(range(4), cats)
    ax[0].legend(loc="upper right")
    modes = ["idle", "pdr", "zupt"]
    ax[1].plot(t, [modes.index(str(m)) if str(m) in modes else -1 for m in tr.mode], "b.", ms=1)
    ax[1].set_yticks(range(3), modes)
    ax[2].step(tg, gyro_on, "g-", where="post")
    ax[2].set_ylabel("gyro on")
    ax[3].step(tg, acc_rate, "m-", where="post")
    ax[3].set_ylabel("acc rate [Hz]")
    ax[3].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def check_scenario(name: str) -> None:
    """A :class:`clients.errors.UserError` (wrong usage) unless ``name`` is in ``clients.synth.scenario_names()``.
    (Not an argparse type: argparse converts string defaults too, and the check imports the synthesiser.)"""
    from clients.errors import UserError
    from clients.synth import scenario_names

    if name not in scenario_names():
        raise UserError(f"--scenario: unknown scenario {name!r} (known: {', '.join(scenario_names())})", 2)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("energy", help="energy: duty-cycle simulation of a mixed day (scheduler vs always-on)")
    esub = p.add_subparsers(dest="energy_command", metavar="ACTION", required=True)
    s = esub.add_parser("simulate", help="scheduler vs always-on ZUPT-KF baseline on a synthetic scenario")
    s.add_argument("--json", action="store_true", help="print one JSON document")
    s.add_argument("--set", action="append", default=None, metavar="SECTION.FIELD=VALUE",
                   help="change one setting of the scheduler's engine (repeatable; `pednav config` lists them)")
    s.add_argument("--scenario", default="mixed-day", help="synthetic scenario (clients.synth.scenario_names())")
    s.add_argument("--seed", type=int, default=0, help="synthesiser seed")
    s.add_argument(
        "--imu-errors",
        choices=("typical-part", "noise-only", "shoe-iron"),
        default="typical-part",
        help="sensor error model of the synthetic device (clients.synth.IMU_ERRORS): typical-part = white noise, "
        "biases and the scale-factor and cross-axis errors of a typical MEMS part (default); noise-only = white "
        "noise and biases only (an ideally calibrated part); shoe-iron = noise-only plus the magnetometer's "
        "hard and soft iron",
    )
    s.add_argument("--profile", default="foot-004", help="device power profile (energy/profiles/NAME.json) or a path")
    s.add_argument(
        "--batch-seconds",
        type=float,
        default=None,
        help="fixed upload batch duration [s] (default: as long as the engine's sensor configuration says)",
    )
    s.add_argument(
        "--user",
        choices=("new", "returning"),
        default="new",
        help="new: the scheduler initialises every behaviour on this day (default); returning: it starts from the "
        "calibration profile it handed out after an earlier day (same scenario, seed + 1000)",
    )
    s.add_argument("--plot", metavar="PNG", help="write mode/behaviour/gyroscope timelines of the scheduler")
    s.add_argument(
        "--repeats",
        type=int,
        default=3,
        help="replay each engine this many times (interleaved) and charge the least CPU time of each (default 3; "
        "with --measure-costs also the replays per engine of the measurement)",
    )
    s.add_argument(
        "--stored-costs",
        action="store_true",
        help="charge computation from energy/profiles/compute_costs.json (per sample and per batch of each engine; "
        "deterministic) instead of measuring this run",
    )
    s.add_argument(
        "--measure-costs",
        action="store_true",
        help="re-measure the per-mode compute costs (per sample and per batch, each engine batching as in the "
        "simulated day) on this machine and store them in energy/profiles/compute_costs.json",
    )
    s.set_defaults(func=_simulate)
