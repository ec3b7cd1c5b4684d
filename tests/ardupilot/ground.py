"""The test's side of an ArduCopter SITL flight: a ground station with the simulator's truth, the
scenario's obstacles on the companion's obstacle link, and (optionally) a relay on the companion link.

- **Ground station** on the SITL's SERIAL0 link (it sends from an ephemeral port to 127.0.0.1:(14550+N)
  and accepts only datagrams from there): a GCS HEARTBEAT at 1 Hz, and the streams this link needs,
  asked with MAV_CMD_SET_MESSAGE_INTERVAL (stream rates default to zero; a request acts on its own link
  only): SIM_STATE (the simulator's truth) at 50 Hz, LOCAL_POSITION_NED (the vehicle's estimate) at 10 Hz,
  GPS_GLOBAL_ORIGIN and HOME_POSITION at 1 Hz. Truth is SIM_STATE's ``lat_int``/``lon_int`` (degE7; its
  float lat/lon hold degE7 quantised to ~0.35 m) and ``alt`` (m AMSL), turned into the local NED frame
  about GPS_GLOBAL_ORIGIN by ArduPilot's own convention (north = dlat * 0.011131884502 m, east = dlon *
  0.011131884502 * cos(latitude) m, down = -dalt).
- **Engagement** is the companion's STATUSTEXT "ENGAGED: ..." (ArduPilot forwards it to this link):
  ArduCopter takes off in GUIDED, so GUIDED alone does not say that the companion is in control. The
  obstacles' scripted motion (:class:`mavsim.obstacles.ObstacleSystem`, as ``mavsim traffic`` plays them)
  starts then; before that they report from their start points. :class:`mavsim.referee.Referee` judges
  the truth and the estimate against them.
- **ADS-B**: an obstacle with ``transport = "adsb"`` is sent as ADSB_VEHICLE from its own system into
  SITL's ground link (as a ground ADS-B receiver would), lat/lon about the GPS_GLOBAL_ORIGIN this link
  received (nothing before it: :attr:`Ground.adsb_held`). ArduCopter with ``ADSB_TYPE`` 0 (its default)
  forwards every ADSB_VEHICLE of another system to its other links as it is, so the companion receives
  the traffic on its autopilot link, as PX4's re-stream reaches it.
- **Relay** (``relay=True``): SITL's companion link goes to a socket of ours and on to the companion's
  port, both ways; :meth:`Ground.drop_pose` makes it drop the vehicle's LOCAL_POSITION_NED from then on
  (the companion loses its estimate while ArduCopter keeps flying).
"""

from __future__ import annotations

import logging
import math
import select
import socket
import threading
import time

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav

from mavsim.obstacles import OWN_API_LINK, OWN_OBSTACLE_LINK, ObstacleSystem
from mavsim.referee import Referee
from mavsim.scenario import Scenario

logger = logging.getLogger(__name__)

GCS_SYSID, GCS_COMPID = 255, 190
GUIDED, LOITER, BRAKE = 4, 5, 17
MODE_NAMES = {0: "STABILIZE", 4: "GUIDED", 5: "LOITER", 6: "RTL", 9: "LAND", 17: "BRAKE", 19: "AVOID_ADSB"}
DEG_E7_M = 0.011131884502
STREAMS = ((108, 50.0), (32, 10.0), (49, 1.0), (242, 1.0))


def _parser() -> mav.MAVLink:
    p = mav.MAVLink(None)
    p.robust_parsing = True
    return p


def _parse(parser: mav.MAVLink, data: bytes) -> list:
    parser.buf, parser.buf_index = bytearray(), 0
    try:
        return [m for m in (parser.parse_buffer(data) or []) if m.get_type() != "BAD_DATA"]
    except Exception:
        return []


