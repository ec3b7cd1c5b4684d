"""Where the largest setpoint gap's time went (:class:`companion.realtime.gap_probe.GapProbe`).

A gap the stream computed through shows its CPU time; a gap it slept through shows
little CPU and a voluntary context switch; a gap the monotonic clock did not see is
told apart; the longest step of the loop within the gap is named; only the largest gap
is kept.
"""

from __future__ import annotations

import sys
import time

import pytest

from companion.realtime.gap_probe import GapProbe


def _compute_for(cpu_s: float) -> None:
    """Spin until this process has used ``cpu_s`` more seconds of CPU (not wall: a loaded machine cannot shorten it)."""
    end = time.process_time() + cpu_s
    while time.process_time() < end:
        pass


def test_a_gap_spent_computing_shows_its_cpu_time_and_its_longest_step():
    probe = GapProbe()
    probe.setpoint(None)
    assert probe.largest is None
    t0 = time.perf_counter()
    _compute_for(0.06)
    probe.step("poll", 0.001)
    probe.step("tick", time.perf_counter() - t0)
    probe.step("sleep", 0.002)
    gap = time.perf_counter() - t0
    probe.setpoint(gap)
    rec = probe.largest
    assert rec["gap_ms"] == round(gap * 1e3, 1) and rec["monotonic_gap_ms"] >= 60.0
    assert rec["cpu_ms"] >= 60.0
    assert rec["longest_step"] == "tick" and rec["longest_step_ms"] >= 60.0


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="run-queue wait and switch counts are Linux's")
def test_a_gap_spent_asleep_shows_little_cpu_and_a_voluntary_switch():
    probe = GapProbe()
    probe.setpoint(None)
    t0 = time.perf_counter()
    time.sleep(0.1)
    probe.step("sleep", time.perf_counter() - t0)
    probe.setpoint(time.perf_counter() - t0)
    rec = probe.largest
    assert rec["gap_ms"] >= 100.0 and rec["cpu_ms"] < 50.0
    assert rec["voluntary_switches"] >= 1
    assert rec["run_queue_wait_ms"] is not None and rec["run_queue_wait_ms"] >= 0.0
    assert rec["steal_ms"] is not None and rec["steal_ms"] >= 0.0
    assert rec["longest_step"] == "sleep"


def test_only_the_largest_gap_is_kept_and_each_gap_starts_its_steps_afresh():
    probe = GapProbe()
    probe.setpoint(None)
    probe.step("obstacle report", 0.03)
    probe.setpoint(0.08)
    probe.step("sleep", 0.002)
    probe.setpoint(0.05)   # smaller: the 80 ms gap stays
    assert probe.largest["gap_ms"] == 80.0 and probe.largest["longest_step"] == "obstacle report"
    probe.setpoint(0.2)    # larger, with no step recorded since the last setpoint
    assert probe.largest["gap_ms"] == 200.0
    # these gaps were only told, not lived: the monotonic clock saw next to nothing pass
    # (as when the wall clock the stream stamps with is set forward)
    assert probe.largest["monotonic_gap_ms"] < 50.0
    assert probe.largest["longest_step"] is None and probe.largest["longest_step_ms"] == 0.0


def test_the_text_report_says_where_the_largest_gap_went():
    from companion.offline.report import format_report

    detail = {"gap_ms": 192.0, "monotonic_gap_ms": 192.1, "cpu_ms": 3.1, "run_queue_wait_ms": 140.2, "steal_ms": 0.0,
              "voluntary_switches": 4, "involuntary_switches": 1, "longest_step": "sleep", "longest_step_ms": 141.0}
    text = format_report({"setpoint_gap_max_ms": 192.0, "setpoint_gap_max_detail": detail})
    assert ("3.1 ms on a CPU, 140.2 ms waiting for one, 0.0 ms taken by the host (all CPUs), "
            "longest step sleep 141.0 ms\n") in text + "\n"
    jumped = format_report({"setpoint_gap_max_detail": {**detail, "run_queue_wait_ms": None, "monotonic_gap_ms": 50.2}})
    assert "run-queue wait unknown" in jumped and "the monotonic clock saw 50.2 ms (the wall clock was set)" in jumped


def test_the_readings_are_those_of_the_tick_starts_the_gap_is_measured_between():
    probe = GapProbe()
    probe.tick_started()
    probe.setpoint(None)
    _compute_for(0.06)          # between the two ticks' starts: inside the gap
    probe.tick_started()
    _compute_for(0.06)          # the second tick's own work, before it sends: the next gap's
    probe.setpoint(0.06)
    assert 60.0 <= probe.largest["cpu_ms"] < 100.0
