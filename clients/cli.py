"""The ``pednav`` command line. Each sub-command lives in its own module under ``clients.commands``.

A command module exposes ``register(subparsers) -> None``, which adds its parser and sets
``func=callable(args) -> int``. Heavy imports happen inside the callables so ``--help`` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

__all__ = ["main", "build_parser"]

# Order = order in --help.
COMMAND_MODULES: tuple[str, ...] = (
    "clients.commands.demo",
    "clients.commands.eval",
    "clients.commands.bench",
    "clients.commands.energy",
    "clients.commands.serve",
    "clients.commands.admin",
    "clients.commands.replay",
    "clients.commands.export",
    "clients.commands.config",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pednav",
        description="Energy-aware pedestrian navigation: evaluation, benchmarks, energy simulation, server.",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:  # command not written yet
                continue
            raise
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    return int(args.func(args) or 0)


if __name__ == "__main__":
    raise SystemExit(main())
