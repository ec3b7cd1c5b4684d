"""Traffic player: a scenario's scripted obstacles played into a real autopilot, with a referee.

For PX4 SITL or a vehicle, where mavsim's own vehicle is not in the loop. The player is a
ground station on the autopilot's GCS link (PX4 SITL: it sends to 14550, listens on
18570) and a sender on the companion's obstacle link:

- It sends a GCS HEARTBEAT at 1 Hz, finds the autopilot by its HEARTBEAT (component 1, not
  a GCS, not MAV_AUTOPILOT_INVALID) and requests GPS_GLOBAL_ORIGIN (MAV_CMD_REQUEST_MESSAGE
  49: PX4 sends it once and then only on change) and HOME_POSITION every second until the
  origin is known. Without GPS_GLOBAL_ORIGIN, HOME_POSITION's geodetic position less its
  local position stands in for it after :data:`HOME_FALLBACK_S`.
- Each obstacle travels as its ``transport`` says (:mod:`mavsim.obstacles`, the same
  report code mavsim flies): ``"link"`` -- its own system on the obstacle link (ODOMETRY,
  LOCAL_POSITION_NED, UTM_GLOBAL_POSITION, OPEN_DRONE_ID_LOCATION); ``"adsb"`` --
  ADSB_VEHICLE from its own system into the autopilot's GCS link, lat/lon/alt from the local
  NED position about the autopilot's origin by PX4's projection (:mod:`mavsim.geo`), which
  PX4 re-streams to the companion (docs/PX4_FACTS.md). ``"api"`` (ODOMETRY towards the
  autopilot) is refused: PX4 may fuse another system's ODOMETRY as its own vision.
- The scripted motion starts when the autopilot's HEARTBEAT first shows it armed in
  OFFBOARD (its personality's ``engaged``, :mod:`mavsim.personalities`; PX4 by default), or
  at once (``start = "now"``). Before that
  every obstacle reports from its start point, at rest.
- It records: the vehicle's position from the autopilot's LOCAL_POSITION_NED (its
  estimate) and, when a ground-truth port is given, from SIH's HIL_STATE_QUATERNION
  (geodetic, turned into the local frame about the same origin), mode changes and STATUSTEXT;
  :mod:`mavsim.referee` keeps the smallest distances. ``record`` writes JSON lines at
  :data:`RECORD_PERIOD_S` (time, mode, the obstacles' true positions, truth, estimate).

Frames and units: local NED metres of the autopilot (its EKF origin, z down), seconds of
the player's monotonic clock since it started (``t_s``) and since engagement (``motion_s``).
A fleet's vehicles each have their own EKF origin; there the scenario's frame is anchored at
``frame_origin`` (one geodetic point for the whole fleet) instead: obstacles are placed,
truth and estimates recorded and refereed in that frame, and reports in a local frame
(ODOMETRY, LOCAL_POSITION_NED on the obstacle link) are shifted into the vehicle's own frame
once its origin is known (held until then). With ``start = "manual"`` the motion starts when
:meth:`TrafficPlayer.engage` is called (one start for several players).
"""

from __future__ import annotations

import json
import logging
import select
import socket
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from mavsim.errors import ScenarioError, SimulationError
from mavsim.geo import global_to_ned, ned_to_global
from mavsim.obstacles import OWN_API_LINK, OWN_OBSTACLE_LINK, ObstacleSystem
from mavsim.personalities import DEFAULT_PERSONALITY, get_personality
from mavsim.referee import Referee
from mavsim.scenario import Scenario

logger = logging.getLogger(__name__)

__all__ = ["PlayerLinks", "TrafficPlayer", "RECORD_PERIOD_S", "HOME_FALLBACK_S"]

GCS_SYSID, GCS_COMPID = 255, 190
MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID = 6, 8
MSG_GPS_GLOBAL_ORIGIN, MSG_HOME_POSITION = 49, 242
REQUEST_PERIOD_S = 1.0
HOME_FALLBACK_S = 3.0
RECORD_PERIOD_S = 0.1
MAX_TEXTS = 100   # STATUSTEXTs in the summary (the newest)
_TICK_S = 0.005
_GEODETIC = ("UTM_GLOBAL_POSITION", "OPEN_DRONE_ID_LOCATION")   # link messages that need the origin


