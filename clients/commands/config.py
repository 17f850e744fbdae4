"""``pednav config``: the engine's configuration tree, every setting with its value, unit and rationale."""

from __future__ import annotations

import argparse
import json
import sys

__all__ = ["register"]


def _run(args: argparse.Namespace) -> int:
    from energy.config import EngineConfig, config_markdown, config_table

    try:
        cfg = EngineConfig().override(dict(_pair(s) for s in args.set or []))
    except (ValueError, TypeError) as exc:
        print(f"pednav config: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(cfg.to_dict(), indent=2))
    elif args.markdown:
        sys.stdout.write(config_markdown(cfg))
    else:
        rows = config_table(cfg)
        width = max(len(r[0]) for r in rows)
        for path, value, unit, _ in rows:
            print(f"{path:<{width}}  {value:>12}  {unit}")
    return 0


def _pair(item: str) -> tuple[str, object]:
    key, sep, raw = item.partition("=")
    if not sep:
        raise ValueError(f"--set {item!r}: expected SECTION.FIELD=VALUE")
    try:
        return key, json.loads(raw)
    except json.JSONDecodeError:
        return key, raw


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("config", help="the engine's settings: value, unit and why (one configuration for all)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--json", action="store_true", help="the tree as JSON (what `--set` paths address)")
    g.add_argument("--markdown", action="store_true", help="the table with rationale (docs/engine.md)")
    p.add_argument("--set", action="append", default=None, metavar="SECTION.FIELD=VALUE",
                   help="show the tree with this change (validated: a bad value is refused by name)")
    p.set_defaults(func=_run)
