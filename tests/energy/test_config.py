"""The engine's configuration tree: validated, addressable by path, documented."""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import pytest

from energy.codec import dumps, loads
from energy.config import EngineConfig, config_markdown, config_table
from energy.engine import Engine


@pytest.mark.parametrize("path, value, name", [
    ("scheduler.l0_m", -1.0, "l0_m"),
    ("scheduler.cross_track_pct", 0.0, "cross_track_pct"),
    ("rates.pdr_rate_hz", float("inf"), "pdr_rate_hz"),
    ("step_length.model", "magic", "model"),
    ("heading.p_turn_start", 1.5, "p_turn_start"),
    ("zupt.hysteresis", 0.5, "hysteresis"),
    ("scheduler.nope", 1.0, "nope"),
])
def test_a_bad_value_is_refused_by_name(path: str, value: object, name: str) -> None:
    with pytest.raises(ValueError, match=name):
        EngineConfig().override({path: value})


def test_override_changes_one_value_and_the_tree_round_trips_through_the_engine_state() -> None:
    cfg = EngineConfig().override({"scheduler.cross_track_pct": 12.5, "steps.min_period_s": 0.4})
    assert cfg.scheduler.cross_track_pct == 12.5 and cfg.steps.min_period_s == 0.4
    assert cfg.rates == EngineConfig().rates
    assert EngineConfig.from_dict(loads(dumps(cfg.to_dict()))) == cfg
    eng = Engine(mode="auto", config=cfg)
    assert Engine.from_bytes(eng.to_bytes()).config == cfg


def test_every_setting_has_a_unit_and_a_reason() -> None:
    rows = config_table()
    assert len({r[0] for r in rows}) == len(rows) > 100
    undocumented = [r[0] for r in rows if not r[3] or r[3].startswith("see ") or not r[2]]
    assert not undocumented, undocumented


def test_the_engine_builds_its_parts_from_the_tree() -> None:
    """A changed setting reaches the part that uses it (no part constructed with a default of its own)."""
    cfg = EngineConfig().override({"steps.window_s": 0.2, "compass.min_stances": 21, "deviation.r_obs_rad": 0.1,
                                   "step_length.min_pairs": 11, "heading.turn_sigma_rad": 0.5,
                                   "zupt.zupt_sigma": 0.02})
    eng = Engine(mode="auto", config=cfg)
    gait = eng._gait
    assert gait is not None
    assert gait._seg.window_s == 0.2 and gait.mag.min_stances == 21 and gait.cal.min_pairs == 11
    assert gait.kf2["walk"].r_obs == 0.1 and gait.est.config.turn_sigma_rad == 0.5
    assert eng._nav.config.zupt_sigma == 0.02


def test_docs_engine_md_carries_the_current_table() -> None:
    text = (Path(__file__).resolve().parents[2] / "docs" / "engine.md").read_text(encoding="utf-8")
    block = text.split("<!-- config-table:start -->\n", 1)[1].split("<!-- config-table:end -->", 1)[0]
    assert block == config_markdown(), "regenerate the table: pednav config --markdown"


def test_every_row_of_the_markdown_table_has_four_cells() -> None:
    for line in config_markdown().splitlines():
        assert len(re.split(r"(?<!\\)\|", line)) == 6, line  # four cells between five unescaped bars


def test_the_heading_budget_is_in_percent_of_distance() -> None:
    f = next(f for f in dataclasses.fields(EngineConfig().scheduler) if f.name == "cross_track_pct")
    assert "%" in f.metadata["unit"] and math.isfinite(EngineConfig().scheduler.cross_track_pct)
