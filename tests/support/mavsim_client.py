"""Shared helpers for the mavsim tests: a tiny PX4 offboard client over lockstep.

(No tests here; the other ``test_mavsim_*`` modules import it.)
"""

from __future__ import annotations

import math

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from mavsim.lockstep import LockstepSimulator

VEL_ONLY = 3527  # type_mask: velocity only, yaw and yaw rate ignored
POS_ONLY = 3576
AIRBORNE = {"vehicle": {"start_ned_m": [0.0, 0.0, -5.0]}}
GROUND = {"vehicle": {"start_ned_m": [0.0, 0.0, 0.0]}}


def with_obstacles(base: dict, n: int = 1, **fields) -> dict:
    """``base`` with ``n`` obstacles flying south; ``fields`` set more keys of each (e.g. ``transport``)."""
    obs = [{"name": f"o{i + 1}", "start_ned_m": [10.0 + i, 5.0 * i, -5.0], "velocity_ned_mps": [-0.5, 0.0, 0.0],
            "measurement_cov_m2": [[0.02, 0, 0], [0, 0.03, 0], [0, 0, 0.04]], **fields} for i in range(n)]
    return {**base, "world": {"obstacles": obs}}


class Client:
    """Sends like a MAVSDK/pymavlink offboard client (sysid 245, compid 190); records replies."""

    def __init__(self, scenario, seed: int = 0, tlog=None) -> None:
        self.sim = LockstepSimulator(scenario, seed=seed, tlog=tlog)
        self.enc = mavlink2.MAVLink(None, srcSystem=245, srcComponent=190)
        self.dec = mavlink2.MAVLink(None)
        self.dec.robust_parsing = True
        self.log: list = []  # (t_s, msg) of everything received

    def send(self, msg) -> None:
        buf = msg.pack(self.enc)
        self.enc.seq = (self.enc.seq + 1) % 256
        self.sim.write(buf)

    def run(self, dt: float, setpoint=None, rate_hz: float = 20.0) -> list:
        """Advance ``dt`` s, sending ``setpoint()`` at ``rate_hz`` if given; return messages."""
        got = []
        step = 1.0 / rate_hz if setpoint is not None else dt
        t_end = self.sim.time_s + dt
        while self.sim.time_s < t_end - 1e-9:
            if setpoint is not None:
                self.send(setpoint())
            api = self.sim.advance(min(step, t_end - self.sim.time_s))
            for t, data in sorted(api + self.sim.take_obstacle_packets(), key=lambda tp: tp[0]):  # both ports
                for m in self.dec.parse_buffer(data) or []:
                    got.append((t, m))
        self.log += got
        return [m for _, m in got]

    def command(self, cmd: int, *params: float, run_s: float = 0.1) -> list:
        p = list(params) + [0.0] * (7 - len(params))
        self.send(mavlink2.MAVLink_command_long_message(1, 1, cmd, 0, *p))
        return self.run(run_s)

    def set_mode_offboard(self, setpoint=None) -> list:
        self.send(mavlink2.MAVLink_command_long_message(1, 1, 176, 0, 29, 6, 0, 0, 0, 0, 0))
        return self.run(1.0, setpoint)

    def heartbeat(self, msgs=None):
        hbs = [m for m in (msgs if msgs is not None else [m for _, m in self.log])
               if m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 1]
        return hbs[-1]

    def mode(self, msgs=None) -> str:
        return mavutil.mode_string_v10(self.heartbeat(msgs))


def vel_sp(vx: float = 0.0, vy: float = 0.0, vz: float = 0.0, frame: int = 1, mask: int = VEL_ONLY):
    return lambda: mavlink2.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, frame, mask, 0, 0, 0, vx, vy, vz, 0, 0, 0, 0, 0)


def of_type(msgs, mtype: str, src: int | None = 1):
    return [m for m in msgs if m.get_type() == mtype and (src is None or m.get_srcSystem() == src)]


def acks(msgs, command: int | None = None):
    return [m for m in of_type(msgs, "COMMAND_ACK") if command is None or m.command == command]


def texts(msgs) -> list[str]:
    return [m.text for m in of_type(msgs, "STATUSTEXT")]


__all__ = ["Client", "vel_sp", "of_type", "acks", "texts", "AIRBORNE", "GROUND", "with_obstacles", "math"]


def hover_record(scenario: dict, seed: int, seconds: float, types: tuple[str, ...]):
    """Fly ``scenario`` (hovering, nobody commanding) in 0.1 s lockstep steps for ``seconds``: the true
    hover point (NED m) at the start, (sim time s, message) of each message of ``types``, and the
    autopilot's mode changes."""
    parser = mavlink2.MAVLink(None)
    out = []
    with LockstepSimulator(scenario, seed=seed) as sim:
        truth = sim.truth.drone_position_ned_m.copy()
        for _ in range(int(seconds / 0.1)):
            for _, packet in sim.advance(0.1):
                for msg in parser.parse_buffer(packet) or []:
                    if msg.get_type() in types:
                        out.append((sim.time_s, msg))
        modes = [m for _, m in sim.simulator.commander.mode_changes]
    return truth, out, modes
