"""The soak harness's own parts (tests/support/soak.py): memory readings and the verdict.

The soak itself is 30 minutes (``make soak``), out of the default suite and of ``.ci/run``;
here its readings of /proc and its judgement are held to what they claim, on this process
and on made-up runs.
"""

from __future__ import annotations

import subprocess
import sys

import pytest

from tests.support.soak import RSS_GROWTH_LIMIT_MB, Sample, SoakRun, children, rss_kb, tlog_bytes, verdict


def test_that_resident_memory_and_children_are_read_from_proc_and_none_once_gone():
    child = subprocess.Popen([sys.executable, "-c", "import time; b = bytearray(64 << 20); time.sleep(30)"])
    try:
        import time
        for _ in range(100):     # until the child holds its 64 MB
            if (rss_kb(child.pid) or 0) > 60_000:
                break
            time.sleep(0.05)
        assert rss_kb(child.pid) > 60_000
        import os
        assert child.pid in children(os.getpid())
    finally:
        child.kill()
        child.wait(timeout=10)
    assert rss_kb(child.pid) is None and children(child.pid) == []


def test_that_the_tlog_size_counts_its_segments(tmp_path):
    (tmp_path / "patrol.tlog").write_bytes(b"x" * 100)
    (tmp_path / "patrol.0003.tlog").write_bytes(b"x" * 50)
    (tmp_path / "other.tlog").write_bytes(b"x" * 7)
    assert tlog_bytes(tmp_path / "patrol.tlog") == 150
    assert tlog_bytes(tmp_path / "absent" / "patrol.tlog") == 0


def _run(stream_growth_kb: int = 1000, gap_ms: float = 60.0, collided: bool = False, code: int = 3) -> SoakRun:
    """A 30 min soak sampled every minute, the stream growing ``stream_growth_kb`` after 5 min."""
    samples = [Sample(60.0 * k, 200_000 + (stream_growth_kb * max(0, k - 5)) // 25, 130_000, 1000 * k)
               for k in range(31)]
    report = {"outcome": "stopped" if code == 3 else "goal reached", "setpoint_gap_max_ms": gap_ms,
              "old_plan_events": 0, "planner_process": {"max_solve_ms": 120.0}, "replans": 5900,
              "mission_items_reached_count": 170, "mission_jumps_taken": 42, "tlog_bytes": 39_000_000}
    return SoakRun(30.0, samples, report, code, {"collided": collided, "min_distance_m": {"a": 1.7}},
                   {"patrol.tlog": 2_500_000, "patrol.0015.tlog": 2_400_000})


def test_that_a_clean_soak_passes_with_its_figures():
    figures, failed = verdict(_run(), tlog_max_bytes=20_000_000)
    assert failed == []
    assert figures["stream_rss_mb_at_5_min"] == pytest.approx(204.8)
    assert figures["stream_rss_growth_mb"] == pytest.approx(1.02, abs=0.01)
    assert figures["planner_rss_growth_mb"] == 0.0
    assert figures["tlog_mb"] == 4.9 and figures["tlog_written_mb"] == 39.0 and figures["laps"] == 42


@pytest.mark.parametrize("run, words", [
    (_run(stream_growth_kb=int(RSS_GROWTH_LIMIT_MB * 1000)), "stream process: resident memory grew 5.1 MB"),
    (_run(gap_ms=151.0), "largest setpoint gap 151.0 ms"),
    (_run(collided=True), "collided = True"),
    (_run(code=0), "fly ended with exit 0"),
])
def test_that_each_broken_promise_fails_the_soak_naming_it(run, words):
    _, failed = verdict(run, tlog_max_bytes=20_000_000)
    assert len(failed) == 1 and words in failed[0], failed


def test_that_a_tlog_over_its_bound_and_missing_samples_fail():
    run = _run()
    run.samples = run.samples[:3]                 # the stream died before the warm-up ended
    _, failed = verdict(run, tlog_max_bytes=4_000_000)
    assert any("no resident-memory sample at 5 min" in f for f in failed)
    assert any("tlog 4900000 bytes on disk (bound 4000000)" in f for f in failed)
