"""mavsim over loopback UDP, driven with pymavlink the way a PX4 offboard client does.

The server runs in a thread on free ports; every wait is bounded.
"""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import threading
import time

import pytest
from pymavlink import mavutil

from mavsim.cli import main
from mavsim.core import Simulator
from mavsim.scenario import scenario_from_dict
from mavsim.udp import LinkAddress, UdpServer


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


SCENARIO = {
    "vehicle": {"start_ned_m": [0.0, 0.0, -5.0]},
    "world": {"obstacles": [
        # On the API link (the old way): the client must still pick the autopilot out of them.
        {"name": "o1", "start_ned_m": [20.0, 0.0, -5.0], "velocity_ned_mps": [-0.5, 0.0, 0.0], "transport": "api"},
        {"name": "o2", "start_ned_m": [20.0, 5.0, -5.0], "velocity_ned_mps": [-0.5, 0.0, 0.0], "transport": "api"},
    ]},
}


@pytest.fixture
def px4(tmp_path):
    """A mavsim UDP server at 2x real time and a pymavlink client listening for it."""
    api, gcs = free_port(), free_port()
    client = mavutil.mavlink_connection(f"udpin:127.0.0.1:{api}", source_system=245, source_component=190,
                                        dialect="common")
    gcs_client = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs}", dialect="common")
    sim = Simulator(scenario_from_dict(SCENARIO), seed=0, links=("api", "gcs"))
    server = UdpServer(sim, [LinkAddress("api", 0, api), LinkAddress("gcs", 0, gcs)], speed=2.0,
                       tlog=tmp_path / "udp.tlog")
    thread = threading.Thread(target=server.run, args=(120.0,), daemon=True)
    thread.start()
    try:
        yield client, gcs_client, sim
    finally:
        server.stop()
        thread.join(timeout=5)
        server.close()
        client.close()
        gcs_client.close()
        assert not thread.is_alive()


def recv(conn, mtype, timeout=3.0, cond=lambda m: True):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        m = conn.recv_match(type=mtype, blocking=True, timeout=0.2)
        if m is not None and cond(m):
            return m
    raise AssertionError(f"no {mtype} within {timeout} s")


def autopilot_heartbeat(conn, timeout=3.0):
    return recv(conn, "HEARTBEAT", timeout, lambda m: m.get_srcSystem() == 1)


def recv_streaming(conn, mtype, vx, timeout, cond=lambda m: True, rate=20.0):
    """Like :func:`recv` while streaming velocity setpoints (so OFFBOARD is kept)."""
    deadline = time.monotonic() + timeout
    next_sp = 0.0
    while time.monotonic() < deadline:
        if time.monotonic() >= next_sp:
            conn.mav.set_position_target_local_ned_send(0, 1, 1, 1, 3527, 0, 0, 0, vx, 0, 0, 0, 0, 0, 0, 0)
            next_sp = time.monotonic() + 1.0 / rate
        m = conn.recv_match(type=mtype, blocking=True, timeout=0.02)
        if m is not None and cond(m):
            return m
    raise AssertionError(f"no {mtype} within {timeout} s")


def stream(conn, vx, seconds, rate=20.0):
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        conn.mav.set_position_target_local_ned_send(0, 1, 1, 1, 3527, 0, 0, 0, vx, 0, 0, 0, 0, 0, 0, 0)
        time.sleep(1.0 / rate)


def test_that_a_pymavlink_client_finds_the_autopilot_not_an_obstacle(px4):
    client, gcs_client, _ = px4
    hb = client.wait_heartbeat(timeout=3)
    assert hb is not None
    recv(client, "ODOMETRY", 3.0, lambda m: m.get_srcSystem() == 102)
    hb = autopilot_heartbeat(client)
    assert client.target_system == 1  # pymavlink locked onto the autopilot
    assert mavutil.mode_string_v10(hb) == "LOITER"
    obstacle_hb = recv(client, "HEARTBEAT", 3.0, lambda m: m.get_srcSystem() in (101, 102))
    assert obstacle_hb.autopilot == 8 and obstacle_hb.get_srcComponent() != 1
    assert not client.probably_vehicle_heartbeat(obstacle_hb)
    # the ground-station link carries the vehicle, not the obstacles
    assert autopilot_heartbeat(gcs_client).autopilot == 12
    deadline = time.monotonic() + 1.5
    while time.monotonic() < deadline:
        m = gcs_client.recv_match(blocking=True, timeout=0.2)
        assert m is None or m.get_srcSystem() == 1


