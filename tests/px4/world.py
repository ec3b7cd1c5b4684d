"""The world around a PX4 SITL flight: obstacles flown and reported as a field would, and SIH's ground truth.

A :class:`World` runs in a thread beside PX4 and the companion:

- It listens on the ground-station port (14550) for PX4's HEARTBEAT, STATUSTEXT and
  LOCAL_POSITION_NED (PX4's boot time, the time base obstacle reports must share).
- It listens on SIH's ground-truth port (19410) for HIL_STATE_QUATERNION and converts
  it to local NED metres about the first fix (the vehicle on the ground at home).
- It flies the scenario's obstacles in straight lines at their speed, starting when
  PX4's HEARTBEAT first shows OFFBOARD, and sends each one as LOCAL_POSITION_NED (with
  the scenario's measurement noise, seeded) from its own system id straight to the
  companion's obstacle link over loopback (``companion_port``; the flight uses 14601 and
  ``fly --obstacles``: the autopilot link refuses other systems' positions), never to PX4
  (PX4 would take ODOMETRY as the vehicle's own external vision).

Units: seconds, metres, NED.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass, field

import numpy as np
from pymavlink import mavutil

logger = logging.getLogger(__name__)

EARTH_RADIUS_M = 6_371_000.0
OFFBOARD_MAIN_MODE = 6


@dataclass
class ObstaclePath:
    """A straight flight from ``start`` to ``end`` at ``speed_mps``, starting at ``t0`` (then it stops)."""

    start: np.ndarray
    end: np.ndarray
    speed_mps: float
    radius_m: float
    noise_cov_m2: np.ndarray
    rate_hz: float

    def position(self, t: float) -> np.ndarray:
        delta = self.end - self.start
        length = float(np.linalg.norm(delta))
        s = min(max(t, 0.0) * self.speed_mps, length)
        return self.start + (delta / length) * s if length > 0 else self.start.copy()

    def velocity(self, t: float) -> np.ndarray:
        delta = self.end - self.start
        length = float(np.linalg.norm(delta))
        if length == 0 or t < 0 or t * self.speed_mps >= length:
            return np.zeros(3)
        return delta / length * self.speed_mps


def paths_from_scenario(path: str) -> list[ObstaclePath]:
    """The ``[[world.obstacles]]`` of a scenario TOML (one waypoint each) as straight paths."""
    import tomllib

    with open(path, "rb") as f:
        data = tomllib.load(f)
    out = []
    for ob in data.get("world", {}).get("obstacles", []):
        out.append(ObstaclePath(np.asarray(ob["start_ned_m"], float), np.asarray(ob["waypoints_ned_m"][-1], float),
                                float(ob["speed_mps"]), float(ob["radius_m"]),
                                np.asarray(ob.get("measurement_cov_m2", np.zeros((3, 3))), float),
                                float(ob.get("report_rate_hz", 10.0))))
    return out


@dataclass
class Observations:
    """What the world saw, for the checks (wall-clock ``time.monotonic`` seconds)."""

    truth: list[tuple[float, np.ndarray]] = field(default_factory=list)          # (t, NED position)
    modes: list[tuple[float, int, int, bool]] = field(default_factory=list)       # (t, main, sub, armed)
    texts: list[tuple[float, str]] = field(default_factory=list)
    obstacles: list[tuple[float, np.ndarray]] = field(default_factory=list)       # (t, (P, 3) true positions)
    estimate: list[tuple[float, np.ndarray]] = field(default_factory=list)       # (t, PX4's LOCAL_POSITION_NED)
    estimate_stamp_s: list[float] = field(default_factory=list)  # LOCAL_POSITION_NED.time_boot_ms of each estimate, s
    # (the truth has no usable stamp: SIH sends HIL_STATE_QUATERNION with time_usec 0)
    offboard_t: float | None = None


class World(threading.Thread):
    """Obstacles and ground truth around a PX4 SITL flight (see the module docstring)."""

    def __init__(self, paths: list[ObstaclePath], seed: int = 0, companion_port: int = 14540,
                 gcs_port: int = 14550, truth_port: int = 19410, first_sysid: int = 101) -> None:
        super().__init__(daemon=True)
        self.paths = paths
        self.rng = np.random.default_rng(seed)
        self.gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs_port}", source_system=255, source_component=190)
        self.truth_link = mavutil.mavlink_connection(f"udpin:127.0.0.1:{truth_port}")
        self.out = mavutil.mavlink_connection(f"udpout:127.0.0.1:{companion_port}", source_system=first_sysid,
                                              source_component=1)
        self.first_sysid = first_sysid
        self.obs = Observations()
        self._halt = threading.Event()
        self._home: tuple[float, float, float] | None = None
        self._px4_boot: tuple[float, int] | None = None     # (monotonic t, PX4 time_boot_ms)
        self.errors: list[str] = []

    def stop(self) -> None:
        self._halt.set()
        self.join(timeout=5.0)
        for conn in (self.gcs, self.truth_link, self.out):
            conn.close()

    def px4_time_ms(self, now: float) -> int | None:
        if self._px4_boot is None:
            return None
        t, ms = self._px4_boot
        return int(ms + (now - t) * 1000.0)

    def run(self) -> None:
        try:
            self._run()
        except Exception as exc:  # reported by the test, never swallowed
            logger.exception("world thread failed")
            self.errors.append(repr(exc))

    def _run(self) -> None:
        next_report = [time.monotonic()] * len(self.paths)
        last_gcs_hb = 0.0
        while not self._halt.is_set():
            now = time.monotonic()
            for _ in range(200):
                msg = self.gcs.recv_match(blocking=False)
                if msg is None:
                    break
                self._on_gcs(now, msg)
            for _ in range(200):
                msg = self.truth_link.recv_match(type="HIL_STATE_QUATERNION", blocking=False)
                if msg is None:
                    break
                self._on_truth(now, msg)
            if now - last_gcs_hb >= 1.0:     # a ground station, so PX4 keeps its GCS link alive
                self.gcs.mav.heartbeat_send(6, 8, 0, 0, 4)
                last_gcs_hb = now
            t_px4 = self.px4_time_ms(now)
            if t_px4 is not None:
                t_move = -1.0 if self.obs.offboard_t is None else now - self.obs.offboard_t
                truth = np.array([p.position(t_move) for p in self.paths]) if self.paths else np.zeros((0, 3))
                for i, path in enumerate(self.paths):
                    if now >= next_report[i]:
                        next_report[i] = now + 1.0 / path.rate_hz
                        noisy = truth[i] + self.rng.multivariate_normal(np.zeros(3), path.noise_cov_m2)
                        vel = path.velocity(t_move)
                        self.out.mav.srcSystem = self.first_sysid + i
                        self.out.mav.local_position_ned_send(t_px4 % (1 << 32), *noisy, *vel)
                if self.paths:
                    self.obs.obstacles.append((now, truth))
            time.sleep(0.01)

    def _on_gcs(self, now: float, msg) -> None:
        kind = msg.get_type()
        if msg.get_srcSystem() != 1 or msg.get_srcComponent() != 1:
            return
        if kind == "HEARTBEAT" and msg.autopilot == 12:
            main, sub = (msg.custom_mode >> 16) & 0xFF, (msg.custom_mode >> 24) & 0xFF
            armed = bool(msg.base_mode & 128)
            self.obs.modes.append((now, main, sub, armed))
            if main == OFFBOARD_MAIN_MODE and armed and self.obs.offboard_t is None:
                self.obs.offboard_t = now
        elif kind == "STATUSTEXT":
            self.obs.texts.append((now, msg.text))
        elif kind in ("LOCAL_POSITION_NED", "ATTITUDE"):
            self._px4_boot = (now, int(msg.time_boot_ms))
            if kind == "LOCAL_POSITION_NED":
                self.obs.estimate.append((now, np.array([msg.x, msg.y, msg.z])))
                self.obs.estimate_stamp_s.append(msg.time_boot_ms * 1e-3)

    def _on_truth(self, now: float, msg) -> None:
        lat, lon, alt = msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3
        if self._home is None:
            self._home = (lat, lon, alt)
        lat0, lon0, alt0 = self._home
        north = math.radians(lat - lat0) * EARTH_RADIUS_M
        east = math.radians(lon - lon0) * EARTH_RADIUS_M * math.cos(math.radians(lat0))
        self.obs.truth.append((now, np.array([north, east, -(alt - alt0)])))
