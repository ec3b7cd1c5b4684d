"""Real time over loopback UDP with obstacles on their own links (issue 17).

``companion demo --realtime`` starts mavsim (obstacles sent to the companion's obstacle port, or
re-streamed by the simulated autopilot as ADSB) and ``companion fly --obstacles ...``. The capture
test puts two rogue obstacle sources beside them and checks that every packet the companion sends
goes to the autopilot's address. Each run takes 20-40 s of wall time; every wait is bounded.
"""

from __future__ import annotations

import dataclasses
import json
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.cli import main
from companion.loop.config import load_scenario
from companion.offline.replay import replay
from tests.support.flight_summary import record_flight
from tests.support.traffic_scenarios import antipodal_variant
from tests.support.ports import free_udp_port

SHORT_HOP = Path(__file__).resolve().parents[1] / "data" / "short_hop.toml"


def _realtime_demo(path: Path, capsys, out: Path | None = None) -> dict:
    assert main(["demo", str(path), "--realtime", "--json", *(["--out", str(out)] if out else [])]) == 0
    return json.loads(capsys.readouterr().out)


def _check_flight(summary: dict, n_sources: int) -> None:
    # OFFBOARD was confirmed from the HEARTBEAT (after the goal the companion may hand back to Hold)
    assert any("ENGAGED" in text for _, text in summary.get("events", [])), summary.get("events") or summary.get("fly_error")
    assert summary["collided"] is False and summary["goal_reached"] is True, summary
    intake = summary["obstacle_intake"]
    # (a clean-clone CI run once saw 107, 40 and 26 reports accepted where runs here accept about
    # 160 per aircraft, cause not found: the context below is printed to find it next time)
    context = {k: summary.get(k) for k in ("time_to_goal_s", "sim_time_s", "inbound_superseded", "inbound_dropped",
                                           "setpoint_gap_max_ms", "tick_max_ms", "stream_nice", "tracks", "wall_s")}
    assert len(intake["accepted"]) == n_sources and min(intake["accepted"].values()) > 50, (intake, context)
    assert intake["clock_restarts"] == {}, intake


def test_that_odometry_on_an_obstacle_link_from_offset_drifting_clocks_is_flown_safely_in_real_time_and_replays_exactly(
        tmp_path, capsys, record_property):
    scenario = antipodal_variant("odometry_clocks", tmp_path)
    summary = _realtime_demo(scenario, capsys, out=tmp_path / "out")
    record_flight(record_property, summary, kept_at=tmp_path / "out")
    _check_flight(summary, 3)
    # The tlog marks each tick and the link of each obstacle message (companion.realtime.tlog_marks):
    # the replay feeds every message on its own link at its own tick and reproduces every command.
    offboard = dataclasses.replace(load_scenario(scenario).offboard, hold_after_goal_s=1.0)  # demo --realtime: fly --exit-after-goal 1
    res = replay(tmp_path / "out" / "companion.tlog", scenario, offboard=offboard)
    assert any("marked" in note for note in res.notes), res.notes
    assert res.commands_compared == res.commands_recorded > 100
    assert res.unmatched_commands == 0 and res.tick_mismatches == 0
    assert res.max_abs_diff_mps == 0.0


@pytest.mark.realtime
@pytest.mark.parametrize("name", ["adsb", "remote_id"])
def test_that_adsb_through_the_autopilot_and_remote_id_are_flown_safely_in_real_time(name, tmp_path, capsys, record_property):
    summary = _realtime_demo(antipodal_variant(name, tmp_path), capsys, out=tmp_path / "out")
    record_flight(record_property, summary, kept_at=tmp_path / "out")
    _check_flight(summary, 3)
    assert summary["obstacle_intake"]["origin"] is not None  # GPS_GLOBAL_ORIGIN requested and answered