def test_that_offboard_flow_works_like_px4_over_udp(px4):
    client, _, sim = px4
    autopilot_heartbeat(client)
    client.set_mode("OFFBOARD")  # no stream yet: refused
    ack = recv(client, "COMMAND_ACK", 2.0, lambda m: m.command == 176)
    assert ack.result == 0
    recv(client, "STATUSTEXT", 2.0, lambda m: "Offboard is currently not available" in m.text)
    assert mavutil.mode_string_v10(autopilot_heartbeat(client)) == "LOITER"

    stream(client, 1.0, 0.6)
    client.set_mode("OFFBOARD")
    hb = recv_streaming(client, "HEARTBEAT", 1.0, 3.0,
                        lambda m: m.get_srcSystem() == 1 and mavutil.mode_string_v10(m) == "OFFBOARD")
    assert hb.base_mode & 128
    lpn = recv_streaming(client, "LOCAL_POSITION_NED", 1.0, 3.0, lambda m: m.vx > 0.5)  # tracks 1 m/s
    assert lpn.vx < 1.3

    client.mav.command_long_send(1, 1, 512, 0, 148, 0, 0, 0, 0, 0, 0)
    assert recv_streaming(client, "COMMAND_ACK", 1.0, 2.0, lambda m: m.command == 512).result == 0
    recv_streaming(client, "AUTOPILOT_VERSION", 1.0, 2.0)
    client.mav.command_long_send(1, 1, 42424, 0, 0, 0, 0, 0, 0, 0, 0)
    assert recv_streaming(client, "COMMAND_ACK", 1.0, 2.0, lambda m: m.command == 42424).result == 3

    t_stop = sim.time_s  # stop streaming: PX4 leaves OFFBOARD about 1 s later
    recv(client, "HEARTBEAT", 4.0, lambda m: m.get_srcSystem() == 1 and mavutil.mode_string_v10(m) != "OFFBOARD")
    left = [c for c in sim.summary()["mode_changes"] if c["mode"] == "POSCTL"][-1]["t_s"]
    assert 0.9 <= left - t_stop <= 1.3


def test_that_arming_and_takeoff_work_from_the_ground_over_udp():
    api = free_port()
    client = mavutil.mavlink_connection(f"udpin:127.0.0.1:{api}", source_system=245, dialect="common")
    sim = Simulator(scenario_from_dict({}), links=("api",))
    server = UdpServer(sim, [LinkAddress("api", 0, api)], speed=4.0)
    thread = threading.Thread(target=server.run, args=(60.0,), daemon=True)
    thread.start()
    try:
        autopilot_heartbeat(client)
        client.arducopter_arm()
        assert recv(client, "COMMAND_ACK", 5.0, lambda m: m.command == 400).result == 0
        client.mav.command_long_send(1, 1, 22, 0, 0, 0, 0, float("nan"), 0, 0, float("nan"))
        assert recv(client, "COMMAND_ACK", 5.0, lambda m: m.command == 22).result == 0
        recv(client, "HEARTBEAT", 8.0, lambda m: m.get_srcSystem() == 1 and mavutil.mode_string_v10(m) == "LOITER")
        assert recv(client, "GLOBAL_POSITION_INT", 1.0).relative_alt == pytest.approx(2500, abs=150)
    finally:
        server.stop()
        thread.join(timeout=5)
        server.close()
        client.close()


def test_that_the_cli_rejects_a_bad_scenario_naming_file_section_and_key(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[sim]\nvelocity_time_constant = 0.3\n")
    assert main(["--scenario", str(bad), "--lockstep"]) == 2
    err = capsys.readouterr().err
    assert "bad.toml" in err and "[sim]" in err and "velocity_time_constant" in err
    assert main(["--scenario", str(tmp_path / "missing.toml")]) == 2


def test_that_the_cli_runs_a_scenario_and_prints_json(tmp_path, capsys):
    tlog = tmp_path / "run.tlog"
    assert main(["--scenario", "configs/single_obstacle.toml", "--lockstep", "--duration", "5", "--json",
                 "--tlog", str(tlog)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["scenario"] == "single_obstacle" and summary["sim_time_s"] == pytest.approx(5.0)
    assert tlog.stat().st_size > 1000


def test_that_the_cli_serves_udp_for_a_bounded_time(capsys):
    api = free_port()
    client = mavutil.mavlink_connection(f"udpin:127.0.0.1:{api}", dialect="common")
    try:
        result = {}
        t = threading.Thread(target=lambda: result.setdefault("rc", main(
            ["--api-port", str(api), "--api-local-port", "0", "--no-gcs", "--duration", "2", "--speed", "4",
             "--json"])), daemon=True)
        t.start()
        assert autopilot_heartbeat(client).autopilot == 12
        t.join(timeout=5)
        assert result.get("rc") == 0
        assert json.loads(capsys.readouterr().out)["sim_time_s"] == pytest.approx(2.0)
    finally:
        client.close()


@pytest.mark.parametrize("signame, after_s", [("SIGINT", 0.3), ("SIGINT", 1.1), ("SIGTERM", 0.7)])
def test_that_a_signal_stops_the_udp_server_after_its_step_and_the_summary_is_still_printed(signame, after_s):
    """SIGINT/SIGTERM set the server's stop flag: no KeyboardInterrupt lands mid-step, so the run
    summary always comes out (an exception inside the simulator used to lose it now and then)."""
    api = free_port()
    sim = subprocess.Popen([sys.executable, "-m", "mavsim.cli", "--api-port", str(api), "--api-local-port", "0",
                            "--no-gcs", "--speed", "4", "--json"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 20.0
        line = ""
        while "mavsim: scenario" not in line and time.monotonic() < deadline:
            line = sim.stderr.readline()  # the start-up line: the server is running
        time.sleep(after_s)
        sim.send_signal(getattr(signal, signame))
        out, err = sim.communicate(timeout=20)
    finally:
        if sim.poll() is None:
            sim.kill()
            sim.communicate()
    assert sim.returncode == 0, err[-2000:]
    assert json.loads(out)["sim_time_s"] > 0.0
    assert f"stopped by {signame}" in err and "Traceback" not in err
