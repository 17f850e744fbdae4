"""Helpers of the load benchmark (``pednav bench load``): Server-Timing parsing and the per-window tail; the engine
benchmark's output (``pednav bench engine``)."""

from __future__ import annotations

import numpy as np
import pytest

from clients.benchmarks.load import _by_window, _server_timing


def test_server_timing_parses_phases_and_skips_malformed_parts() -> None:
    assert _server_timing("queue;dur=0.12, engine;dur=3.5,write;dur=1") == {"queue": 0.12, "engine": 3.5, "write": 1.0}
    assert _server_timing("") == {}
    assert _server_timing("x;dur=abc, y;dur=2") == {"y": 2.0}


def test_by_window_gives_the_p99_of_the_requests_sent_in_each_window() -> None:
    sent = np.array([0.5, 1.0, 9.9, 10.0, 15.0, 31.0])
    lat = np.array([10.0, 20.0, 30.0, 500.0, 40.0, 7.0])
    # windows [0,10): 10, 20, 30; [10,20): 500, 40; [20,30): none (skipped); [30,40): 7
    got = _by_window(sent, lat, 10.0)
    assert got == [round(float(np.percentile([10.0, 20.0, 30.0], 99)), 1),
                   round(float(np.percentile([500.0, 40.0], 99)), 1), 7.0]
    assert _by_window(np.array([]), np.array([]), 10.0) == []


def test_engine_bench_sessions_start_apart_and_keep_time_increasing_over_the_loop() -> None:
    """``pednav bench engine``: session i starts 7 i s into the recording; looping it shifts time forward."""
    from clients.benchmarks.engine import _session_batches
    from models.batch import SensorBatch

    t = np.arange(0, 5_000_000_000, 10_000_000, dtype=np.int64)  # 5 s at 100 Hz
    rec = SensorBatch(acc_t_ns=t, acc=np.tile([0.0, 0.0, 9.81], (t.size, 1)))
    sess = _session_batches(rec, sessions=3, batches=8)
    assert [len(s) for s in sess] == [8, 8, 8]
    firsts = [int(s[0]["acc_t_ns"][0]) for s in sess]
    assert firsts == [0, 2_000_000_000, 4_000_000_000]  # 7 i mod 5 s
    for s in sess:
        ts = np.concatenate([b["acc_t_ns"] for b in s])
        assert np.all(np.diff(ts) > 0) and ts.size == 8 * 100


@pytest.mark.parametrize("period", [1.0, 2.0])
def test_load_bench_bounded_run_loses_and_duplicates_nothing(period: float) -> None:
    """CI's bounded version of ``pednav bench load`` (the full sweep: ``pednav bench load --sweep``): a real server
    with its engine helper, 5 devices for 4 s on SQLite, one batch every ``period`` s; every batch acknowledged,
    stored once, each holding ``period`` s of samples."""
    import argparse

    from clients.benchmarks.load import run

    args = argparse.Namespace(devices=5, seconds=4.0, rate_hz=100.0, batch_seconds=period, database_url=None,
                              encoding="msgpack", workers=1, sweep=False)
    r = run(args)
    n = 5 * round(4 / period)
    assert r["requests_sent"] == n and r["acked"] == n and r["stored"] == n
    assert r["lost_batches"] == 0 and r["duplicated_batches"] == 0 and r["other_statuses"] == {}
    assert r["batch_seconds"] == period
    # the body holds the period's samples (msgpack, <f4 values: 3 streams x 3 values x 4 bytes per sample)
    assert 36 * 100 * period <= r["body_bytes"] < 2 * 36 * 100 * period


@pytest.mark.parametrize("text", ["0", "-1", "61", "nan"])
def test_load_bench_refuses_a_period_that_is_not_one_naming_the_option(text: str,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    from clients.cli import main

    with pytest.raises(SystemExit) as e:
        main(["bench", "load", "--batch-seconds", text])
    assert e.value.code == 2
    assert "--batch-seconds" in capsys.readouterr().err


def test_thread_cpu_reads_this_process_main_thread() -> None:
    """The event-loop share of the worker's CPU (``server_worker_event_loop``) is its main thread's own counter:
    it grows while the main thread computes and stays below the whole process's CPU time."""
    import os
    import time

    from clients.benchmarks.load import _thread_cpu

    t0 = _thread_cpu(os.getpid())
    end = time.process_time() + 0.3
    while time.process_time() < end:  # ~0.3 s of this (main) thread's CPU
        pass
    t1 = _thread_cpu(os.getpid())
    assert 0.15 <= t1 - t0 <= 1.0
    assert t1 <= time.process_time() + 0.05


def test_engine_bench_gives_every_path_in_peer_samples(capsys: pytest.CaptureFixture[str]) -> None:
    """``pednav bench engine --json``: each path's CPU per batch also in samples of the Madgwick peer measured in the
    same run (the figure that cancels the machine's speed), consistent with the absolute one; a tiny run (the
    gdin walk when the data is there, else the synthetic walk)."""
    import json

    from clients.cli import main

    code = main(["bench", "engine", "--json", "--modes", "auto", "--sessions", "2", "--batches", "3",
                 "--server-sessions", "2", "--peer-samples", "200"])
    assert code == 0
    doc = json.loads(capsys.readouterr().out)
    peer = doc["peer_madgwick_us_per_sample"]
    assert peer > 0
    paths = doc["modes"]["auto"]
    for k in ("helper_cached", "helper_restore", "server_cached", "server_restore"):
        p = paths[k]
        assert p["cpu_ms_per_batch"] > 0
        assert p["cpu_in_peer_samples"] == round(1e3 * p["cpu_ms_per_batch"] / peer, 1)