class _RogueSource:
    """A MAVLink system sending ``make()`` at 10 Hz to ``port`` and counting every byte sent back to it."""

    def __init__(self, port: int, sysid: int, make) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.1)
        self.port, self.mav, self.make = port, mavlink2.MAVLink(None, sysid, 197), make
        self.sent = self.received = 0
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        t0 = time.monotonic()
        while not self.stop.is_set():
            self.sock.sendto(self.make(time.monotonic() - t0).pack(self.mav), ("127.0.0.1", self.port))
            self.sent += 1
            try:
                while True:
                    self.received += len(self.sock.recv(65535))
            except (TimeoutError, socket.timeout, BlockingIOError):
                pass
            except ConnectionRefusedError:  # nobody listening yet
                time.sleep(0.1)


def test_that_every_packet_the_companion_sends_goes_to_the_autopilot_and_none_to_an_obstacle_source(tmp_path):
    api, gcs, api_local, gcs_local, obs, obs_local = (free_udp_port() for _ in range(6))
    sim = subprocess.Popen(
        [sys.executable, "-m", "mavsim.cli", "--scenario", str(SHORT_HOP), "--api-port", str(api), "--gcs-port", str(gcs),
         "--api-local-port", str(api_local), "--gcs-local-port", str(gcs_local), "--obstacle-port", str(obs),
         "--obstacle-local-port", str(obs_local), "--json"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    nan = float("nan")
    # The dangerous wiring: another system's ODOMETRY reaching the companion's autopilot port ...
    on_autopilot_port = _RogueSource(api, 150, lambda t: mavlink2.MAVLink_odometry_message(
        int(t * 1e6), 1, 1, 100.0, 100.0, -5.0, [1, 0, 0, 0], nan, nan, nan, 0, 0, 0, [nan] * 21, [nan] * 21, 0, 0, 0))
    # ... and a perception process on the obstacle port (far away: it must not change the flight).
    on_obstacle_port = _RogueSource(obs, 151, lambda t: mavlink2.MAVLink_local_position_ned_message(
        int(t * 1e3), -100.0, -100.0, -5.0, 0.0, 0.0, 0.0))
    for rogue in (on_autopilot_port, on_obstacle_port):
        rogue.thread.start()
    try:
        fly = subprocess.run(
            [sys.executable, "-m", "companion.cli", "fly", "--connect", f"udpin:127.0.0.1:{api}", "--obstacles",
             f"udpin:127.0.0.1:{obs}", "--scenario", str(SHORT_HOP), "--exit-after-goal", "1.0", "--duration", "40",
             "--json"], capture_output=True, text=True, timeout=120)
    finally:
        for rogue in (on_autopilot_port, on_obstacle_port):
            rogue.stop.set()
            rogue.thread.join(timeout=2)
            rogue.sock.close()
        sim.send_signal(signal.SIGINT)
        try:
            sim_out, sim_err = sim.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            sim.kill()
            sim_out, sim_err = sim.communicate()
    assert fly.stdout.strip().startswith("{"), fly.stderr[-2000:]
    report = json.loads(fly.stdout)
    assert "{" in sim_out, f"mavsim printed no summary (rc {sim.returncode}): {sim_err[-2000:]}"
    truth = json.loads(sim_out[sim_out.index("{"):])
    assert any("ENGAGED" in text for _, text in report["events"]) and truth["goal_reached"] is True and not truth["collided"]
    assert on_autopilot_port.sent > 50 and on_obstacle_port.sent > 50
    assert on_autopilot_port.received == 0, "the companion sent to an obstacle source on its autopilot port"
    assert on_obstacle_port.received == 0, "the companion sent on a receive-only obstacle link"
    assert truth["link"]["SET_POSITION_TARGET_LOCAL_NED"] > 100 and truth["link"]["COMMAND_LONG"] >= 1  # all at the autopilot
    assert truth["link"].get("obstacle_link_received", 0) == 0
    intake = report["obstacle_intake"]
    assert any("system 150" in w and "EKF2_EV_CTRL" in w for w in intake["warnings"])
    assert intake["rejected"].get("autopilot sys 150: wrong link: ODOMETRY", 0) > 50  # counted, not used
    assert intake["accepted"].get("obstacles1 sys 151", 0) > 50 and intake["accepted"].get("obstacles1 sys 101", 0) > 50