class Ground:
    """Ground station, obstacle player and relay of one SITL flight, run in a thread (see the module docstring)."""

    def __init__(self, scenario: Scenario, gcs_port: int, obstacle_port: int, seed: int = 0,
                 relay_to: int | None = None) -> None:
        self.scenario = scenario
        self.t0 = time.monotonic()
        self.gcs = self._bind(gcs_port)
        self.out = self._bind(0)
        self.obstacle_addr = ("127.0.0.1", obstacle_port)
        self.relay_ap = self._bind(0) if relay_to is not None else None
        self.relay_c = self._bind(0) if relay_to is not None else None
        self.relay_to = relay_to
        self._ap_addr: tuple | None = None       # SITL's ground-link address (learned)
        self._relay_ap_addr: tuple | None = None  # SITL's companion-link address (learned)
        self._dropping = False
        self.dropped = 0
        self._encoders: dict = {}
        seeds = np.random.SeedSequence(int(seed)).spawn(len(scenario.obstacles))
        self.systems = [ObstacleSystem(ob, scenario.obstacle_sysid_base + i, scenario.obstacle_compid,
                                       np.random.Generator(np.random.PCG64(seeds[i])), i)
                        for i, ob in enumerate(scenario.obstacles)]
        self.referees = {"truth": Referee(scenario, "truth"), "estimate": Referee(scenario, "estimate")}
        self.origin: tuple[float, float, float] | None = None   # lat, lon degE7, alt m
        self.adsb_sent = 0     # ADSB_VEHICLE sent into SITL's ground link
        self.adsb_held = 0     # ... not sent: no GPS_GLOBAL_ORIGIN (or no SITL address) yet
        self.engaged_t: float | None = None
        self.mode: str | None = None
        self.modes: list[tuple[float, str]] = []
        self.texts: list[tuple[float, str]] = []
        self.truth: list[tuple[float, np.ndarray, np.ndarray]] = []   # t, NED m, NED m/s
        self.estimate: list[tuple[float, np.ndarray]] = []
        self._parser = _parser()
        self._relay_parser = _parser()
        self._stop = threading.Event()
        self._next_hb = self._next_req = 0.0
        self._thread = threading.Thread(target=self._run, daemon=True)

    @property
    def relay_port(self) -> int:
        return self.relay_ap.getsockname()[1]

    def _bind(self, port: int) -> socket.socket:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", port))
        s.setblocking(False)
        return s

    def now(self) -> float:
        return time.monotonic() - self.t0

    def motion(self, t: float) -> float:
        return 0.0 if self.engaged_t is None else max(0.0, t - self.engaged_t)

    def drop_pose(self) -> None:
        """From now on the relay drops the vehicle's LOCAL_POSITION_NED on the companion link."""
        self._dropping = True

    def start(self) -> Ground:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        for s in (self.gcs, self.out, self.relay_ap, self.relay_c):
            if s is not None:
                s.close()

    def _send(self, sock, addr, sysid, compid, msg) -> None:
        enc = self._encoders.get((sysid, compid))
        if enc is None:
            enc = self._encoders[(sysid, compid)] = mav.MAVLink(None, sysid, compid)
        data = bytes(msg.pack(enc))
        enc.seq = (enc.seq + 1) % 256
        try:
            sock.sendto(data, addr)
        except OSError:
            pass

    def _run(self) -> None:
        socks = [s for s in (self.gcs, self.relay_ap, self.relay_c) if s is not None]
        while not self._stop.is_set():
            select.select(socks, [], [], 0.005)
            t = self.now()
            self._duties(t)
            self._receive(t)

    def _duties(self, t: float) -> None:
        if self._ap_addr is not None and t >= self._next_hb:
            self._next_hb = t + 1.0
            self._send(self.gcs, self._ap_addr, GCS_SYSID, GCS_COMPID, mav.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
        if self._ap_addr is not None and t >= self._next_req and (self.origin is None or not self.truth or t < 60):
            self._next_req = t + 5.0
            for msg_id, hz in STREAMS:
                self._send(self.gcs, self._ap_addr, GCS_SYSID, GCS_COMPID, mav.MAVLink_command_long_message(
                    0, 0, 511, 0, msg_id, 1e6 / hz, 0, 0, 0, 0, 0))
        now_us = round(t * 1e6)
        for system in self.systems:
            for route, msg in system.due(now_us, self.motion(t)):
                if route == OWN_OBSTACLE_LINK:
                    self._send(self.out, self.obstacle_addr, system.sysid, system.compid, msg)
                elif route == OWN_API_LINK and system.transport == "adsb":
                    if self.origin is None or self._ap_addr is None:
                        self.adsb_held += 1
                    else:
                        self._send(self.gcs, self._ap_addr, system.sysid, system.compid, msg)
                        self.adsb_sent += 1

    def _receive(self, t: float) -> None:
        for _ in range(200):
            got = False
            for sock in (self.gcs, self.relay_ap, self.relay_c):
                if sock is None:
                    continue
                try:
                    data, addr = sock.recvfrom(65535)
                except (BlockingIOError, InterruptedError):
                    continue
                except OSError:
                    continue
                got = True
                if sock is self.gcs:
                    self._ap_addr = addr
                    for m in _parse(self._parser, data):
                        self._on_gcs(t, m)
                elif sock is self.relay_ap:
                    self._relay_ap_addr = addr
                    if self._dropping:
                        msgs = _parse(self._relay_parser, data)
                        keep = b"".join(bytes(m.get_msgbuf()) for m in msgs if m.get_type() != "LOCAL_POSITION_NED")
                        self.dropped += sum(m.get_type() == "LOCAL_POSITION_NED" for m in msgs)
                        data = keep
                    if data:
                        self.relay_c.sendto(data, ("127.0.0.1", self.relay_to))
                else:   # from the companion, to SITL
                    if self._relay_ap_addr is not None:
                        self.relay_ap.sendto(data, self._relay_ap_addr)
            if not got:
                return

    def _on_gcs(self, t: float, m) -> None:
        kind = m.get_type()
        if kind == "HEARTBEAT" and m.get_srcComponent() == 1 and m.autopilot == 3:
            mode = MODE_NAMES.get(m.custom_mode, str(m.custom_mode)) + ("" if m.base_mode & 128 else " disarmed")
            if mode != self.mode:
                self.mode = mode
                self.modes.append((round(t, 3), mode))
        elif kind == "STATUSTEXT":
            text = str(m.text).strip()
            self.texts.append((round(t, 3), text))
            if self.engaged_t is None and text.startswith("ENGAGED"):
                self.engaged_t = t
                logger.info("t=%.2f companion engaged: obstacles start moving", t)
        elif kind == "GPS_GLOBAL_ORIGIN" and self.origin is None:
            self.origin = (m.latitude, m.longitude, m.altitude * 1e-3)
            for system in self.systems:   # ADS-B positions about the vehicle's own origin
                system.origin = (m.latitude * 1e-7, m.longitude * 1e-7, m.altitude * 1e-3)
        elif kind == "SIM_STATE" and self.origin is not None:
            lat0, lon0, alt0 = self.origin
            lat, lon = getattr(m, "lat_int", 0) or m.lat, getattr(m, "lon_int", 0) or m.lon
            coslat = math.cos(math.radians((lat + lat0) * 0.5e-7))
            p = np.array([(lat - lat0) * DEG_E7_M, (lon - lon0) * DEG_E7_M * coslat, -(m.alt - alt0)])
            v = np.array([m.vn, m.ve, m.vd], float)
            self.truth.append((t, p, v))
            if self.engaged_t is not None:
                self.referees["truth"].update(self.motion(t), p)
        elif kind == "LOCAL_POSITION_NED":
            p = np.array([m.x, m.y, m.z], float)
            self.estimate.append((t, p))
            if self.engaged_t is not None:
                self.referees["estimate"].update(self.motion(t), p)
