"""``pednav bench speed``: the paired cost ratio is what its pairs say (no timing is asserted: speed figures
come from the benchmark, as ratios against a peer measured in the same run)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from clients.benchmarks.speed import _paired_ratio
from clients.cli import main


def test_paired_ratio_alternates_order_and_divides_each_pair() -> None:
    calls: list[str] = []
    out = _paired_ratio(lambda: calls.append("a"), lambda: calls.append("b"), 4)
    assert calls == ["a", "b", "b", "a", "a", "b", "b", "a"]
    assert len(out) == 4 and all(r > 0 for r in out)


def test_cli_reports_the_paired_ratio_with_its_pairs(capsys, monkeypatch) -> None:
    pytest.importorskip("imufusion")
    monkeypatch.delenv("PEDNAV_DATA", raising=False)  # the synthetic recording: quick
    assert main(["bench", "speed", "--json", "--repeat", "1", "--pairs", "3", "--peer-samples", "200"]) == 0
    doc = json.loads(capsys.readouterr().out)
    pairs = doc["zupt_cost_vs_imufusion_pairs"]
    assert len(pairs) == 3
    assert doc["zupt_cost_vs_imufusion_paired"] == pytest.approx(float(np.median(pairs)), abs=0.01)
