"""mavsim's traffic player (``mavsim traffic``) against a scripted stand-in for PX4's GCS link.

The stand-in is a UDP socket that sends PX4 HEARTBEATs, answers the player's
MAV_CMD_REQUEST_MESSAGE for GPS_GLOBAL_ORIGIN and sends SIH-like HIL_STATE_QUATERNION
truth; the test drives :meth:`TrafficPlayer.step` itself. Checked: the origin is requested
and used (ADSB_VEHICLE lat/lon by PX4's projection about it, to 1e-7 degree), obstacles
wait at their start points until the HEARTBEAT shows armed OFFBOARD and then move on their
tracks, link obstacles arrive on the obstacle link from their own system ids, the referee's
smallest distance; and the command's bad-input and signal behaviour.
"""

from __future__ import annotations

import json
import math
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from mavsim.geo import global_to_ned, ned_to_global
from mavsim.scenario import scenario_from_dict
from mavsim.traffic import PlayerLinks, TrafficPlayer
from tests.support.ports import free_udp_port

ORIGIN = (47.3977448, 8.5455937, 489.067)   # lat deg, lon deg, alt m AMSL (GPS_GLOBAL_ORIGIN)
OFFBOARD_ARMED = (1 | 16 | 128, 6 << 16)     # base_mode, custom_mode
POSCTL_DISARMED = (1 | 64 | 16, 3 << 16)
ZERO = [[0.0] * 3] * 3


def _scenario(adsb_start=(10.0, 5.0, -5.0), link_start=(0.0, 8.0, -5.0)):
    return scenario_from_dict({
        "scenario": {"name": "player"},
        "vehicle": {"radius_m": 0.5, "start_ned_m": [0.0, 0.0, -5.0]},
        "mission": {"goal_ned_m": [20.0, 0.0, -5.0], "goal_tolerance_m": 0.3},
        "world": {"obstacles": [
            {"name": "plane", "transport": "adsb", "radius_m": 0.5, "start_ned_m": list(adsb_start),
             "velocity_ned_mps": [-2.0, 0.0, 0.0], "measurement_cov_m2": ZERO, "velocity_cov_m2ps2": ZERO, "report_rate_hz": 20.0},
            {"name": "drone", "transport": "link", "message": "LOCAL_POSITION_NED", "radius_m": 0.5,
             "start_ned_m": list(link_start), "waypoints_ned_m": [[0.0, -8.0, -5.0]], "speed_mps": 1.0,
             "measurement_cov_m2": ZERO, "velocity_cov_m2ps2": ZERO, "report_rate_hz": 20.0},
        ]},
    }, "player.toml")


