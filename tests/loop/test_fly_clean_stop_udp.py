"""Ctrl-C and SIGTERM stop ``companion fly`` cleanly mid-encounter, over loopback UDP against mavsim.

mavsim serves the antipodal encounter in a thread (its truth at hand); ``companion fly``
runs as its own process, as an operator starts it. Eight seconds after the start, in the
middle of the encounter, the test sends the signal. The companion must hand the vehicle
back (Hold, requested while the setpoints still stream, so mavsim sees no setpoint loss),
stop its planning process without a traceback, print its summary, close its tlog (which
replays exactly) and exit 3. About 15 s of wall time per signal: marked realtime.
"""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from companion.loop.config import load_scenario
from companion.offline.replay import replay
from tests.support.fly_udp import FlyRun, fly_beside_mavsim
from tests.support.ports import free_udp_port

pytestmark = [pytest.mark.realtime]

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "configs" / "antipodal.toml"
STOP_AFTER_S = 8.0


def _fly_and_signal(tmp_path: Path, signum: int, *, second_signal: bool = False, group: bool = False) -> FlyRun:
    """Fly the encounter and signal fly mid-way (``group``: its whole process group, planning
    process included, as a terminal's Ctrl-C or systemd's default stop does)."""
    def signal_it(fly: subprocess.Popen, _sim) -> None:
        send = (lambda: os.killpg(fly.pid, signum)) if group else (lambda: fly.send_signal(signum))
        time.sleep(STOP_AFTER_S)
        send()
        if second_signal:
            time.sleep(0.2)
            send()

    return fly_beside_mavsim(SCENARIO, tmp_path, autopilot_port=free_udp_port(), duration_s=60, during=signal_it,
                             new_session=group)


@pytest.mark.parametrize("signum, group", [(signal.SIGINT, False), (signal.SIGTERM, False), (signal.SIGTERM, True)],
                         ids=["SIGINT", "SIGTERM", "SIGTERM to the process group"])
def test_that_a_signal_mid_encounter_hands_back_to_hold_and_exits_3_with_a_summary(tmp_path, signum, group):
    run = _fly_and_signal(tmp_path, signum, group=group)
    sim, tlog = run.sim, run.tlog
    assert "Traceback" not in run.err, run.err[-3000:]
    assert run.returncode == 3, run.err[-3000:]
    report = json.loads(run.out)
    assert report["outcome"] == "stopped" and report["exit_code"] == 3
    assert report["stop_requested_by"] == signal.Signals(signum).name
    assert report["phase"] == "HELD"
    assert report["planner_process"]["errors"] == 0  # no planner trouble on the way out
    assert any("ENGAGED" in text for _, text in report["events"])        # it was flying the encounter
    assert report["goal_reached_companion_t_s"] is None                  # stopped before the goal
    truth = sim.summary()
    modes = [m["mode"] for m in truth["mode_changes"]]
    assert truth["final_mode"] == "AUTO.LOITER" and modes[-2:] == ["OFFBOARD", "AUTO.LOITER"], modes
    assert truth["armed"]
    # the stream went on until mavsim showed Hold: no setpoint loss, so no failsafe on the way
    assert not any("failsafe" in str(m).lower() for m in truth["mode_changes"])
    # the tlog was closed whole, and replays exactly
    offboard = dataclasses.replace(load_scenario(SCENARIO).offboard, hold_after_goal_s=1.0)  # fly_beside_mavsim's flags
    res = replay(tlog, SCENARIO, offboard=offboard)
    assert res.commands_compared == res.commands_recorded > 100
    assert res.max_abs_diff_mps == 0.0 and res.unmatched_commands == 0


def test_that_a_second_ctrl_c_stops_at_once_and_says_hold_was_not_confirmed(tmp_path):
    run = _fly_and_signal(tmp_path, signal.SIGINT, second_signal=True)
    assert "Traceback" not in run.err, run.err[-3000:]
    assert run.returncode == 4
    report = json.loads(run.out)
    assert report["outcome"] == "stopped not held" and report["phase"] == "HANDING_BACK"


def test_that_with_no_autopilot_fly_says_so_every_five_seconds_and_exits_6(tmp_path):
    port = free_udp_port()
    run = subprocess.run(
        [sys.executable, "-m", "companion.cli", "fly", "--connect", f"udpin:127.0.0.1:{port}", "--scenario",
         str(SCENARIO), "--duration", "6", "--json"], capture_output=True, text=True, timeout=60)
    assert run.returncode == 6, run.stderr[-2000:]
    assert f"companion fly: no autopilot heard on udpin:127.0.0.1:{port} after 5 s" in run.stderr
    report = json.loads(run.stdout)
    assert report["outcome"] == "link lost" and report["phase"] == "WAIT_AUTOPILOT"


def test_that_fly_ends_linger_seconds_after_the_pilot_takes_over_and_exits_5(tmp_path):
    """The pilot switches the vehicle to Position mode mid-encounter: fly stops commanding at once
    and ends --linger (3 s) later with exit code 5, instead of running on."""
    def pilot(_fly: subprocess.Popen, sim) -> None:
        time.sleep(STOP_AFTER_S)
        sim.commander.request_mode(3, 0, sim.time_s, sim.vehicle)  # POSCTL, as from the pilot's radio

    started = time.monotonic()
    run = fly_beside_mavsim(SCENARIO, tmp_path, autopilot_port=free_udp_port(), duration_s=60, during=pilot)
    elapsed = time.monotonic() - started
    assert "Traceback" not in run.err, run.err[-3000:]
    assert run.returncode == 5, run.err[-3000:]
    report = json.loads(run.out)
    assert report["outcome"] == "pilot took over" and report["phase"] == "PILOT_TOOK_OVER"
    assert elapsed < STOP_AFTER_S + 20.0   # well before the 60 s of --duration
    assert run.sim.summary()["final_mode"] == "POSCTL"
