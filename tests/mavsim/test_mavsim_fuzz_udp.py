"""Fuzzing mavsim over loopback UDP: garbage datagrams change nothing, absurd values crash nothing.

The server runs in a thread on free ports for a few seconds of wall time; every datagram
is its own packet boundary, so a broken frame cannot swallow the next good one.
"""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from mavsim.core import Simulator
from mavsim.scenario import scenario_from_dict
from mavsim.udp import LinkAddress, UdpServer

FUZZ_S = 2.0
SCENARIO = {
    "vehicle": {"start_ned_m": [0.0, 0.0, -5.0]},
    "world": {"obstacles": [{"name": "o1", "start_ned_m": [20.0, 0.0, -5.0], "velocity_ned_mps": [-0.5, 0.0, 0.0],
                               "transport": "api"}]},  # on the API link: one port to fuzz
}


@pytest.fixture
def server():
    client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    client.bind(("127.0.0.1", 0))
    client.settimeout(0.2)
    sim = Simulator(scenario_from_dict(SCENARIO), seed=0)
    srv = UdpServer(sim, [LinkAddress("api", 0, client.getsockname()[1])], speed=1.0)
    thread = threading.Thread(target=srv.run, args=(60.0,), daemon=True)
    thread.start()
    try:
        yield sim, client, ("127.0.0.1", srv.local_ports["api"]), thread
    finally:
        srv.stop()
        thread.join(timeout=5)
        srv.close()
        client.close()


def packets(*msgs) -> list[bytes]:
    enc = mavlink2.MAVLink(None, srcSystem=245, srcComponent=190)
    out = []
    for m in msgs:
        out.append(bytes(m.pack(enc)))
        enc.seq = (enc.seq + 1) % 256
    return out


def mangled(rng: np.random.Generator, good: list[bytes]) -> bytes:
    """Random bytes, or a good frame truncated or with bits flipped (never a valid frame)."""
    kind = rng.integers(3)
    if kind == 0:
        return rng.integers(0, 256, int(rng.integers(1, 400)), dtype=np.uint8).tobytes()
    b = bytearray(good[int(rng.integers(len(good)))])
    if kind == 1:
        return bytes(b[: int(rng.integers(1, len(b) - 1))])
    for i in rng.choice(np.arange(1, len(b) - 1), size=int(rng.integers(1, 4)), replace=False):
        b[int(i)] ^= 1 << int(rng.integers(8))
    b[-1] ^= 0x80  # and the CRC's high byte
    return bytes(b)


def test_that_garbage_datagrams_change_nothing_and_a_good_command_still_gets_through(server):
    sim, client, addr, thread = server
    land, arm_off = packets(
        mavlink2.MAVLink_command_long_message(1, 1, 176, 0, 129, 4, 6, 0, 0, 0, 0),   # DO_SET_MODE AUTO.LAND
        mavlink2.MAVLink_command_long_message(1, 1, 400, 0, 0, 21196, 0, 0, 0, 0, 0),  # force disarm
    )
    rng = np.random.default_rng(2024)
    mode0, armed0 = sim.commander.mode, sim.commander.armed
    end, sent = time.monotonic() + FUZZ_S, 0
    while time.monotonic() < end:
        for _ in range(20):
            client.sendto(mangled(rng, [land, arm_off]), addr)
            sent += 1
        time.sleep(0.01)
    time.sleep(0.2)
    assert thread.is_alive() and sent > 500
    assert (sim.commander.mode, sim.commander.armed) == (mode0, armed0) == ("AUTO.LOITER", True)
    assert sim.stats.get("packets_received", 0) == 0 and sim.stats.get("handler_errors", 0) == 0
    assert np.all(np.isfinite(sim.vehicle.position_ned_m))
    # a 2-byte datagram "fd ff" (a MAVLink 2 start, length 255) must not swallow the next command
    client.sendto(b"\xfd\xff", addr)
    client.sendto(land, addr)
    end = time.monotonic() + 2.0
    while sim.commander.mode != "AUTO.LAND" and time.monotonic() < end:
        time.sleep(0.02)
    assert sim.commander.mode == "AUTO.LAND" and sim.stats["packets_received"] == 1


def test_that_absurd_values_in_valid_packets_never_crash_the_server(server):
    sim, client, addr, thread = server
    rng = np.random.default_rng(7)
    absurd = [np.nan, np.inf, -np.inf, 1e30, -1e30, 3.4e38]
    end = time.monotonic() + FUZZ_S
    sent = 0
    while time.monotonic() < end:
        f = lambda: float(rng.choice(absurd))  # noqa: E731
        for data in packets(
            mavlink2.MAVLink_set_position_target_local_ned_message(0, 1, 1, 1, int(rng.integers(65536)),
                                                                    *(f() for _ in range(11))),
            mavlink2.MAVLink_command_long_message(1, 1, int(rng.choice([22, 176, 400, 512])), 0, *(f() for _ in range(7))),
            mavlink2.MAVLink_param_set_message(1, 1, b"COM_OF_LOSS_T", f(), 9),
            mavlink2.MAVLink_odometry_message(0, 1, 0, *(f() for _ in range(3)), [f(), 0, 0, 0], *(f() for _ in range(6)),
                                              [f()] * 21, [f()] * 21, 0, 0, 0),
        ):
            client.sendto(data, addr)
            sent += 1
        time.sleep(0.01)
    time.sleep(0.2)
    assert thread.is_alive() and sent > 200
    assert sim.stats.get("handler_errors", 0) == 0
    assert sim.stats["packets_received"] == sent
    assert np.all(np.isfinite(sim.vehicle.position_ned_m)) and np.all(np.isfinite(sim.vehicle.velocity_ned_mps))