class FakePx4:
    """PX4's GCS link as the player sees it: HEARTBEATs, GPS_GLOBAL_ORIGIN on request, truth."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.port = self.sock.getsockname()[1]
        self.mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        self.parser = mavlink2.MAVLink(None)
        self.player_addr: tuple[str, int] | None = None
        self.received: list = []

    def send(self, msg, addr) -> None:
        self.sock.sendto(bytes(msg.pack(self.mav)), addr)

    def heartbeat(self, addr, base_mode, custom_mode) -> None:
        self.send(mavlink2.MAVLink_heartbeat_message(2, 12, base_mode, custom_mode, 4, 3), addr)

    def pump(self) -> None:
        """Read what the player sent; answer a GPS_GLOBAL_ORIGIN request."""
        while True:
            try:
                data, addr = self.sock.recvfrom(65535)
            except BlockingIOError:
                return
            self.player_addr = addr
            for msg in self.parser.parse_buffer(data) or []:
                self.received.append(msg)
                if msg.get_type() == "COMMAND_LONG" and msg.command == 512 and int(msg.param1) == 49:
                    self.send(mavlink2.MAVLink_gps_global_origin_message(
                        round(ORIGIN[0] * 1e7), round(ORIGIN[1] * 1e7), round(ORIGIN[2] * 1000), 0), addr)

    def close(self) -> None:
        self.sock.close()


def _listener() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.setblocking(False)
    return s


def _drain(sock: socket.socket) -> list:
    parser, out = mavlink2.MAVLink(None), []
    while True:
        try:
            data = sock.recv(65535)
        except BlockingIOError:
            return out
        out.extend(parser.parse_buffer(data) or [])


def _run(player: TrafficPlayer, px4: FakePx4, seconds: float, mode=POSCTL_DISARMED, truth=None) -> None:
    end, next_hb = time.monotonic() + seconds, 0.0
    gcs_addr = ("127.0.0.1", player.links.gcs_local_port)
    while time.monotonic() < end:
        if time.monotonic() >= next_hb:
            px4.heartbeat(gcs_addr, *mode)
            next_hb = time.monotonic() + 0.25
        if truth is not None:
            lat, lon, alt = ned_to_global(*truth, *ORIGIN)
            px4.send(mavlink2.MAVLink_hil_state_quaternion_message(
                0, [1, 0, 0, 0], 0, 0, 0, round(lat * 1e7), round(lon * 1e7), round(alt * 1000), 0, 0, 0, 0, 0, 0, 0, 0),
                ("127.0.0.1", player.links.truth_port))
        px4.pump()
        player.step()
        time.sleep(0.005)


def test_that_the_player_plays_adsb_about_the_autopilots_origin_and_starts_the_obstacles_at_offboard():
    px4, obstacle_link = FakePx4(), _listener()
    links = PlayerLinks(gcs_local_port=free_udp_port(), autopilot_port=px4.port,
                        obstacle_port=obstacle_link.getsockname()[1], truth_port=free_udp_port())
    try:
        with TrafficPlayer(_scenario(), links) as player:
            _run(player, px4, 1.5)
            assert player.origin == pytest.approx(ORIGIN) and player.origin_source == "GPS_GLOBAL_ORIGIN"
            requests = [m for m in px4.received if m.get_type() == "COMMAND_LONG" and m.command == 512]
            assert {int(m.param1) for m in requests} >= {49, 242}
            assert any(m.get_type() == "HEARTBEAT" and m.type == 6 for m in px4.received)
            adsb = [m for m in px4.received if m.get_type() == "ADSB_VEHICLE"]
            assert adsb and {m.get_srcSystem() for m in adsb} == {101}
            # before engagement: at rest at the start point, by PX4's projection about its origin
            lat, lon, alt = ned_to_global(10.0, 5.0, -5.0, *ORIGIN)
            last = adsb[-1]
            assert abs(last.lat - lat * 1e7) <= 0.5 and abs(last.lon - lon * 1e7) <= 0.5
            assert last.altitude == round(alt * 1000) and last.hor_velocity == 0
            link = [m for m in _drain(obstacle_link) if m.get_type() == "LOCAL_POSITION_NED"]
            assert link and {m.get_srcSystem() for m in link} == {102}
            assert (link[-1].x, link[-1].y, link[-1].z) == pytest.approx((0.0, 8.0, -5.0))
            assert player.engaged_t_s is None
            # engaged: the obstacles move on their tracks from that moment
            px4.received.clear()
            _run(player, px4, 1.0, mode=OFFBOARD_ARMED, truth=(0.0, 0.0, -5.0))
            assert player.engaged_t_s is not None
            moved = player.motion_s(player.now_s())
            last = [m for m in px4.received if m.get_type() == "ADSB_VEHICLE"][-1]
            north, east, down = global_to_ned(last.lat * 1e-7, last.lon * 1e-7, last.altitude * 1e-3, *ORIGIN)
            assert 10.0 - 2.0 * moved - 0.15 < north < 10.0 - 2.0 * (moved - 0.35), (north, moved)
            assert east == pytest.approx(5.0, abs=0.02) and down == pytest.approx(-5.0, abs=1e-3)
            assert last.hor_velocity == 200 and last.heading == 18000
            link = [m for m in _drain(obstacle_link) if m.get_type() == "LOCAL_POSITION_NED"]
            assert 8.0 - moved - 0.1 < link[-1].y < 8.0 - (moved - 0.35) and link[-1].vy == pytest.approx(-1.0)
            summary = json.loads(json.dumps(player.summary()))
        assert summary["engaged"] and summary["judged_on"] == "truth"
        truth = summary["referee"]["truth"]
        # the drone sits at (0, 0, -5): the link obstacle comes to within 8 - (its travel) m
        assert truth["obstacles"][1]["min_distance_m"] == pytest.approx(8.0 - moved, abs=0.1)
        assert truth["obstacles"][0]["min_distance_m"] == pytest.approx(math.hypot(10.0 - 2.0 * moved, 5.0), abs=0.15)
        assert summary["mode_changes"][0][1] == "POSCTL disarmed" and summary["mode_changes"][-1][1] == "OFFBOARD"
    finally:
        px4.close()
        obstacle_link.close()



def test_that_with_a_frame_origin_a_fleets_player_places_everything_in_the_fleets_frame():
    """A fleet's vehicle whose EKF origin lies 12 m north and 3 m west of the fleet's frame
    origin: ADS-B about the frame origin, the link obstacle's local reports shifted into the
    vehicle's frame (held until its origin is known), truth and estimate in the fleet's frame,
    and the motion waiting for :meth:`engage` ("manual") although the vehicle is in OFFBOARD."""
    frame = ned_to_global(-12.0, 3.0, 0.0, *ORIGIN)   # the vehicle's origin is (12, -3, 0) in the frame
    px4, obstacle_link = FakePx4(), _listener()
    links = PlayerLinks(gcs_local_port=free_udp_port(), autopilot_port=px4.port,
                        obstacle_port=obstacle_link.getsockname()[1], truth_port=free_udp_port())
    try:
        with TrafficPlayer(_scenario(), links, start="manual", frame_origin=frame, keep_samples=True) as player:
            for _ in range(20):     # no answer from the autopilot yet: its origin is unknown
                player.step()
                time.sleep(0.01)
            assert player.stats["local_held_no_origin"] > 0 and not _drain(obstacle_link)
            _run(player, px4, 1.5, mode=OFFBOARD_ARMED, truth=(0.0, 0.0, -5.0))   # truth: the vehicle's frame
            assert player.engaged_t_s is None                  # OFFBOARD, but the start is the caller's
            assert player.vehicle_offset_m == pytest.approx([12.0, -3.0, 0.0], abs=1e-3)
            adsb = [m for m in px4.received if m.get_type() == "ADSB_VEHICLE"][-1]
            north, east, down = global_to_ned(adsb.lat * 1e-7, adsb.lon * 1e-7, adsb.altitude * 1e-3, *frame)
            assert (north, east, down) == pytest.approx((10.0, 5.0, -5.0), abs=0.02)   # the scenario's point
            link = [m for m in _drain(obstacle_link) if m.get_type() == "LOCAL_POSITION_NED"][-1]
            assert (link.x, link.y, link.z) == pytest.approx((-12.0, 11.0, -5.0), abs=1e-4)   # (0, 8, -5) less the offset
            _, truth = player.samples["truth"][-1]
            assert truth == pytest.approx([12.0, -3.0, -5.0], abs=0.02)
            player.engage()
            engaged = player.engaged_t_s
            _run(player, px4, 0.5, mode=OFFBOARD_ARMED, truth=(0.0, 0.0, -5.0))
            assert player.engaged_t_s == engaged and player.motion_s(player.now_s()) > 0.4
            summary = json.loads(json.dumps(player.summary()))
        assert summary["frame_origin"]["lat_deg"] == pytest.approx(frame[0])
        assert summary["vehicle_offset_m"] == pytest.approx([12.0, -3.0, 0.0], abs=1e-3)
        # the link obstacle (0, 8, -5) in the frame, the vehicle at (12, -3, -5): refereed in the frame
        assert summary["referee"]["truth"]["obstacles"][1]["min_distance_m"] == pytest.approx(math.hypot(12.0, 11.0), abs=0.6)
    finally:
        px4.close()
        obstacle_link.close()

def _traffic(*args: str, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mavsim", "traffic", *args], capture_output=True, text=True,
                          timeout=60, **kw)


@pytest.mark.parametrize("change, words", [
    ({"transport": "api"}, "transport = \"api\" cannot be played"),
    (None, "no [[world.obstacles]] to play"),
])
def test_that_mavsim_traffic_refuses_a_scenario_it_cannot_play_in_one_line(tmp_path, change, words):
    ob = '[[world.obstacles]]\nname = "a"\nstart_ned_m = [1.0, 0.0, -5.0]\nvelocity_ned_mps = [0.0, 0.0, 0.0]\n'
    text = "[scenario]\nname = \"x\"\n" + ("" if change is None else ob + "".join(
        f'{k} = "{v}"\n' for k, v in change.items()))
    path = tmp_path / "s.toml"
    path.write_text(text)
    proc = _traffic("--scenario", str(path), "--duration", "1", "--gcs-local-port", str(free_udp_port()))
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("mavsim traffic: error:") and words in lines[0], proc.stderr


def test_that_mavsim_traffic_refuses_bad_arguments_and_a_port_in_use_in_one_line():
    for args in (["--duration", "1"], ["--scenario", "configs/antipodal.toml"],
                 ["--scenario", "configs/antipodal.toml", "--duration", "-1"],
                 ["--scenario", "configs/antipodal.toml", "--duration", "1", "--obstacle-port", "70000"]):
        proc = _traffic(*args)
        assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, (args, proc.stderr)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as busy:
        busy.bind(("127.0.0.1", 0))
        proc = _traffic("--scenario", "configs/antipodal.toml", "--duration", "1",
                        "--gcs-local-port", str(busy.getsockname()[1]))
    assert proc.returncode == 2 and "cannot bind the ground-station socket" in proc.stderr, proc.stderr


def test_that_mavsim_traffic_stops_on_sigterm_with_its_summary_and_says_the_vehicle_never_engaged():
    proc = subprocess.Popen([sys.executable, "-m", "mavsim", "traffic", "--scenario", "configs/antipodal.toml",
                             "--duration", "60", "--json", "--gcs-local-port", str(free_udp_port()),
                             "--autopilot-port", str(free_udp_port()), "--obstacle-port", str(free_udp_port()),
                             "--no-truth"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        time.sleep(2.0)
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=10)
        assert time.monotonic() - t0 < 2.0
    finally:
        proc.kill()
    assert proc.returncode == 1, err
    assert "stopped by SIGTERM" in err and "never engaged" in err
    summary = json.loads(out)
    assert summary["engaged"] is False and summary["sent"]["obstacle_link_sent"] > 0
    assert np.isclose(summary["player_time_s"], 2.0, atol=1.5)
