"""``pednav bench state``: the measurement runs and reports what the stand-state tests bound."""

from __future__ import annotations

import json

from clients.benchmarks.state import measure
from clients.cli import main


def test_state_after_a_minute_of_standing_is_reported_per_part() -> None:
    r = measure("pdr", None, 1.2)
    one = r["marks"]["1"]
    assert one["bytes"] < 40_000  # 47 kB after one minute before the segmenter collapsed long stances
    assert one["parts"]["gait.seg.buf"] < 5_000  # the segmenter's sample buffer: 24.5 kB then
    assert r["cpu"]["stand_first_min"]["batches"] > 10


def test_cli_prints_one_json_document(capsys) -> None:
    assert main(["bench", "state", "--json", "--mode", "zupt", "--stand-min", "0.5", "--batch", "1"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["mode"] == "zupt" and doc["batch_s"] == 1.0 and doc["peak_bytes"] > 0