@dataclass(frozen=True)
class PlayerLinks:
    """Where the player listens and sends (UDP; PX4 SITL's ports by default).

    ``gcs_local_port``: our GCS socket (PX4 SITL's GCS link sends to 14550);
    ``autopilot_port``: the autopilot's GCS link (PX4 SITL 18570); ``obstacle_port``: the
    companion's obstacle link (``companion fly --obstacles udpin:0.0.0.0:14601``);
    ``truth_port``: SIH's ground truth (HIL_STATE_QUATERNION, 19410), None for none.
    """

    bind: str = "127.0.0.1"
    gcs_local_port: int = 14550
    autopilot_host: str = "127.0.0.1"
    autopilot_port: int = 18570
    obstacle_host: str = "127.0.0.1"
    obstacle_port: int = 14601
    truth_port: int | None = 19410


def _socket(bind: str, port: int, what: str) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind((bind, port))
    except OSError as exc:
        sock.close()
        raise SimulationError(f"cannot bind the {what} socket to {bind}:{port}: {exc.strerror or exc}") from None
    sock.setblocking(False)
    return sock


def _parser() -> mavlink2.MAVLink:
    p = mavlink2.MAVLink(file=None)
    p.robust_parsing = True
    return p


class TrafficPlayer:
    """Plays ``scenario``'s obstacles into an autopilot and referees the encounter.

    Parameters
    ----------
    scenario : Scenario
        Its ``[[world.obstacles]]`` (at least one; no ``transport = "api"``), goal and radii.
    links : PlayerLinks
    seed : int
        Seeds the obstacles' measurement noise (one generator each, as in mavsim).
    start : ``"offboard"`` or ``"now"``
        When the scripted motion starts.
    record : path or None
        JSON-lines trace (see the module docstring).
    keep_samples : bool
        Keep every vehicle position heard in :attr:`samples` (``"truth"``: (t_s, NED m);
        ``"estimate"``: (t_s, NED m, the autopilot's time_boot_ms in s)) for a caller that
        judges more than the referee does (the PX4 SITL tests).
    autopilot : str
        The autopilot's kind, a personality in :data:`mavsim.personalities.PERSONALITIES`:
        it names the HEARTBEAT's modes and says when the vehicle is engaged.
    frame_origin : (lat deg, lon deg, alt m AMSL) or None
        Where the scenario's NED frame is anchored; None: at the autopilot's own origin.
    """

    def __init__(self, scenario: Scenario, links: PlayerLinks = PlayerLinks(), seed: int = 0,
                 start: str = "offboard", record: str | Path | None = None, keep_samples: bool = False,
                 autopilot: str = DEFAULT_PERSONALITY,
                 frame_origin: tuple[float, float, float] | None = None) -> None:
        self.personality = get_personality(autopilot)
        if not scenario.obstacles:
            raise ScenarioError(f"{scenario.source}: no [[world.obstacles]] to play")
        for ob in scenario.obstacles:
            if ob.transport == "api":
                raise ScenarioError(f"{scenario.source}: obstacle {ob.name!r}: transport = \"api\" cannot be played "
                                    "into a real autopilot (PX4 may fuse ODOMETRY as its own vision); use \"link\" or \"adsb\"")
        if start not in ("offboard", "now", "manual"):
            raise SimulationError(f"start must be 'offboard', 'now' or 'manual', got {start!r}")
        self.scenario, self.links, self.start = scenario, links, start
        seeds = np.random.SeedSequence(int(seed)).spawn(len(scenario.obstacles))
        self.systems = [ObstacleSystem(ob, scenario.obstacle_sysid_base + i, scenario.obstacle_compid,
                                       np.random.Generator(np.random.PCG64(seeds[i])), i)
                        for i, ob in enumerate(scenario.obstacles)]
        self.uses_adsb = any(ob.transport == "adsb" for ob in scenario.obstacles)
        self._socks: list[socket.socket] = []
        try:
            self.gcs = self._add(_socket(links.bind, links.gcs_local_port, "ground-station"))
            self.out = self._add(_socket(links.bind, 0, "obstacle-link"))
            self.truth = None if links.truth_port is None else self._add(_socket(links.bind, links.truth_port, "ground-truth"))
        except SimulationError:
            self.close()
            raise
        self._parsers = {"gcs": _parser(), "truth": _parser()}
        self._encoders: dict[tuple[int, int], mavlink2.MAVLink] = {}
        self.t0 = time.monotonic()
        self.stats: Counter[str] = Counter()
        self.autopilot: tuple[int, int] | None = None
        self.origin: tuple[float, float, float] | None = None   # (lat deg, lon deg, alt m AMSL)
        self.origin_source: str | None = None
        self.frame_origin = None if frame_origin is None else tuple(float(x) for x in frame_origin)
        #: the vehicle's origin in the scenario's frame (NED m); zero without a frame_origin
        self.vehicle_offset_m: np.ndarray | None = None if frame_origin is not None else np.zeros(3)
        if self.frame_origin is not None:
            for system in self.systems:
                system.origin = self.frame_origin
        self._home: tuple[float, float, float, float, float, float] | None = None
        self._home_since: float | None = None
        self.engaged_t_s: float | None = 0.0 if start == "now" else None
        self.mode: str | None = None
        self.mode_changes: list[tuple[float, str]] = []
        self.texts: list[tuple[float, str]] = []
        self.referees = {"truth": Referee(scenario, "truth"), "estimate": Referee(scenario, "estimate")}
        self.samples: dict[str, list] | None = {"truth": [], "estimate": []} if keep_samples else None
        self._last_truth: np.ndarray | None = None
        self._last_estimate: np.ndarray | None = None
        self._next_hb = self._next_request = self._next_record = 0.0
        self._record = None if record is None else open(record, "w", encoding="utf-8")

    def _add(self, sock: socket.socket) -> socket.socket:
        self._socks.append(sock)
        return sock

    # ------------------------------------------------------------------ time
    def now_s(self) -> float:
        """Seconds since the player started (monotonic)."""
        return time.monotonic() - self.t0

    def engage(self, t_s: float | None = None) -> None:
        """Start the scripted motion at ``t_s`` (player clock, s; default now), once; for
        ``start = "manual"``, when several players must move their obstacles together."""
        if self.engaged_t_s is None:
            self.engaged_t_s = self.now_s() if t_s is None else float(t_s)
            logger.info("t=%.2f engaged from outside: obstacles start moving", self.engaged_t_s)

    def motion_s(self, t_s: float) -> float:
        """Time on the obstacles' tracks at ``t_s`` (s; 0 before engagement)."""
        return 0.0 if self.engaged_t_s is None else max(0.0, t_s - self.engaged_t_s)

    # ------------------------------------------------------------------ sending
    def _encode(self, sysid: int, compid: int, msg) -> bytes:
        mav = self._encoders.get((sysid, compid))
        if mav is None:
            mav = self._encoders[(sysid, compid)] = mavlink2.MAVLink(file=None, srcSystem=sysid, srcComponent=compid)
        data = bytes(msg.pack(mav))
        mav.seq = (mav.seq + 1) % 256
        return data

    def _send(self, sock: socket.socket, addr: tuple[str, int], sysid: int, compid: int, msg, what: str) -> None:
        try:
            sock.sendto(self._encode(sysid, compid, msg), addr)
            self.stats[what] += 1
        except OSError as exc:   # nobody listening yet (ICMP refused): count it, keep playing
            self.stats[f"{what}_failed"] += 1
            logger.debug("send %s failed: %s", what, exc)

    def _to_autopilot(self, msg, sysid: int = GCS_SYSID, compid: int = GCS_COMPID, what: str = "gcs_sent") -> None:
        self._send(self.gcs, (self.links.autopilot_host, self.links.autopilot_port), sysid, compid, msg, what)

    def _gcs_duties(self, t_s: float) -> None:
        if t_s >= self._next_hb:
            self._next_hb = t_s + 1.0
            self._to_autopilot(mavlink2.MAVLink_heartbeat_message(MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID, 0, 0, 4, 3))
        if self.origin is None and self.autopilot is not None and t_s >= self._next_request:
            self._next_request = t_s + REQUEST_PERIOD_S
            for msg_id in (MSG_GPS_GLOBAL_ORIGIN, MSG_HOME_POSITION):
                self._to_autopilot(mavlink2.MAVLink_command_long_message(
                    self.autopilot[0], self.autopilot[1], mavlink2.MAV_CMD_REQUEST_MESSAGE, 0, msg_id, 0, 0, 0, 0, 0, 0))
        if self.origin is None and self._home is not None and t_s - self._home_since >= HOME_FALLBACK_S:
            lat, lon, alt, x, y, z = self._home
            self._set_origin(ned_to_global(-x, -y, -z, lat, lon, alt), "HOME_POSITION", t_s)

    def _play(self, t_s: float) -> None:
        now_us = round(t_s * 1e6)
        motion = self.motion_s(t_s)
        obstacle_addr = (self.links.obstacle_host, self.links.obstacle_port)
        for system in self.systems:
            for route, msg in system.due(now_us, motion):
                if route == OWN_OBSTACLE_LINK and self.origin is None and system.message in _GEODETIC:
                    self.stats["geodetic_held_no_origin"] += 1
                elif route == OWN_OBSTACLE_LINK and self.vehicle_offset_m is None:
                    self.stats["local_held_no_origin"] += 1   # no place in the vehicle's frame yet
                elif route == OWN_OBSTACLE_LINK:
                    self._send(self.out, obstacle_addr, system.sysid, system.compid, msg, "obstacle_link_sent")
                elif route == OWN_API_LINK and system.transport == "adsb":
                    if self.origin is None:   # no geodetic frame yet: nothing honest to send
                        self.stats["adsb_held_no_origin"] += 1
                    else:
                        self._to_autopilot(msg, system.sysid, system.compid, "adsb_sent")
                # AUTOPILOT_ALL_LINKS: the autopilot's own re-stream, which the real one does itself

    # ------------------------------------------------------------------ receiving
    def _set_origin(self, origin: tuple[float, float, float], source: str, t_s: float) -> None:
        self.origin, self.origin_source = origin, source
        if self.frame_origin is None:
            for system in self.systems:
                system.origin = origin
        else:
            self.vehicle_offset_m = np.array(global_to_ned(*origin, *self.frame_origin))
            for system in self.systems:
                system.local_offset_m = self.vehicle_offset_m
        logger.info("t=%.2f origin %.7f %.7f %.2f m from %s", t_s, *origin, source)

    def _receive(self, t_s: float) -> None:
        for name, sock, handler in (("gcs", self.gcs, self._on_autopilot), ("truth", self.truth, self._on_truth)):
            if sock is None:
                continue
            for _ in range(500):
                try:
                    data = sock.recv(65535)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError:
                    self.stats["receive_errors"] += 1
                    break
                p = self._parsers[name]
                p.buf, p.buf_index = bytearray(), 0      # one datagram, parsed afresh
                try:
                    msgs = p.parse_buffer(data) or []
                except Exception:  # pymavlink raises on some malformed input even in robust mode
                    self._parsers[name] = _parser()
                    self.stats["parse_errors"] += 1
                    continue
                for msg in msgs:
                    if msg.get_type() != "BAD_DATA":
                        handler(t_s, msg)

    def _on_autopilot(self, t_s: float, msg) -> None:
        kind, src = msg.get_type(), (msg.get_srcSystem(), msg.get_srcComponent())
        if kind == "HEARTBEAT":
            if self.autopilot is None and src[1] == 1 and msg.autopilot != MAV_AUTOPILOT_INVALID and msg.type != MAV_TYPE_GCS:
                self.autopilot = src
                logger.info("t=%.2f autopilot %d/%d (autopilot type %d)", t_s, *src, msg.autopilot)
            if src != self.autopilot:
                return
            mode = self.personality.heartbeat_mode_name(msg.custom_mode) + ("" if msg.base_mode & 128 else " disarmed")
            if mode != self.mode:
                self.mode = mode
                self.mode_changes.append((round(t_s, 3), mode))
            if self.engaged_t_s is None and self.start == "offboard" and self.personality.engaged(msg.base_mode, msg.custom_mode):
                self.engaged_t_s = t_s
                logger.info("t=%.2f engaged (armed in OFFBOARD): obstacles start moving", t_s)
            return
        if src != self.autopilot:
            return
        if kind == "GPS_GLOBAL_ORIGIN" and self.origin_source != "GPS_GLOBAL_ORIGIN":
            self._set_origin((msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3), "GPS_GLOBAL_ORIGIN", t_s)
        elif kind == "HOME_POSITION" and self._home is None:
            self._home = (msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3, msg.x, msg.y, msg.z)
            self._home_since = t_s
        elif kind == "LOCAL_POSITION_NED":
            if self.vehicle_offset_m is None:
                return   # the vehicle's frame is not placed in the scenario's yet
            self._last_estimate = np.array([msg.x, msg.y, msg.z], float) + self.vehicle_offset_m
            if self.samples is not None:
                self.samples["estimate"].append((t_s, self._last_estimate, msg.time_boot_ms * 1e-3))
            if self.engaged_t_s is not None:
                self.referees["estimate"].update(self.motion_s(t_s), self._last_estimate)
        elif kind == "STATUSTEXT":
            self.texts.append((round(t_s, 3), str(msg.text).strip()))

    def _on_truth(self, t_s: float, msg) -> None:
        frame = self.frame_origin or self.origin
        if msg.get_type() != "HIL_STATE_QUATERNION" or frame is None:
            return
        self._last_truth = np.array(global_to_ned(msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3, *frame))
        if self.samples is not None:
            self.samples["truth"].append((t_s, self._last_truth))
        if self.engaged_t_s is not None:
            self.referees["truth"].update(self.motion_s(t_s), self._last_truth)

    # ------------------------------------------------------------------ loop
    def _write_record(self, t_s: float) -> None:
        if self._record is None or t_s < self._next_record:
            return
        self._next_record = t_s + RECORD_PERIOD_S
        motion = self.motion_s(t_s)

        def vec(p: np.ndarray | None) -> list[float] | None:
            return None if p is None else [round(float(x), 3) for x in p]

        line = {"t_s": round(t_s, 3), "motion_s": None if self.engaged_t_s is None else round(motion, 3),
                "mode": self.mode,
                "obstacles_ned_m": [vec(p) for p in self.referees["truth"].obstacle_positions(motion)],
                "truth_ned_m": vec(self._last_truth), "estimate_ned_m": vec(self._last_estimate)}
        self._record.write(json.dumps(line) + "\n")

    def step(self) -> None:
        """One pass: read what arrived, do the GCS duties, send what is due, record."""
        t_s = self.now_s()
        self._receive(t_s)
        self._gcs_duties(t_s)
        self._play(t_s)
        self._write_record(t_s)

    def run(self, duration_s: float, should_stop=lambda: False) -> None:
        """Play for ``duration_s`` wall seconds or until ``should_stop()`` is true."""
        end = self.t0 + duration_s
        socks = [s for s in (self.gcs, self.truth) if s is not None]
        while not should_stop():
            now = time.monotonic()
            if now >= end:
                break
            self.step()
            select.select(socks, [], [], min(_TICK_S, max(0.0, end - now)))

    def summary(self) -> dict:
        """JSON-serialisable: what was played, when it engaged, and the referee's figures
        (judged on SIH's truth when it arrived, else on the autopilot's estimate)."""
        judged = "truth" if self.referees["truth"].samples else "estimate"
        referee = self.referees[judged].summary()
        return {
            "scenario": self.scenario.name,
            "player_time_s": round(self.now_s(), 2),
            "autopilot": None if self.autopilot is None else {"system": self.autopilot[0], "component": self.autopilot[1]},
            "origin": None if self.origin is None else {"lat_deg": self.origin[0], "lon_deg": self.origin[1],
                                                        "alt_m": self.origin[2], "from": self.origin_source},
            "frame_origin": None if self.frame_origin is None else dict(zip(("lat_deg", "lon_deg", "alt_m"), self.frame_origin)),
            "vehicle_offset_m": None if self.vehicle_offset_m is None else [round(float(x), 3) for x in self.vehicle_offset_m],
            "engaged": self.engaged_t_s is not None,
            "engaged_at_s": None if self.engaged_t_s is None else round(self.engaged_t_s, 3),
            "obstacles": [{"name": s.name, "system": s.sysid, "transport": s.transport,
                           "message": "ADSB_VEHICLE" if s.transport == "adsb" else s.message} for s in self.systems],
            "judged_on": judged,
            "min_distance_m": referee["min_distance_m"],
            "min_clearance_m": referee["min_clearance_m"],
            "collision": referee["collision"],
            "goal_reached": referee["goal_reached"],
            "referee": {name: r.summary() for name, r in self.referees.items()},
            "mode_changes": self.mode_changes,
            "statustexts": self.texts[-MAX_TEXTS:],
            "sent": {k: int(n) for k, n in sorted(self.stats.items())},
        }

    def close(self) -> None:
        for sock in self._socks:
            sock.close()
        self._socks.clear()
        if getattr(self, "_record", None) is not None:
            self._record.close()
            self._record = None

    def __enter__(self) -> TrafficPlayer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
