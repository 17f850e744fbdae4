"""The heading and scheduling core stays readable: small, and no function of it too branched."""

from __future__ import annotations

from pathlib import Path

import pytest

radon = pytest.importorskip("radon.complexity", reason="radon (test extra) measures cyclomatic complexity")

ROOT = Path(__file__).resolve().parents[1]
CORE = ("energy/engine.py", "energy/gait_dr.py", "energy/scheduler.py", "models/compass.py", "models/heading.py")
MAX_COMPLEXITY = 25
CORE_LINES_BEFORE = 4045  # engine, gait_dr, compass, scheduler before the heading estimator replaced the rules


def _functions(path: Path):
    text = path.read_text(encoding="utf-8")
    jitted = {line.split("def ", 1)[1].split("(", 1)[0]
              for prev, line in zip(text.splitlines(), text.splitlines()[1:])
              if prev.strip().startswith("@njit") and line.lstrip().startswith("def ")}
    for block in radon.cc_visit(text):
        for f in [block, *getattr(block, "methods", [])]:
            if getattr(f, "is_method", None) is not None or not hasattr(f, "methods"):
                if f.name not in jitted:
                    yield f


@pytest.mark.parametrize("rel", CORE)
def test_no_core_function_is_too_branched(rel: str) -> None:
    worst = [(f.name, f.complexity) for f in _functions(ROOT / rel) if f.complexity > MAX_COMPLEXITY]
    assert not worst, worst


def test_the_core_is_smaller_than_the_rules_it_replaced() -> None:
    lines = sum(len((ROOT / rel).read_text(encoding="utf-8").splitlines()) for rel in CORE)
    assert lines < CORE_LINES_BEFORE, lines
