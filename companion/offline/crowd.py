"""A crowd of MAVLink systems for real-time stress runs: many stationary obstacles reporting over UDP.

``companion demo --realtime --crowd N`` (and the real-time tests) start a :class:`Crowd`
beside mavsim: N systems, each with its own MAVLink identity (system 30.., component
198), placed off the mission's route (:func:`positions_off_route`), each sending
ODOMETRY to the companion's obstacle port (a receive-only obstacle link) at ``rate_hz``,
with the accuracy of a perception source (position standard deviation 0.2 m, velocity
0.1 m/s, in the message's covariances). The reports are stamped on the vehicle's boot clock, which the crowd learns by listening where mavsim sends its
ground-station stream (any message with ``time_boot_ms``), as an obstacle perception
process on the vehicle would share its clock. Until it has heard the vehicle, it sends
nothing. One thread; every socket operation is non-blocking and every wait bounded.
"""

from __future__ import annotations

import logging
import math
import socket
import threading
import time
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

logger = logging.getLogger(__name__)

FIRST_SYSTEM_ID = 30
COMPONENT_ID = 198  # distinct from mavsim's obstacle component, so keys never collide
MAX_SYSTEMS = 200
POSITION_VAR_M2 = 0.04     # (0.2 m)^2, reported in each ODOMETRY's pose covariance
VELOCITY_VAR_M2PS2 = 0.01  # (0.1 m/s)^2
_MAV_FRAME_LOCAL_NED = 1


def _upper_triangle(diagonal: float) -> list[float]:
    """MAVLink's 21-element row-major upper triangle of a 6x6 covariance: ``diagonal`` on the x, y, z entries, 0 elsewhere."""
    cov = [0.0] * 21
    for i in (0, 6, 11):  # (0,0), (1,1), (2,2)
        cov[i] = diagonal
    return cov


def positions_off_route(
    start: np.ndarray, goal: np.ndarray, n: int, *, seed: int = 0, lateral_m: tuple[float, float] = (6.0, 10.0)
) -> np.ndarray:
    """``n`` points (NED m) beside the straight route from ``start`` to ``goal``.

    Each lies ``lateral_m`` metres to the left or right of the route horizontally (within
    the companion's default 10 m sensing range of it), along the route from 2 m before
    the start to 2 m past the goal, within 1 m of the route's altitude.
    """
    rng = np.random.default_rng([seed, 0xC20D])
    route = np.asarray(goal, float) - np.asarray(start, float)
    length = float(np.linalg.norm(route[:2]))
    along = route / max(float(np.linalg.norm(route)), 1e-9)
    side = np.array([-along[1], along[0], 0.0])
    side /= max(float(np.linalg.norm(side)), 1e-9)
    s = rng.uniform(-2.0, length + 2.0, n)
    d = rng.uniform(*lateral_m, n) * rng.choice([-1.0, 1.0], n)
    dz = rng.uniform(-1.0, 1.0, n)
    return np.asarray(start, float) + s[:, None] * along + d[:, None] * side + dz[:, None] * np.array([0.0, 0.0, 1.0])


@dataclass
class CrowdStats:
    sent: int = 0
    vehicle_clock_heard: bool = False


class Crowd:
    """N stationary systems reporting ODOMETRY to ``target`` (see the module docstring).

    Parameters
    ----------
    positions : (N, 3) array
        NED metres, N <= 200.
    target : (host, port)
        The companion's UDP port.
    clock_port : int
        Local port where the vehicle's ground-station stream arrives (its boot clock).
    rate_hz : float
        Reports per second per system (spread evenly over the period).
    """

    def __init__(self, positions: np.ndarray, target: tuple[str, int], clock_port: int, *, rate_hz: float = 1.0) -> None:
        positions = np.asarray(positions, dtype=float).reshape(-1, 3)
        if len(positions) > MAX_SYSTEMS:
            raise ValueError(f"at most {MAX_SYSTEMS} crowd systems, got {len(positions)}")
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate_hz must be finite and > 0, got {rate_hz!r}")
        self.positions = positions
        self.target = target
        self.rate_hz = float(rate_hz)
        self.stats = CrowdStats()
        self._pose_cov = _upper_triangle(POSITION_VAR_M2)
        self._velocity_cov = _upper_triangle(VELOCITY_VAR_M2PS2)
        self._senders = [mavlink2.MAVLink(None, FIRST_SYSTEM_ID + i, COMPONENT_ID) for i in range(len(positions))]
        self._out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._out.bind(("127.0.0.1", 0))
        self._out.setblocking(False)
        self._clock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._clock.bind(("127.0.0.1", clock_port))
        self._clock.setblocking(False)
        self._parser = mavlink2.MAVLink(None, 255, 0)
        self._parser.robust_parsing = True
        self._offset_s: float | None = None  # local monotonic minus vehicle boot time
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="crowd", daemon=True)

    def start(self) -> "Crowd":
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self._out.close()
        self._clock.close()

    def _listen(self) -> None:
        for _ in range(100):
            try:
                data = self._clock.recv(65536)
            except (BlockingIOError, OSError):
                break
            try:
                msgs = self._parser.parse_buffer(data) or []
            except Exception:
                msgs = []
            self._parser.buf, self._parser.buf_index = bytearray(), 0
            for m in msgs:
                boot_ms = getattr(m, "time_boot_ms", None)
                if boot_ms is not None and m.get_srcSystem() == 1:
                    offset = time.monotonic() - boot_ms * 1e-3
                    self._offset_s = offset if self._offset_s is None else min(self._offset_s, offset)
                    self.stats.vehicle_clock_heard = True
        try:  # the companion's udpin answers every address it heard: drain the copies it sends us
            while self._out.recv(65536):
                pass
        except (BlockingIOError, OSError):
            pass

    def _run(self) -> None:
        n = len(self._senders)
        slots = 10  # a period in ten slices: no burst of N datagrams at once
        i = 0
        next_t = time.monotonic()
        while not self._stop.is_set():
            self._listen()
            now = time.monotonic()
            if self._offset_s is not None and now >= next_t:
                boot_us = int((now - self._offset_s) * 1e6)
                chunk = range(i * n // slots, (i + 1) * n // slots)
                for k in chunk:
                    p = self.positions[k]
                    msg = mavlink2.MAVLink_odometry_message(
                        boot_us, _MAV_FRAME_LOCAL_NED, _MAV_FRAME_LOCAL_NED, p[0], p[1], p[2], [1.0, 0.0, 0.0, 0.0],
                        0.0, 0.0, 0.0, 0.0, 0.0, 0.0, self._pose_cov, self._velocity_cov, 0, 0, 100)
                    try:
                        self._out.sendto(msg.pack(self._senders[k]), self.target)
                        self.stats.sent += 1
                    except OSError:
                        pass
                    self._senders[k].seq = (self._senders[k].seq + 1) % 256
                i = (i + 1) % slots
                next_t += 1.0 / (self.rate_hz * slots)
                if next_t < now:
                    next_t = now
            self._stop.wait(0.005)
