"""mavsim speed in lockstep: simulated seconds per wall second.

Rows: the antipodal scenario (vehicle + 3 obstacles) with no client; with a client
streaming velocity setpoints at 20 Hz (encoding its packets, advancing 0.05 s per
setpoint); and the same client also decoding every packet mavsim sends (what a
companion harness pays). Target: at least 50x real time.
"""

from __future__ import annotations

import time
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink2

from mavsim.lockstep import LockstepSimulator

SCENARIO = Path(__file__).resolve().parents[2] / "configs" / "antipodal.toml"
SIM_S = 60.0
TARGET = 50.0


def _run(client: bool, decode: bool) -> tuple[float, int]:
    sim = LockstepSimulator.from_file(SCENARIO, seed=0)
    enc = mavlink2.MAVLink(None, srcSystem=245, srcComponent=190)
    dec = mavlink2.MAVLink(None)
    packets = 0
    t0 = time.perf_counter()
    steps = round(SIM_S / 0.05)
    for k in range(steps):
        if client:
            msg = mavlink2.MAVLink_set_position_target_local_ned_message(
                int(sim.time_s * 1000), 1, 1, 1, 3527, 0, 0, 0, 1.0, 0.0, 0.0, 0, 0, 0, 0, 0)
            sim.write(bytes(msg.pack(enc)))
            enc.seq = (enc.seq + 1) % 256
            if k == 20:
                sim.write(bytes(mavlink2.MAVLink_command_long_message(1, 1, 176, 0, 29, 6, 0, 0, 0, 0, 0).pack(enc)))
        out = sim.advance(0.05)
        packets += len(out)
        if decode:
            for _, data in out:
                dec.parse_buffer(data)
    wall = time.perf_counter() - t0
    if client:
        assert sim.truth.mode == "OFFBOARD", sim.truth.mode
    return SIM_S / wall, packets


def run() -> list[dict]:
    rows = []
    for name, client, decode, note in (
        ("realtime_factor_no_client", False, False, "antipodal: vehicle + 3 obstacles, 60 s simulated"),
        ("realtime_factor_client_20hz", True, False, "client streams SET_POSITION_TARGET_LOCAL_NED at 20 Hz"),
        ("realtime_factor_client_20hz_decoding", True, True, "client also decodes every packet with pymavlink"),
    ):
        factor, packets = _run(client, decode)
        rows.append({"name": name, "value": factor, "unit": "sim s / wall s", "target": f">= {TARGET:g}",
                     "note": f"{note}; {packets / SIM_S:.0f} packets per simulated s"})
    return rows
