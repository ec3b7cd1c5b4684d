"""Obstacle intake: every traffic report from every link, to the obstacle tracker or to a counted rejection.

Routing (by link role, then system id, then ICAO address):

- obstacle links (``obstaclesN``) are receive-only. Their traffic kinds go to the tracker if
  the source's policy accepts them. Anything from the autopilot's own system id on an
  obstacle link is *wrong link*: counted, not used (the autopilot is followed on its own
  link only).
- the autopilot link: ADSB_VEHICLE (re-streamed by PX4 under its own id, and the original
  packets it forwards under the senders' ids) is traffic; other traffic kinds from other
  systems are wrong link unless ``[traffic] autopilot_link_kinds`` accepts them.
  ODOMETRY from another system on the autopilot link raises a warning at once: PX4 may fuse
  it as its own external vision.

Tracks are keyed by identity: ``("icao", address)`` for ADSB on any link (so the two copies
PX4 delivers are one aircraft; a copy within 2 LSB of lat/lon, 1 cm of altitude and 1 s of
the previous report is a duplicate, counted and dropped), ``("uas", id, link)`` for UTM and
Remote ID reports that carry one, ``(sysid, compid, link)`` otherwise (so ``key[0]`` is the
system id, as for the autopilot's own ``(sysid, compid)``).

Time: each identity's stamps are mapped onto link time by its own
:class:`~companion.loop.intake.source_clocks.SourceClock` (ADSB carries no stamp: arrival minus ``tslc``),
then onto the vehicle's time by the caller's ``vehicle_time``. A clock jump restarts the
mapping and the track (never freezes it); a report from the future is clamped.

Nothing is dropped silently: every rejection is counted per source and reason
(:meth:`ObstacleIntake.summary`), logged, and announced by a STATUSTEXT at most once per
``statustext_period_s``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections import Counter
from collections.abc import Callable
from typing import Hashable

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.core.intent import Intent
from companion.loop.intake.source_clocks import SourceClock
from companion.loop.peer_intents import PeerIntents
from companion.loop.fleet_frame import FleetFrame
from companion.loop.intake.traffic_config import AUTOPILOT_LINK, FLEET_LINK, SourcePolicy, TrafficConfig, obstacle_link_name
from companion.loop.vehicle_reference import MessageRequest, VehicleReference
from companion.mavlink import fleet, messages, traffic
from companion.mavlink.link import Received

logger = logging.getLogger(__name__)

MSG_GPS_RAW_INT = 24
_MAX_GEOID_REQUESTS = 5  # an autopilot whose receiver gives no ellipsoid height is not asked forever
#: Kinds whose altitude is a WGS-84 ellipsoid height: they need the geoid separation.
ELLIPSOID_KINDS = frozenset({"UTM_GLOBAL_POSITION", "OPEN_DRONE_ID_LOCATION"})
_ORIGIN_REQUEST_PERIOD_S = 2.0
_DUPLICATE_WINDOW_S = 1.0
_DUPLICATE_LATLON_LSB = 2  # PX4 truncates lat/lon of what it re-streams by about 1 cm (1 LSB)
_MAX_SOURCES = 1024  # bounds per-source state whatever arrives
#: A peer's plan may start this far after its intent arrives (s): its planner's lead, with room; more is garbage.
_MAX_INTENT_LEAD_S = 2.0
Severity = int


def replay_link(msg, autopilot: tuple[int, int] | None) -> str:
    """The link a logged message most likely came in on, for replay (a tlog does not say).

    Obstacle kinds (all traffic but ADSB_VEHICLE, which the autopilot's link carries) from a
    system other than the autopilot's (once known) are taken as from the first obstacle link, where a
    companion records them; everything else as from the autopilot link.
    """
    mtype = msg.get_type()
    if mtype in traffic.TRAFFIC_KINDS and mtype != "ADSB_VEHICLE":
        if autopilot is not None and msg.get_srcSystem() != autopilot[0]:
            return obstacle_link_name(0)
    return AUTOPILOT_LINK


def _track_key(link: str, identity: tuple) -> tuple:
    """The tracker key of a report's identity on ``link`` (see the module docstring)."""
    if identity[0] == "icao":
        return identity
    if identity[0] == "uas":
        return ("uas", identity[1], link)
    return (identity[1], identity[2], link)


def _reason_code(reason: str) -> str:
    """A short, countable form of a decoder's reason text."""
    return reason.split(" (")[0].split(":")[0].strip()[:40]


_MessageRequest = MessageRequest  # the geoid request's kind (shared with the vehicle reference)


#: Dropped tracks named one STATUSTEXT each in one tick; more are counted in one more.
_DROPS_NAMED = 3


def _track_label(key: Hashable) -> str:
    """A track's key as said: ``sys 101:197`` for a MAVLink system's (on any link), ``icao a00065`` for ADS-B."""
    if isinstance(key, tuple) and len(key) in (2, 3) and all(isinstance(x, int) for x in key[:2]):
        return f"sys {key[0]}:{key[1]}"
    if isinstance(key, tuple):
        return " ".join(f"{x:x}" if isinstance(x, int) and x > 0xFFFF else str(x) for x in key)
    return str(key)


class ObstacleIntake:
    """Routes traffic to the tracker; counts and announces what it cannot use.

    Parameters
    ----------
    config : TrafficConfig
    tracker : estimator.ObstacleTracker
        Receives ``update(key, t_vehicle, ...)`` and ``drop(key)`` on a clock restart.
    vehicle_time : callable (t_link) -> float or None
        Link time to the vehicle's time (None while the vehicle's clock is unknown).
    default_radius_m : float
        Body radius of obstacles whose source sets none.
    reference : VehicleReference, optional
        The vehicle's origin and home, shared with whatever else places geodetic points
        (default: one of its own).
    peers : PeerIntents, optional
        Where the fleet's intents (TRAJECTORY_REPRESENTATION_WAYPOINTS on an obstacle link,
        :mod:`companion.mavlink.fleet`) go, on the vehicle's time base; None: intents are ignored.
    fleet_frame : FleetFrame, optional
        The fleet's frame: positions heard on the fleet link (:data:`FLEET_LINK`) are in it and
        are moved into the local frame (they wait, counted, while it is not known).
    """

    def __init__(self, config: TrafficConfig, tracker, vehicle_time: Callable[[float], float | None],
                 default_radius_m: float, reference: VehicleReference | None = None,
                 peers: PeerIntents | None = None, fleet_frame: FleetFrame | None = None) -> None:
        self.config = config
        self.tracker = tracker
        self.vehicle_time = vehicle_time
        self.default_radius_m = float(default_radius_m)
        self.reference = reference if reference is not None else VehicleReference(_ORIGIN_REQUEST_PERIOD_S)
        self.rejected: Counter[tuple[str, str]] = Counter()  # (source, reason) -> count
        self.waiting: Counter[tuple[str, str]] = Counter()   # (source, why) -> reports too early to place
        self.accepted: Counter[str] = Counter()
        self.duplicates = 0
        self.clamped: Counter[str] = Counter()
        self.restarts: Counter[str] = Counter()
        self.warnings: list[str] = []
        self._clocks: dict[Hashable, SourceClock] = {}
        self._radius: dict[Hashable, float] = {}
        self._range: dict[Hashable, float] = {}   # tracks whose source sets a range (range_m)
        self._last_adsb: dict[int, tuple[float, int, int, int]] = {}
        self._warned_odometry: set[tuple[int, int]] = set()
        self._texts: list[tuple[Severity, str]] = []
        self._tracked: set[Hashable] = set()  # the tracker's keys at the last outbound()
        self.tracks_dropped_announced = 0
        self._last_text_t = -math.inf
        self._announced = 0
        self._origin_request = self.reference.origin_request
        self._measured_geoid_m: float | None = None  # from the autopilot's GPS_RAW_INT
        self._geoid_request = _MessageRequest(MSG_GPS_RAW_INT, _ORIGIN_REQUEST_PERIOD_S, _MAX_GEOID_REQUESTS)
        self._geoid_given_up = False
        self.peers = peers
        self.fleet_frame = fleet_frame

    @property
    def origin(self) -> traffic.GlobalOrigin | None:
        """The local frame's origin (GPS_GLOBAL_ORIGIN), kept in the shared :attr:`reference`."""
        return self.reference.origin

    @origin.setter
    def origin(self, origin: traffic.GlobalOrigin | None) -> None:
        self.reference.origin = origin

    def geoid_separation_m(self) -> float | None:
        """Geoid above the WGS-84 ellipsoid (m): the autopilot's GPS_RAW_INT, else configured, else None."""
        return self._measured_geoid_m if self._measured_geoid_m is not None else self.config.geoid_separation_m

    # ------------------------------------------------------------------ inbound

    def claims(self, rx: Received, autopilot: tuple[int, int] | None) -> bool:
        """Take ``rx`` if it is the intake's business (returns True); else leave it to the caller."""
        link = getattr(rx, "link", AUTOPILOT_LINK)
        mtype = rx.msg.get_type()
        key = messages.source_key(rx.msg)
        on_autopilot_link = link == AUTOPILOT_LINK
        if mtype == "GPS_RAW_INT":
            if on_autopilot_link and autopilot is not None and key[0] == autopilot[0]:
                n = traffic.geoid_separation(rx.msg)
                if n is not None and n != self._measured_geoid_m:
                    logger.info("geoid separation %.2f m (GPS_RAW_INT alt_ellipsoid - alt)", n)
                    self._measured_geoid_m = n
                    self._geoid_request.wanted = False
                    if self.origin is not None:
                        self.origin = dataclasses.replace(self.origin, geoid_separation_m=n)
            return False  # the vehicle side may use it too
        if mtype == "GPS_GLOBAL_ORIGIN":
            if on_autopilot_link and autopilot is not None and key[0] == autopilot[0]:
                self.reference.on_origin(traffic.decode_origin(rx.msg, self.geoid_separation_m()))
            elif not on_autopilot_link:
                self._reject(f"{link} sys {key[0]}", "GPS_GLOBAL_ORIGIN not from the autopilot", rx.t_s)
            return True
        if not on_autopilot_link:
            if autopilot is not None and key[0] == autopilot[0]:
                self._reject(f"{link} sys {key[0]}", f"wrong link: {mtype} of the autopilot's system", rx.t_s)
            elif mtype in traffic.TRAFFIC_KINDS:
                self._take(rx, link, autopilot)
            elif mtype == "TRAJECTORY_REPRESENTATION_WAYPOINTS" and self.peers is not None:
                self._take_intent(rx, link)
            return True  # an obstacle link never drives the vehicle side
        if mtype not in traffic.TRAFFIC_KINDS:
            return False
        if autopilot is None:
            if mtype == "ADSB_VEHICLE":
                self._take(rx, AUTOPILOT_LINK, autopilot)  # counted: no origin yet
                return True
            return False  # poses before the autopilot is known: the caller's rule
        if key[0] == autopilot[0] and mtype != "ADSB_VEHICLE":
            return False  # the vehicle's own estimate
        if mtype == "ODOMETRY" and key not in self._warned_odometry:
            self._warned_odometry.add(key)
            text = (f"ODOMETRY from system {key[0]} component {key[1]} on the autopilot link: PX4 may fuse it as "
                    f"its own external vision (EKF2_EV_CTRL). Fix: send obstacle ODOMETRY to a companion "
                    f"--obstacles port, never onto the autopilot's MAVLink network")
            logger.warning("%s", text)
            self.warnings.append(text)
            self._texts.append((mavlink2.MAV_SEVERITY_WARNING, f"ODOMETRY sys {key[0]} on AP link: EV risk"))
        self._take(rx, AUTOPILOT_LINK, autopilot)
        return True

    def _take(self, rx: Received, link: str, autopilot) -> None:
        msg = rx.msg
        mtype = msg.get_type()
        key = messages.source_key(msg)
        icao = int(msg.ICAO_address) if mtype == "ADSB_VEHICLE" else None
        source = f"{link} ICAO {icao:06X}" if icao is not None else f"{link} sys {key[0]}"
        policy = self.config.policy(link, key[0], icao)
        if mtype not in policy.kinds:
            reason = "wrong link" if link == AUTOPILOT_LINK else "kind not accepted"
            self._reject(source, f"{reason}: {mtype}", rx.t_s)
            return
        if mtype in traffic.GLOBAL_KINDS and self.origin is None:
            self._origin_request.wanted = True
        if mtype in ELLIPSOID_KINDS and self._measured_geoid_m is None:
            self._geoid_request.wanted = True  # ask the autopilot even when one is configured: its receiver knows better
        decoded = traffic.decode_traffic(msg, self.origin)
        if isinstance(decoded, messages.Rejected):
            if decoded.reason == traffic.NO_ORIGIN_YET:  # not wrong: early (the origin is being asked for)
                self.waiting[(source, f"{mtype}: {decoded.reason}")] += 1
            else:
                self._reject(source, f"{mtype} {_reason_code(decoded.reason)}", rx.t_s)
            return
        assert decoded is not None
        if icao is not None and self._is_duplicate(icao, msg, rx.t_s):
            self.duplicates += 1
            return
        if link == FLEET_LINK and self.fleet_frame is not None:
            offset = self.fleet_frame.offset()
            if offset is None:
                self.waiting[(source, "the fleet's frame: this vehicle's origin not known yet")] += 1
                return
            if np.any(offset):
                decoded = dataclasses.replace(decoded, position_ned=decoded.position_ned - offset)
        track = _track_key(link, decoded.identity)
        estimate = link == FLEET_LINK and self.peers is not None and self.peers.config.peer_reports == "estimate"
        self._fuse(track, source, decoded, policy, rx.t_s, estimate=estimate)

    def _take_intent(self, rx: Received, link: str) -> None:
        """A peer's intent, placed on the vehicle's time base through its state announcements' clock.

        The intent's stamp is the time of its first knot on the sender's clock (the plan's
        start, which may be ahead of the sending): it is mapped with the clock its ODOMETRY
        built (:meth:`SourceClock.peek`), not fed to it. Before the peer's first state
        announcement there is no clock: the intent waits (counted).
        """
        key = messages.source_key(rx.msg)
        source = f"{link} sys {key[0]}"
        decoded = fleet.decode_intent(rx.msg)
        if isinstance(decoded, messages.Rejected):
            self._reject(source, f"intent {_reason_code(decoded.reason)}", rx.t_s)
            return
        track = (key[0], key[1], link)
        clock = self._clocks.get(track)
        t_link = None if clock is None else clock.peek(decoded.stamp, 1e-6)
        if t_link is None:
            self.waiting[(source, "intent before its state (no clock)")] += 1
            return
        if t_link > rx.t_s + _MAX_INTENT_LEAD_S:
            self._reject(source, f"intent starts more than {_MAX_INTENT_LEAD_S:g} s ahead", rx.t_s)
            return
        t_v = self.vehicle_time(t_link)
        if t_v is None:
            self.waiting[(source, "vehicle time unknown")] += 1
            return
        if decoded.positions.shape[0] == 0:
            self.peers.update(track, None)
            return
        offset = np.zeros(3) if self.fleet_frame is None or link != FLEET_LINK else self.fleet_frame.offset()
        if offset is None:
            self.waiting[(source, "the fleet's frame: this vehicle's origin not known yet")] += 1
            return
        self.peers.update(track, Intent(t0_s=t_v, spacing_s=self.peers.config.intent_knot_spacing_s,
                                        positions=decoded.positions - offset, velocities=decoded.velocities))
        self.accepted[f"{source} intent"] += 1

    def _is_duplicate(self, icao: int, msg, t_rx: float) -> bool:
        last = self._last_adsb.get(icao)
        now = (t_rx, int(msg.lat), int(msg.lon), int(msg.altitude))
        if last is not None and t_rx - last[0] <= _DUPLICATE_WINDOW_S and abs(now[1] - last[1]) <= _DUPLICATE_LATLON_LSB \
                and abs(now[2] - last[2]) <= _DUPLICATE_LATLON_LSB and abs(now[3] - last[3]) <= 10:
            return True
        if len(self._last_adsb) < _MAX_SOURCES or icao in self._last_adsb:
            self._last_adsb[icao] = now
        return False

    def _fuse(self, track: Hashable, source: str, r: traffic.TrafficReport, policy: SourcePolicy, t_rx: float,
              estimate: bool = False) -> None:
        """Put one report on the vehicle's time base and into the tracker (``estimate``: a fleet
        peer's own estimate, taken as its track's state; :meth:`ObstacleTracker.update`)."""
        if r.stamp is None:
            t_link = t_rx - max(0.0, r.age_s)
        else:
            clock = self._clocks.get(track)
            if clock is None:
                if len(self._clocks) >= _MAX_SOURCES:
                    self._reject(source, "too many sources", t_rx)
                    return
                clock = self._clocks[track] = SourceClock(window_s=self.config.clock_window_s, jump_s=self.config.clock_jump_s)
            mapped = clock.map(r.stamp, t_rx, r.stamp_unit_s)
            if mapped.restarted and clock.epochs > 1:
                self.restarts[source] += 1
                self._texts.append((mavlink2.MAV_SEVERITY_NOTICE, f"obstacle {source[:28]}: clock jump, track reset"))
                if track in self.tracker:
                    self.tracker.drop(track)
            if mapped.clamped:
                self.clamped[source] += 1
            t_link = mapped.t_s
        t_v = self.vehicle_time(t_link)
        if t_v is None:  # not wrong: early (no autopilot clock yet to put it on)
            self.waiting[(source, "vehicle time unknown")] += 1
            return
        h2, v2, vel2 = policy.position_std_m ** 2, policy.vertical_std_m ** 2, policy.velocity_std_mps ** 2
        pos_cov = r.position_cov if r.position_cov is not None else np.diag([h2, h2, v2])
        vel_cov = None
        if r.velocity_ned is not None:
            vel_cov = r.velocity_cov if r.velocity_cov is not None else vel2 * np.eye(3)
            if r.vertical_velocity_unknown:
                vel_cov = vel_cov.copy()
                vel_cov[2, 2] = max(vel_cov[2, 2], vel2)
        result = self.tracker.update(track, t_v, r.position_ned, r.velocity_ned, pos_cov, vel_cov, estimate=estimate)
        if not result.accepted:
            self._reject(source, f"tracker: {result.reason}", t_rx)
            return
        self.accepted[source] += 1
        radius = policy.radius_m if policy.radius_m is not None else (r.radius_m or self.default_radius_m)
        if track in self._radius or len(self._radius) < _MAX_SOURCES:
            self._radius[track] = radius
        if policy.range_m is not None and (track in self._range or len(self._range) < _MAX_SOURCES):
            self._range[track] = policy.range_m

    def _reject(self, source: str, reason: str, t_s: float) -> None:
        self.rejected[(source, reason)] += 1
        logger.debug("obstacle report rejected: %s: %s", source, reason)

    # ------------------------------------------------------------------ outbound

    def radius(self, track: Hashable) -> float:
        """Body radius of a tracked obstacle, metres."""
        return self._radius.get(track, self.default_radius_m)

    def planning_range(self, track: Hashable) -> float | None:
        """How far out a tracked obstacle is planned around (its source's ``range_m``), metres;
        None: the planner's ``sensing_range_m``."""
        return self._range.get(track)

    def outbound(self, t_s: float, autopilot: tuple[int, int] | None) -> tuple[list, list[tuple[Severity, str]]]:
        """(messages to send, (severity, text) to announce) at link time ``t_s``.

        Requests GPS_GLOBAL_ORIGIN (MAV_CMD_REQUEST_MESSAGE 49) and HOME_POSITION while
        global traffic or a goal waits for them (:meth:`VehicleReference.outbound`), and
        GPS_RAW_INT (24, for the geoid separation) while ellipsoid-height traffic has none
        measured, each every 2 s; summarises new rejections in one STATUSTEXT per period.
        """
        out: list = self.reference.outbound(t_s, autopilot)
        msg = self._geoid_request.due(t_s, autopilot)
        if msg is not None:
            out.append(msg)
        if self._geoid_request.exhausted and not self._geoid_given_up:
            self._geoid_given_up = True
            text = ("no geoid separation from the autopilot (GPS_RAW_INT alt_ellipsoid) after "
                    f"{_MAX_GEOID_REQUESTS} requests: " + ("using [traffic] geoid_separation_m"
                    if self.config.geoid_separation_m is not None else
                    "UTM and Remote ID reports stay rejected; set [traffic] geoid_separation_m"))
            logger.warning("%s", text)
            self.warnings.append(text)
        texts, self._texts = self._texts, []
        texts.extend(self._dropped_tracks())
        total = sum(self.rejected.values())
        if total > self._announced and t_s - self._last_text_t >= self.config.statustext_period_s:
            (source, reason), _ = max(self.rejected.items(), key=lambda kv: kv[1])
            texts.append((mavlink2.MAV_SEVERITY_WARNING, f"obstacles: {total - self._announced} rejected, {source}: {reason}"))
            self._announced = total
            self._last_text_t = t_s
        return out, texts

    def _dropped_tracks(self) -> list[tuple[Severity, str]]:
        """A STATUSTEXT for each track gone since the last call (pruned after ``drop_after_s`` of
        silence: its source died or its link did), at most :data:`_DROPS_NAMED` named a tick."""
        keys = set(self.tracker.keys())
        gone, self._tracked = self._tracked - keys, keys
        if not gone:
            return []
        self.tracks_dropped_announced += len(gone)
        silent = getattr(getattr(self.tracker, "config", None), "drop_after_s", None)
        why = "track dropped" + (f", silent > {silent:g} s" if silent is not None else "")
        names = sorted((_track_label(k) for k in gone))
        texts = [(mavlink2.MAV_SEVERITY_WARNING, f"obstacle {name[:20]}: {why}") for name in names[:_DROPS_NAMED]]
        if len(names) > _DROPS_NAMED:
            texts.append((mavlink2.MAV_SEVERITY_WARNING, f"obstacles: {len(names) - _DROPS_NAMED} more tracks dropped"))
        for name in names:
            logger.info("obstacle %s: %s", name, why)
        if self.peers is not None:
            for key in gone:
                self.peers.forget(key)
        return texts

    def summary(self) -> dict:
        """Counts for the run report: accepted, rejected per source and reason, clock events."""
        return {
            "accepted": dict(self.accepted),
            "rejected": {f"{s}: {r}": n for (s, r), n in sorted(self.rejected.items())},
            "rejected_total": sum(self.rejected.values()),
            # reports that came before they could be placed (no vehicle clock or origin yet): early, not wrong
            "waiting": {f"{s}: {r}": n for (s, r), n in sorted(self.waiting.items())},
            "waiting_total": sum(self.waiting.values()),
            "adsb_duplicates": self.duplicates,
            "tracks_dropped": self.tracks_dropped_announced,
            "clock_restarts": dict(self.restarts),
            "future_clamped": dict(self.clamped),
            "origin": None if self.origin is None else [self.origin.lat_deg, self.origin.lon_deg, self.origin.alt_m],
            "geoid_separation_m": self.geoid_separation_m(),
            "warnings": list(self.warnings),
        }
