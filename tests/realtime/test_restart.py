"""``companion fly`` SIGKILLed mid-encounter and started again, against one mavsim over loopback UDP.

docs/FAULTS.md, the restart row. The first fly engages and flies; 7 s of mavsim's time into
OFFBOARD (the encounter) it is killed with its planning process (its process group, which this
test started). PX4's offboard-loss failsafe takes the vehicle to Position mode 1 s later. The
second fly, same command line, finds the vehicle armed, airborne and in a failsafe: by default it
gives up at once (exit 1) and sends nothing that commands; with ``--reengage`` it takes the vehicle
back, and its first setpoint is its own hover (zero velocity), never a plan of the old process.
Every wait is bounded.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from companion.mavlink.tlog import read_tlog
from mavsim.core import Simulator
from mavsim.scenario import load_scenario
from mavsim.udp import LinkAddress, UdpServer
from tests.support.ports import free_udp_port
from tests.support.processes import kill_process_group

pytestmark = pytest.mark.realtime   # in .ci/run: 20 of 20 in make flake-check (docs/TESTING.md)

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "configs" / "antipodal.toml"
IN_OFFBOARD_S = 7.0
WAIT_S = 40.0
FLY_TIMEOUT_S = 90.0


def _fly(port: int, obstacle_port: int, tlog: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "companion.cli", "fly", "--connect", f"udpin:127.0.0.1:{port}",
         "--scenario", str(SCENARIO), "--obstacles", f"udpin:127.0.0.1:{obstacle_port}",
         "--duration", "40", "--exit-after-goal", "1.0", "--tlog", str(tlog), "--json", *extra],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True, cwd=ROOT)


def _wait(predicate, timeout_s: float = WAIT_S) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.01)
    return False


def _restart(tmp_path: Path, *second_args: str):
    port, obstacle_port = free_udp_port(), free_udp_port()
    sim = Simulator(load_scenario(SCENARIO), seed=0)
    server = UdpServer(sim, [LinkAddress("api", 0, port), LinkAddress("obstacles", 0, obstacle_port)], speed=1.0)
    serve = threading.Thread(target=server.run, args=(90.0,), daemon=True)
    first = _fly(port, obstacle_port, tmp_path / "first.tlog")
    second = None
    marks: dict = {}
    try:
        time.sleep(0.5)                      # fly's sockets bound before mavsim sends
        serve.start()
        engaged_at: list[float] = []

        def flown_into_encounter() -> bool:
            if sim.commander.mode == "OFFBOARD" and not engaged_at:
                engaged_at.append(sim.time_s)
            return bool(engaged_at) and sim.time_s - engaged_at[0] >= IN_OFFBOARD_S

        assert _wait(flown_into_encounter), "the first fly never flew 7 s in OFFBOARD"
        kill_process_group(first)
        marks["killed_s"] = sim.time_s
        assert _wait(lambda: sim.commander.mode != "OFFBOARD", 5.0)   # PX4's failsafe
        marks["failsafe_s"] = sim.time_s
        marks["last_setpoint_before_s"] = sim.commander.last_setpoint_s
        second = _fly(port, obstacle_port, tmp_path / "second.tlog", *second_args)
        out, err = second.communicate(timeout=FLY_TIMEOUT_S)
        marks["second_started_s"] = marks["failsafe_s"]
    finally:
        for proc in (first, second):
            if proc is not None and proc.poll() is None:
                kill_process_group(proc)
        server.stop()
        serve.join(timeout=5)
        server.close()
    return sim, second.returncode, out, err, tmp_path / "second.tlog", marks


def test_that_a_restarted_fly_finds_the_vehicle_in_px4s_failsafe_and_does_not_take_it_back(tmp_path):
    sim, code, out, err, tlog, marks = _restart(tmp_path)
    assert "Traceback" not in err, err[-3000:]
    report = json.loads(out)
    assert code == 1, (report.get("outcome"), report.get("events"))
    assert report["phase"] == "GAVE_UP"
    texts = [text for _, text in report["events"]]
    assert any("vehicle found armed in a failsafe (POSCTL)" in t and "not taking over" in t for t in texts), texts
    truth = sim.summary()
    modes = [m["mode"] for m in truth["mode_changes"]]
    assert modes[-1] == "POSCTL" and modes.count("OFFBOARD") == 1, modes        # never taken back
    assert sim.commander.last_setpoint_s == marks["last_setpoint_before_s"]      # no setpoint reached it
    sent = [m.get_type() for _, m in read_tlog(tlog) if m.get_srcComponent() == 191]
    assert "SET_POSITION_TARGET_LOCAL_NED" not in sent and "COMMAND_LONG" not in sent, sorted(set(sent))
    assert not truth["collided"], truth


def test_that_a_restarted_fly_with_reengage_takes_the_vehicle_back_from_a_hover(tmp_path):
    sim, code, out, err, tlog, marks = _restart(tmp_path, "--reengage")
    assert "Traceback" not in err, err[-3000:]
    report = json.loads(out)
    truth = sim.summary()
    modes = [m["mode"] for m in truth["mode_changes"]]
    assert modes[-2:] in (["OFFBOARD", "AUTO.LOITER"], ["POSCTL", "OFFBOARD"]) and modes.count("OFFBOARD") == 2, modes
    setpoints = [m for _, m in read_tlog(tlog) if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"
                 and m.get_srcComponent() == 191]
    assert setpoints, "the second fly streamed nothing"
    first = setpoints[0]
    assert (first.vx, first.vy, first.vz) == (0.0, 0.0, 0.0)    # its own hover, not a plan of the old process
    assert code == 0 and report["outcome"] == "goal reached", (code, report.get("outcome"), report.get("events"))
    assert not truth["collided"], truth
