"""``pednav bench speed|engine|load|state|phone``: benchmarks that prove speed and capacity targets (never timed unit tests)."""

from __future__ import annotations

import argparse
import importlib
import json

__all__ = ["register"]


def _run(args: argparse.Namespace) -> int:
    module = importlib.import_module(f"clients.benchmarks.{args.bench}")
    result = module.run(args)
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        width = max(len(k) for k in result) if result else 0
        for k, v in result.items():
            print(f"{k:<{width}}  {v}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="benchmarks (speed vs a peer measured in the same run; server load)")
    bsub = p.add_subparsers(dest="bench", metavar="BENCH", required=True)
    for name, help_text in (
        ("speed", "per-sample cost of each engine mode on real data vs ahrs Madgwick updateIMU"),
        ("engine", "CPU per batch of the server's engine helper (restore, feed, serialise) on real data"),
        ("load", "many simulated devices against one server worker: latency percentiles, lost batches"),
        ("state", "engine state size and CPU per batch against the time a person stands"),
        ("coldstart", "a fresh install's first upload, readiness and first accepted batch (empty numba cache)"),
        ("jobs", "re-processing stored sessions through the job engine (Dramatiq, Dask) with 1, 2, 4 workers"),
        ("phone", "step-and-heading engine: CPU per step vs the ZUPT-KF's, its MARG filter vs ahrs Madgwick and "
                  "imufusion (speed and heading accuracy on the IPIN trials), its compute costs per cost class"),
    ):
        try:
            module = importlib.import_module(f"clients.benchmarks.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"clients.benchmarks.{name}":
                raise
            continue
        bp = bsub.add_parser(name, help=help_text)
        bp.add_argument("--json", action="store_true", help="print one JSON document")
        module.add_arguments(bp)
        bp.set_defaults(func=_run)
