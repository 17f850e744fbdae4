"""Numba kernels are cached, and their first compilation is announced (the first demo does not look hung)."""

from __future__ import annotations

import ast
import io
from pathlib import Path

import numpy as np

from clients.warmup import CompileWatch, warm_up

ROOT = Path(__file__).resolve().parents[2]


def _name(node: ast.AST) -> str:
    return node.id if isinstance(node, ast.Name) else node.attr if isinstance(node, ast.Attribute) else ""


def _uncached_jits(root: Path = ROOT) -> list[str]:
    """Every numba ``njit``/``jit`` in the packages that is not ``cache=True``: bare decorators, and calls
    (``@njit(...)``, ``njit(...)(f)``) without ``cache=True``."""
    bad = []
    for pkg in ("models", "energy", "server", "clients"):
        for path in sorted((root / pkg).rglob("*.py")):
            tree = ast.parse(path.read_text(), str(path))
            for node in ast.walk(tree):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    bad += [f"{path.relative_to(root)}:{d.lineno} bare @{_name(d)}" for d in node.decorator_list
                            if _name(d) in ("njit", "jit")]
                elif isinstance(node, ast.Call) and _name(node.func) in ("njit", "jit"):
                    if not any(k.arg == "cache" and isinstance(k.value, ast.Constant) and k.value.value is True
                               for k in node.keywords):
                        bad.append(f"{path.relative_to(root)}:{node.lineno} {_name(node.func)}(...) without cache=True")
    return bad


def test_every_numba_kernel_is_cached() -> None:
    assert _uncached_jits() == []


def test_the_check_finds_an_uncached_kernel(tmp_path: Path) -> None:
    pkg = tmp_path / "models"
    pkg.mkdir()
    (pkg / "k.py").write_text("from numba import njit\n\n@njit\ndef f(x):\n    return x\n\n\n@njit(cache=False)\n"
                              "def g(x):\n    return x\n\n\nh = njit(cache=True)(f)\n")
    assert len(_uncached_jits(tmp_path)) == 2


def test_compile_watch_counts_cache_misses_only() -> None:
    from numba import njit

    @njit(cache=False)
    def twice(x):  # type: ignore[no-untyped-def]
        return 2 * x

    with CompileWatch() as w:
        twice(np.float64(1.0))
        first = w.compiled
        twice(np.float64(2.0))
    assert first == 1 and w.compiled == 1 and w.names[0].endswith("twice")


def test_warm_up_says_what_it_did() -> None:
    from clients.synth import synthesize

    rec = synthesize("walk", seed=0)
    out = io.StringIO()
    res = warm_up([rec.batch.time_slice(None, int(rec.batch.t_start_ns) + 20 * 10**9)], show=True, out=out)
    text = out.getvalue()
    assert res.seconds > 0 and ("loaded from the cache" in text or ("first run: compiling" in text and res.compiled > 0))
