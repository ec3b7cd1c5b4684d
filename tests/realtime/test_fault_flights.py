"""``companion fly`` under link faults in real time: mavsim -> fault proxy -> fly over loopback UDP.

The rows of docs/FAULTS.md that need the real process (its exit code, its clock, its sockets).
Faults are added to the proxy once mavsim's vehicle has flown 7 s in OFFBOARD (in lockstep it
engages at 1 s, so that is the encounter at 8 s; in real time the planning process's start
delays the engagement by one to three seconds, and a cut at 8 s of simulated time leaves the
vehicle hovering on the head-on obstacle's path, docs/FAULTS.md), so the machine's load moves
the start, not the point of the flight the fault hits.
Every wait is bounded (fly: 120 s; each poll below: 40 s).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

from companion.mavlink.tlog import read_tlog
from tests.support.fault_proxy import Fault, FaultProxy
from tests.support.fly_udp import fly_beside_mavsim
from tests.support.ports import free_udp_port

pytestmark = pytest.mark.realtime   # in .ci/run: 20 of 20 in make flake-check (docs/TESTING.md)

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "configs" / "antipodal.toml"
IN_OFFBOARD_S = 7.0
WAIT_S = 40.0


def _when_engaged_for(sim, s: float) -> bool:
    """Wait (bounded) until the vehicle has been ``s`` seconds of mavsim's time in OFFBOARD."""
    deadline, engaged_at = time.monotonic() + WAIT_S, None
    while time.monotonic() < deadline:
        if sim.commander.mode == "OFFBOARD":
            engaged_at = sim.time_s if engaged_at is None else engaged_at
            if sim.time_s - engaged_at >= s:
                return True
        time.sleep(0.01)
    return False


def _fly_with_cut(tmp_path, cut_s: float):
    """fly through the proxy; both ways cut ``cut_s`` seconds once the vehicle flew 7 s in OFFBOARD."""
    listen, fly_port = free_udp_port(), free_udp_port()
    proxy = FaultProxy(listen, fly_port, seed=0)
    cut: dict = {}

    def cut_mid_encounter(_fly, sim) -> None:
        if _when_engaged_for(sim, IN_OFFBOARD_S):
            start = proxy.elapsed_s()
            proxy.faults.append(Fault("cut", "both", start_s=start, end_s=start + cut_s))
            cut["sim_s"] = sim.time_s

    proxy.start()
    try:
        run = fly_beside_mavsim(SCENARIO, tmp_path, autopilot_port=listen, fly_port=fly_port, duration_s=60,
                                during=cut_mid_encounter)
    finally:
        proxy.stop()
    assert "Traceback" not in run.err, run.err[-3000:]
    assert cut, "the vehicle never reached OFFBOARD at the encounter"
    assert proxy.stats["down", "cut"] > 0 and proxy.stats["up", "cut"] > 0, proxy.stats
    return run, json.loads(run.out), cut


def test_that_fly_rides_through_a_half_second_cut_to_the_goal(tmp_path):
    run, report, _ = _fly_with_cut(tmp_path, 0.5)
    assert run.returncode == 0 and report["outcome"] == "goal reached", (report.get("outcome"), report.get("events"))
    truth = run.sim.summary()
    modes = [m["mode"] for m in truth["mode_changes"]]
    assert modes[modes.index("OFFBOARD") + 1:] in ([], ["AUTO.LOITER"]), modes     # no failsafe; Hold at the end
    assert not truth["collided"], truth


@pytest.mark.parametrize("cut_s", [2.0, 10.0])
def test_that_fly_names_px4s_failsafe_after_a_cut_and_exits_7(tmp_path, cut_s):
    """The finding of a manual run: a 2 s cut of the autopilot link, PX4's offboard-loss failsafe,
    and fly ended "pilot took over" (5). Now: "autopilot failsafe" (7), and nothing fought it."""
    run, report, cut = _fly_with_cut(tmp_path, cut_s)
    assert run.returncode == 7, (report.get("outcome"), report.get("events"), run.err[-2000:])
    assert report["outcome"] == "autopilot failsafe" and report["phase"] == "PILOT_TOOK_OVER"
    truth = run.sim.summary()
    modes = [m["mode"] for m in truth["mode_changes"]]
    fell_back = modes.index("OFFBOARD") + 1
    assert modes[fell_back:] == ["POSCTL"], modes                 # PX4's fallback, never re-taken
    assert not truth["collided"], (cut, truth["mode_changes"], truth.get("min_true_clearance_m"))
    texts = [text for _, text in report["events"]]
    assert any("autopilot failsafe after" in t for t in texts), texts
    # The companion's own log: nothing sent to command the vehicle after the HEARTBEAT that showed it.
    took_over = None
    for t, msg in read_tlog(run.tlog):
        kind = msg.get_type()
        if took_over is None and kind == "HEARTBEAT" and msg.get_srcSystem() == 1 and (msg.custom_mode >> 16) & 0xFF == 3:
            took_over = t
        elif took_over is not None and msg.get_srcComponent() == 191:
            assert kind not in ("SET_POSITION_TARGET_LOCAL_NED", "COMMAND_LONG", "SET_MODE"), (t - took_over, kind)
    assert took_over is not None
