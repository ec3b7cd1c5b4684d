"""Fuzz-style robustness: random bytes, corrupted and truncated packets, and valid
packets with random contents. Bounded in time (about 3 s in all).

Invalid input must change nothing: a simulator fed it produces byte-identical output
to one fed nothing. Valid-but-absurd input must never crash the simulator.
"""

from __future__ import annotations

import time

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from mavsim.lockstep import LockstepSimulator
from tests.support.mavsim_client import AIRBORNE, with_obstacles

BUDGET_S = 1.4


def _valid_packets(rng: np.random.Generator) -> list[bytes]:
    enc = mavlink2.MAVLink(None, srcSystem=245, srcComponent=190)
    msgs = [
        mavlink2.MAVLink_command_long_message(1, 1, 176, 0, 29, 6, 0, 0, 0, 0, 0),
        mavlink2.MAVLink_command_long_message(1, 1, 400, 0, 0, 21196, 0, 0, 0, 0, 0),
        mavlink2.MAVLink_command_long_message(1, 1, 21, 0, 0, 0, 0, 0, 0, 0, 0),
        mavlink2.MAVLink_set_mode_message(1, 1, 6 << 16),
        mavlink2.MAVLink_set_position_target_local_ned_message(0, 1, 1, 1, 3527, 0, 0, 0, 2, 1, -1, 0, 0, 0, 0, 0),
        mavlink2.MAVLink_param_set_message(1, 1, b"COM_OF_LOSS_T", 5.0, 9),
        mavlink2.MAVLink_mission_request_list_message(1, 1, 0),
    ]
    out = []
    for m in msgs:
        out.append(bytes(m.pack(enc)))
        enc.seq = (enc.seq + 1) % 256
    return out


def _corrupt(pkt: bytes, rng: np.random.Generator) -> bytes:
    kind = rng.integers(3)
    b = bytearray(pkt)
    if kind == 0:  # flip 1-3 bytes after the magic
        for _ in range(rng.integers(1, 4)):
            i = int(rng.integers(1, len(b)))
            b[i] ^= int(rng.integers(1, 256))
    elif kind == 1:  # break the checksum
        b[-1] ^= 0x5A
    else:  # truncate, then a fresh magic byte so the next packet resyncs the stream
        b = b[: int(rng.integers(1, len(b) - 1))]
    return bytes(b)


def test_that_invalid_input_changes_nothing_and_never_crashes():
    rng = np.random.default_rng(12345)
    sc = with_obstacles(AIRBORNE, 2)
    fed, clean = LockstepSimulator(sc, seed=4), LockstepSimulator(sc, seed=4)
    valid = _valid_packets(rng)
    t0 = time.monotonic()
    chunks = 0
    while time.monotonic() - t0 < BUDGET_S:
        for _ in range(20):
            if rng.random() < 0.5:
                data = rng.integers(0, 256, int(rng.integers(1, 300)), dtype=np.uint8).tobytes()
            else:
                data = _corrupt(valid[int(rng.integers(len(valid)))], rng)
            fed.write(data)
            chunks += 1
        assert fed.advance(0.05) == clean.advance(0.05)
    s = fed.summary()["link"]
    assert chunks > 100
    assert s.get("packets_received", 0) == 0 and s.get("handler_errors", 0) == 0
    assert fed.truth.mode == clean.truth.mode == "AUTO.LOITER" and fed.truth.armed


def _random_message(rng: np.random.Generator):
    f = lambda: float(rng.choice([np.nan, np.inf, -np.inf, 0.0, 1e30, -1e30, rng.normal() * 10]))  # noqa: E731
    i = lambda hi: int(rng.integers(0, hi))  # noqa: E731
    kind = i(8)
    if kind == 0:
        return mavlink2.MAVLink_command_long_message(i(3), i(3), int(rng.choice([176, 400, 22, 21, 20, 512, 511, 510, 520, i(65536)])),
                                                     i(256), f(), f(), f(), f(), f(), f(), f())
    if kind == 1:
        return mavlink2.MAVLink_set_position_target_local_ned_message(
            i(2**32), i(3), i(3), i(12), i(65536), *(f() for _ in range(11)))
    if kind == 2:
        return mavlink2.MAVLink_set_mode_message(i(3), i(256), i(2**32))
    if kind == 3:
        name = rng.choice([b"COM_OF_LOSS_T", b"COM_OBL_RC_ACT", b"MPC_XY_VEL_MAX", b"\xff\xfe", b"X" * 16])
        return mavlink2.MAVLink_param_set_message(i(3), i(3), name, f(), i(12))
    if kind == 4:
        return mavlink2.MAVLink_param_request_read_message(i(3), i(3), b"NOPE", int(rng.integers(-5, 40)))
    if kind == 5:
        return mavlink2.MAVLink_command_int_message(i(3), i(3), i(20), int(rng.choice([176, 400, 22, 512])), 0, 0,
                                                    f(), f(), f(), f(), i(2**31), i(2**31), f())
    if kind == 6:
        return mavlink2.MAVLink_timesync_message(int(rng.integers(0, 2**62)), int(rng.integers(0, 2**62)))
    return mavlink2.MAVLink_ping_message(int(rng.integers(0, 2**62)), i(2**32), i(3), i(3))


def test_that_valid_packets_with_random_contents_never_crash_the_simulator():
    rng = np.random.default_rng(99)
    sim = LockstepSimulator(with_obstacles(AIRBORNE, 1), seed=1)
    enc = mavlink2.MAVLink(None, srcSystem=245, srcComponent=190)
    t0 = time.monotonic()
    sent = 0
    while time.monotonic() - t0 < BUDGET_S:
        for _ in range(10):
            sim.write(bytes(_random_message(rng).pack(enc)))
            enc.seq = (enc.seq + 1) % 256
            sent += 1
        out = sim.advance(0.05)
        assert all(len(data) >= 12 for _, data in out)
    s = sim.summary()
    assert sent > 100 and s["link"]["packets_received"] == sent
    assert s["link"].get("handler_errors", 0) == 0
    assert np.all(np.isfinite(sim.truth.drone_position_ned_m)) and sim.truth.drone_position_ned_m[2] <= 0.0
