"""Where the development recordings are: ``PEDNAV_DATA`` or ``../shared/datasets`` from the project root."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["data_root", "dataset_dir"]

_PROJECT_ROOT = Path(__file__).resolve().parent.parent


def data_root() -> Path | None:
    """The datasets folder, or ``None`` when it is absent (callers skip with a reason)."""
    env = os.environ.get("PEDNAV_DATA")
    candidates = [Path(env)] if env else [_PROJECT_ROOT.parent / "shared" / "datasets", Path.cwd().parent / "shared" / "datasets"]
    for c in candidates:
        if c.is_dir():
            return c
    return None


def dataset_dir(name: str) -> Path | None:
    """``data_root()/name`` when it exists (e.g. ``"vicon"``, ``"gdin"``), else ``None``."""
    root = data_root()
    if root is None:
        return None
    d = root / name
    return d if d.is_dir() else None
