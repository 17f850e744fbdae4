"""Test helper: the batches a device obeying an engine actually sent (gyro gaps, rate changes)."""

from __future__ import annotations

from typing import Any

from energy.config import EngineConfig
from energy.device import replay
from energy.engine import Engine
from models.batch import SensorBatch

__all__ = ["replayed_batches"]


def replayed_batches(rec: Any, config: EngineConfig, profile: dict | None = None,
                     batch_seconds: float | None = 1.0) -> list[SensorBatch]:
    """Replay ``rec`` (a synthesised recording) through an auto-mode engine in ``batch_seconds`` uploads (None:
    as long as the engine asks) and return every batch the device sent, in order; re-feeding them elsewhere
    reproduces what the engine saw."""
    sent: list[SensorBatch] = []
    eng = Engine(mode="auto", config=config, profile=profile)
    orig = eng.feed

    def feed(batch: SensorBatch):  # noqa: ANN202
        sent.append(batch)
        return orig(batch)

    eng.feed = feed  # type: ignore[method-assign]
    replay(eng, rec.batch, batch_seconds=batch_seconds)
    return sent
