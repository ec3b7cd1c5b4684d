"""``make flake-check``'s table and a failing flight test's own explanation (issue 46).

The table is read from real pytest JUnit XML (a small test file run in a subprocess, a few
seconds), so a change of pytest's report that the reader does not follow fails here.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap

from tests.support.flake_check import read_junit, render, stage_argv, tally
from tests.support.flight_summary import flight_line

SUMMARY = {
    "phase": "HELD", "goal_reached_companion_t_s": None, "time_to_goal_s": None, "min_true_goal_distance_m": 1.25,
    "collided": False, "min_true_clearance_m": 0.0018, "min_wall_clearance_m": 0.12, "min_realised_contour": 0.05,
    "setpoint_gap_max_ms": 50.8, "setpoint_gaps_over_150ms": 0, "replans": 103, "failed_plans": 1,
    "setpoint_gap_max_detail": {"cpu_ms": 8.7, "run_queue_wait_ms": 0.0, "longest_step": "tick", "longest_step_ms": 4.2},
    "events": [[0.0, "PRESTREAM: streaming"], [2.25, "ENGAGED: OFFBOARD confirmed by HEARTBEAT"], [15.95, "companion: no valid plan, braking"],
               [16.25, "companion: valid plan again, resuming"], [60.0, "GAVE_UP: duration over"]],
}

FLIGHT_TESTS = textwrap.dedent('''
    import pytest
    from tests.support.flight_summary import record_flight
    SUMMARY = {summary!r}

    def test_flies_well(record_property):
        record_flight(record_property, dict(SUMMARY, min_true_clearance_m=0.4, goal_reached_companion_t_s=30.0), "/tmp/a")

    def test_grazes(record_property):
        record_flight(record_property, SUMMARY, "/tmp/b")
        assert SUMMARY["goal_reached_companion_t_s"] is not None, "never reached the goal"
''').format(summary=SUMMARY)


def _run_pytest(tmp_path, *extra):
    (tmp_path / "test_flights.py").write_text(FLIGHT_TESTS)
    xml = tmp_path / "report.xml"
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "--rootdir", str(tmp_path), "-c", "/dev/null",
         "-p", "tests.conftest", f"--junitxml={xml}", str(tmp_path / "test_flights.py"), *extra],
        capture_output=True, text=True, timeout=60)
    return proc, xml.read_text()


def test_that_the_flight_line_names_outcome_goal_clearances_gap_events_and_the_tlogs():
    line = flight_line(SUMMARY, "/tmp/x/flight")
    for needle in ("outcome HELD", "goal NOT reached", "true clearance 0.002 m", "wall clearance 0.120 m",
                   "largest setpoint gap 50.800 ms (cpu_ms 8.7", "GAVE_UP: duration over", "tlogs kept in /tmp/x/flight",
                   "failed plans 1"):
        assert needle in line, (needle, line)
    assert "PRESTREAM" not in line and "ENGAGED" in line  # the last four events


def test_that_a_failing_flight_test_prints_its_flight_and_the_table_counts_it(tmp_path):
    proc, xml = _run_pytest(tmp_path)
    assert proc.returncode == 1, proc.stdout[-2000:]
    # the CI log carries the flight under the failure, not only the assertion
    assert "the flight" in proc.stdout and "true clearance 0.002 m" in proc.stdout, proc.stdout[-3000:]
    cases = read_junit(xml)
    assert [c["outcome"] for c in cases] == ["passed", "failed"]
    assert cases[0]["true_clearance_m"] == 0.4 and "never reached the goal" in cases[1]["message"]
    table = tally([cases, cases, [dict(cases[1], outcome="passed")]])
    runs = list(table.values())
    assert (runs[0].passes, runs[0].runs) == (2, 2) and (runs[1].passes, runs[1].runs) == (1, 3)
    text = render(table, 3)
    assert "round 1: outcome HELD" in text and "round 2: outcome HELD" in text and "round 3" not in text
    assert text.splitlines()[-1] == "0 of 2 tests passed 3 of 3 rounds"  # 2 of 2 runs is not 3 of 3
    assert "0.002" in text.splitlines()[2] and "0.400" in text.splitlines()[1]


def test_that_a_skipped_run_is_not_counted():
    cases = [{"test": "t", "outcome": "skipped", "seconds": 0.0, "flight": None, "true_clearance_m": None, "message": ""}]
    assert tally([cases]) == {}


def test_that_a_stage_run_narrowed_by_k_selects_within_the_stages_marker(tmp_path):
    argv = stage_argv("quarantine", tmp_path / "r.xml", "clean_stop")
    assert argv[-4:] == ["-m", "quarantine", "-k", "clean_stop"]
    assert "-k" not in stage_argv("realtime", tmp_path / "r.xml")


def test_that_a_failed_round_keeps_its_files_and_says_where(tmp_path):
    """Each stage run's tmp_path lives under --basetemp; a failure's line names it."""
    argv = stage_argv("realtime", tmp_path / "r.xml", basetemp=tmp_path / "round03-realtime-tmp")
    assert f"--basetemp={tmp_path / 'round03-realtime-tmp'}" in argv
    assert not any(a.startswith("--basetemp") for a in stage_argv("realtime", tmp_path / "r.xml"))
    failed = {"test": "t", "outcome": "failed", "seconds": 1.0, "flight": "outcome goal reached", "true_clearance_m": None,
              "message": "", "kept": "out/x/round03-realtime-tmp"}
    (line,) = tally([[failed]])["t"].failures
    assert line == "round 1: outcome goal reached | files kept in out/x/round03-realtime-tmp"
