"""The simulator: MAVLink bytes in, timed MAVLink packets out. No clock, no socket.

Time is an integer count of microseconds since boot, advanced in fixed physics steps
(``[sim] physics_step_s``, default 0.01 s); an ``advance_to`` that does not end on the
grid ends with one shorter step. Incoming bytes are parsed and handled at the current
time; their replies are stamped with it. Each step:

1. the commander checks failsafes and computes the velocity command (state at step start),
2. the vehicle is stepped, time advances,
3. truth is updated (collisions, distances, goal),
4. STATUSTEXTs, due telemetry of the vehicle and of every obstacle system are emitted.

Packets are encoded per (link, system, component) so each link has its own sequence
numbers, as each PX4 MAVLink instance does. What the autopilot is (HEARTBEAT identity,
modes, commander, parameters, default streams, vehicle responses) is its personality's
(:mod:`mavsim.personalities`, PX4 by default). Obstacles reach the client the way their
``transport`` says: on the separate ``"obstacles"`` link (added to the links when an
obstacle uses it; the autopilot streams nothing there and ignores what arrives on it),
re-streamed by the autopilot as ADSB_VEHICLE on every vehicle link, or (the old way) as
ODOMETRY on the API link. Randomness: one ``numpy.random.Generator`` per source (vehicle estimate,
each obstacle) spawned from ``SeedSequence(seed)``, so a seed fixes every byte.
"""

from __future__ import annotations

import dataclasses
import logging
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from mavsim.signing import enable_signing

from mavsim.autopilot import COMPID, SYSID, Autopilot, statustext
from mavsim.errors import SimulationError
from mavsim.noise import GaussMarkovError, VelocityBias
from mavsim.obstacles import AUTOPILOT_ALL_LINKS, OWN_API_LINK, ObstacleSystem, noise_factor
from mavsim.params import ParamStore
from mavsim.personalities import DEFAULT_PERSONALITY, get_personality, velocity_response
from mavsim.personalities.base import SEV_WARNING
from mavsim.scenario import Scenario, load_scenario
from mavsim.telemetry import TelemetryBuilder
from mavsim.truth import Truth, TruthRecorder
from mavsim.vehicle import VehicleParams, initial_state, step

logger = logging.getLogger(__name__)

__all__ = ["Simulator", "Packet"]

#: Name of the link obstacles with ``transport = "link"`` send on.
OBSTACLE_LINK = "obstacles"
#: When the obstacles' scripted motion may start (see :class:`Simulator`).
OBSTACLES_START = ("boot", "offboard")
#: (time since boot in us, link name, raw packet bytes)
Packet = tuple[int, str, bytes]
#: tap(direction "in"/"out", link, time_us, packet bytes)
Tap = Callable[[str, str, int, bytes], None]


class Simulator:
    """An autopilot's vehicle plus scripted obstacles behind a byte interface.

    Parameters
    ----------
    scenario : Scenario or path
    seed : int
        Seeds every noise source.
    links : tuple of str
        Vehicle link names; the first one is the offboard API link. When an obstacle uses
        ``transport = "link"``, :data:`OBSTACLE_LINK` is appended (see :attr:`links`).
    signing : (key, Unix time s) or None
        MAVLink 2 signing from boot (see :meth:`enable_signing`): the 32-byte key and the
        wall time that seeds the outgoing signing timestamps.
    obstacles_start : ``"boot"`` or ``"offboard"``
        When the obstacles' scripted motion starts: at boot (time 0, the default), or when the
        vehicle is first armed in OFFBOARD (engagement), so an encounter meets the vehicle
        however long it took to take off. Before that the obstacles report from their start
        points, at rest. :attr:`obstacles_started_s` is the simulated time it started.
    obstacles_gate : callable or None
        With ``obstacles_start = "offboard"``: called with whether this vehicle has engaged,
        returns whether the obstacles may start now (default: as soon as it has). A fleet
        passes one that waits for every vehicle (:class:`mavsim.fleet.FleetServer`).
    personality : str
        The autopilot imitated, a name in :data:`mavsim.personalities.PERSONALITIES`. The
        scenario's ``start_mode`` and ``params`` must be its own (SimulationError otherwise).
    system_id : int
        The vehicle's MAVLink system id (1 to 100; default 1): one vehicle of a fleet each
        has its own, as PX4's multi-instance SITL gives instance N the id N + 1.
    """

    def __init__(self, scenario: Scenario | str | Path, seed: int = 0, links: tuple[str, ...] = ("api",),
                 signing: tuple[bytes, float] | None = None, obstacles_start: str = "boot",
                 personality: str = DEFAULT_PERSONALITY, system_id: int = SYSID,
                 obstacles_gate: Callable[[bool], bool] | None = None) -> None:
        if obstacles_start not in OBSTACLES_START:
            raise SimulationError(f"obstacles_start must be one of {', '.join(OBSTACLES_START)}, got {obstacles_start!r}")
        if not isinstance(scenario, Scenario):
            scenario = load_scenario(scenario)
        if not links:
            raise SimulationError("at least one link is needed")
        if not 1 <= int(system_id) <= 100:
            raise SimulationError(f"system_id must be 1 to 100 (obstacles use 101 up), got {system_id}")
        self.system_id = int(system_id)
        self.personality = get_personality(personality)
        self.scenario = scenario
        self.seed = int(seed)
        self.vehicle_links = tuple(links)
        needs_obstacle_link = any(ob.transport == "link" for ob in scenario.obstacles)
        self.links = self.vehicle_links + ((OBSTACLE_LINK,) if needs_obstacle_link and OBSTACLE_LINK not in links else ())
        cfg = scenario.sim
        self.now_us = 0
        self.obstacles_start = obstacles_start
        #: us since boot the obstacles' motion started (0 at boot; None until engagement)
        self.motion_epoch_us: int | None = 0 if obstacles_start == "boot" else None
        self._obstacles_gate: Callable[[bool], bool] = obstacles_gate or bool
        self.step_us = max(1, round(cfg.physics_step_s * 1e6))
        seeds = np.random.SeedSequence(self.seed).spawn(1 + len(scenario.obstacles))
        self._rng = np.random.Generator(np.random.PCG64(seeds[0]))
        self._position_error = GaussMarkovError(noise_factor(cfg.position_noise_cov_m2), cfg.position_noise_correlation_s)
        self._velocity_bias = VelocityBias(cfg.velocity_bias_mps, cfg.velocity_bias_period_s) \
            if np.any(cfg.velocity_bias_mps) else None
        self._Lv = noise_factor(cfg.velocity_noise_cov_m2ps2)
        self._resets = [(round(t * 1e6), np.array(step)) for t, step in cfg.estimator_resets]
        # GPS outages: (start us, end us, drift velocity NED m/s), the drifts from their own stream
        # so that adding an outage moves none of the other noises
        gps_rng = np.random.default_rng([self.seed, 0x475053])
        self._gps_outages = [(round(t * 1e6), round((t + d) * 1e6), cfg.gps_outage_drift_mps * gps_rng.standard_normal(3))
                             for t, d in cfg.gps_outages]
        self._gps_sd_growth_mps = cfg.gps_outage_sd_growth_mps
        # a degraded GPS: (start us, end us, sd m), a unit horizontal Gauss-Markov error scaled by
        # sd, its draws from a stream of their own as well
        self._gps_degradations = [(round(t * 1e6), round((t + d) * 1e6), sd) for t, d, sd in cfg.gps_degradations]
        self._gps_noise = GaussMarkovError(np.diag([1.0, 1.0, 0.0]), cfg.gps_degradation_correlation_s)
        self._gps_noise_rng = np.random.default_rng([self.seed, 0x4E4F4953])
        longest = max((d for _, d in cfg.gps_outages), default=0.0)
        limit = self.personality.gps_outage_max_s
        if limit is not None and longest >= limit:
            raise SimulationError(f"[sim] gps_outages: an outage of {longest:g} s; the {self.personality.name} "
                                  f"personality models outages shorter than {limit:g} s (its failsafe on a lost "
                                  "position is not modelled)")
        self.vparams = VehicleParams(cfg.velocity_time_constant_s, cfg.accel_max_mps2,
                                     response=velocity_response(cfg.vehicle))
        self.vehicle = initial_state(scenario.start_ned_m, cfg.start_yaw_rad)
        ap = self.personality
        start_mode = cfg.start_mode if cfg.start_mode is not None else ap.default_start_mode(cfg.start_airborne)
        if start_mode not in ap.mode_names:
            raise SimulationError(f"start_mode {start_mode!r} is not a mode of autopilot {ap.name!r} "
                                  f"({', '.join(ap.mode_names)})")
        unknown = sorted(set(cfg.params) - set(ap.params)) + sorted(set(cfg.stream_rates_hz) - set(ap.stream_rates_hz))
        if unknown:
            raise SimulationError(f"not parameters or streams of autopilot {ap.name!r}: {', '.join(unknown)}")
        self.params = ParamStore(ap.params, cfg.params, ints_bytewise=ap.param_ints_bytewise)
        arming_delay_s = cfg.arming_delay_s if cfg.arming_delay_s is not None \
            else ap.default_arming_delay_s(not self.vehicle.on_ground)
        self.commander = ap.commander(self.params, start_mode, cfg.start_armed, self.vehicle,
                                      arming_delay_s, cfg.offboard_reject_ack)
        tm = TelemetryBuilder(cfg.position_noise_cov_m2, cfg.velocity_noise_cov_m2ps2,
                              cfg.home_lat_deg, cfg.home_lon_deg, cfg.home_alt_m, cfg.geoid_separation_m, ap)
        self.autopilot = Autopilot(self.commander, self.params, tm, self.vehicle_links, cfg.stream_rates_hz,
                                   cfg.home_alt_m, ap.stream_rates_hz, system_id=self.system_id)
        origin = (cfg.home_lat_deg, cfg.home_lon_deg, cfg.home_alt_m)
        self.obstacles = [
            ObstacleSystem(ob, scenario.obstacle_sysid_base + i, scenario.obstacle_compid,
                           np.random.Generator(np.random.PCG64(seeds[1 + i])), i, origin, cfg.geoid_separation_m)
            for i, ob in enumerate(scenario.obstacles)
        ]
        self.recorder = TruthRecorder(scenario)
        self.stats: Counter[str] = Counter()
        self.taps: list[Tap] = []
        self._signing: tuple[bytes, float] | None = None  # (key, Unix time signing began)
        self._last_signing_text_us = -(10**12)
        self._parsers = {link: self._new_parser() for link in self.links}
        self._encoders: dict[tuple[str, int, int], mavlink2.MAVLink] = {}
        if signing is not None:
            self.enable_signing(*signing)  # before the first packet is encoded
        self._pending: list[Packet] = []
        self._est_t = -1
        self._est = (np.zeros(3), np.zeros(3))
        self.recorder.update(0.0, self.vehicle.position_ned_m, self._obstacle_positions(0))
        self._emit_due()

    # ------------------------------------------------------------------ helpers
    def _new_parser(self) -> mavlink2.MAVLink:
        p = mavlink2.MAVLink(file=None, srcSystem=self.system_id, srcComponent=COMPID)
        p.robust_parsing = True  # bad CRC / prefix -> BAD_DATA instead of an exception
        if self._signing is not None:
            enable_signing(p, self._signing[0], link_id=0, now_s=self._signing[1])
        return p

    def enable_signing(self, key: bytes, now_s: float) -> None:
        """MAVLink 2 signing from now on: every packet sent is signed (vehicle and obstacles
        alike, one network key), and unsigned or badly signed packets received are dropped,
        counted in ``stats["signature_rejected"]`` and reported by a STATUSTEXT at most
        every 5 s. ``now_s`` (Unix time) seeds the outgoing signing timestamps."""
        self._signing = (bytes(key), float(now_s))
        for mav in self._parsers.values():
            enable_signing(mav, key, link_id=0, now_s=now_s)
        for (link, _, _), mav in self._encoders.items():
            enable_signing(mav, key, link_id=self.links.index(link), now_s=now_s)

    @property
    def time_s(self) -> float:
        """Simulated seconds since boot."""
        return self.now_us * 1e-6

    @property
    def goal_reached_t_s(self) -> float | None:
        """Simulation time (s) at which the true position first came within the goal tolerance, or None."""
        return self.recorder.goal_reached_t_s

    def _estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """Noisy (position, velocity) estimate, sampled once per time instant."""
        if self._est_t != self.now_us:
            w = self._rng.standard_normal(6)
            v = self.vehicle
            velocity = v.velocity_ned_mps + self._Lv @ w[3:]
            if self._velocity_bias is not None:    # the velocity estimate the velocity loop flies on
                velocity = velocity + self._velocity_bias.bias(self.now_us * 1e-6)
            position = v.position_ned_m + self._position_error.sample(self.now_us, w[:3])
            done = [step for t_us, step in self._resets if t_us <= self.now_us]
            if done:   # the estimator's resets so far: the estimate stepped, the counter counts them
                position = position + np.sum(done, axis=0)
            drift, outage_s, outages_ended = self._gps_outage(self.now_us)
            position = position + drift
            tm = self.autopilot.tm
            tm.reset_counter = (len(done) + outages_ended) % 256   # each outage ends in a reset to the GPS
            tm.gps_fix = outage_s is None
            tm.extra_horizontal_var_m2 = 0.0 if outage_s is None else (self._gps_sd_growth_mps * outage_s) ** 2
            sd = self._gps_degradation_sd(self.now_us)
            if sd:
                position = position + sd * self._gps_noise.sample(self.now_us, self._gps_noise_rng.standard_normal(3))
                tm.extra_horizontal_var_m2 += sd * sd
            tm.gps_degraded_sd_m = sd
            self._est = (position, velocity)
            self._est_t = self.now_us
        return self._est

    def _gps_degradation_sd(self, now_us: int) -> float:
        """The extra horizontal standard deviation of a degraded GPS now (m; 0 when it is not)."""
        for start_us, end_us, sd in self._gps_degradations:
            if start_us <= now_us < end_us:
                return sd
        return 0.0

    def _gps_outage(self, now_us: int) -> tuple[np.ndarray, float | None, int]:
        """The estimate's dead-reckoning drift now (NED m), how long the outage in progress has
        lasted (s; None: the GPS is there) and how many outages have ended (``[sim] gps_outages``)."""
        ended = 0
        for start_us, end_us, velocity in self._gps_outages:
            if now_us >= end_us:
                ended += 1
            elif now_us >= start_us:
                tau = (now_us - start_us) * 1e-6
                return velocity * tau, tau, ended
        return np.zeros(3), None, ended

    @property
    def obstacles_started_s(self) -> float | None:
        """Simulated time (s) the obstacles' motion started, or None before engagement."""
        return None if self.motion_epoch_us is None else self.motion_epoch_us / 1e6

    def _motion_s(self, now_us: int) -> float:
        """Time on the obstacles' scripted tracks at ``now_us`` (s; 0 before their start)."""
        if self.motion_epoch_us is None:
            return 0.0
        return (now_us - self.motion_epoch_us) * 1e-6

    def _check_engaged(self) -> None:
        """Start the obstacles' motion at the first armed OFFBOARD (``obstacles_start = "offboard"``),
        or when the gate says so (a fleet: once every vehicle has engaged)."""
        if self.motion_epoch_us is None and self._obstacles_gate(self.commander.engaged):
            self.motion_epoch_us = self.now_us
            logger.info("t=%.2f engaged: obstacles start moving", self.now_us * 1e-6)

    def _obstacle_positions(self, now_us: int) -> np.ndarray:
        t_s = self._motion_s(now_us)
        return np.array([o.track.position(t_s) for o in self.obstacles]).reshape(-1, 3)

    def _encode(self, link: str, sysid: int, compid: int, msg) -> bytes:
        key = (link, sysid, compid)
        mav = self._encoders.get(key)
        if mav is None:
            mav = self._encoders[key] = mavlink2.MAVLink(file=None, srcSystem=sysid, srcComponent=compid)
            if self._signing is not None:
                enable_signing(mav, self._signing[0], link_id=self.links.index(link), now_s=self._signing[1])
        buf = bytes(msg.pack(mav))
        mav.seq = (mav.seq + 1) % 256
        return buf

    def _send(self, link: str, sysid: int, compid: int, msg) -> None:
        data = self._encode(link, sysid, compid, msg)
        self._pending.append((self.now_us, link, data))
        self.stats["packets_sent"] += 1
        for tap in self.taps:
            tap("out", link, self.now_us, data)

    def _flush_texts(self) -> None:
        texts = self.commander.texts
        if texts:
            for severity, text in texts:
                msg = statustext(severity, text)
                for link in self.vehicle_links:
                    self._send(link, self.system_id, COMPID, msg)
            texts.clear()

    def _emit_due(self) -> None:
        self._check_engaged()
        self._flush_texts()
        if self.commander.announce:
            pos, vel = self._estimate()
            for msg_id in self.commander.announce:
                msg = self.autopilot.tm.build(msg_id, self.now_us, self.commander, self.vehicle, pos, vel)
                for link in self.vehicle_links:
                    self._send(link, self.system_id, COMPID, msg)
            self.commander.announce.clear()
        for link, msg in self.autopilot.streams_due(self.now_us, self.vehicle, self._estimate):
            self._send(link, self.system_id, COMPID, msg)
        api = self.links[0]
        motion_s = None if self.motion_epoch_us == 0 else self._motion_s(self.now_us)
        for ob in self.obstacles:
            for route, msg in ob.due(self.now_us, motion_s):
                if route == AUTOPILOT_ALL_LINKS:
                    for link in self.vehicle_links:
                        self._send(link, self.system_id, COMPID, msg)
                else:
                    self._send(api if route == OWN_API_LINK else OBSTACLE_LINK, ob.sysid, ob.compid, msg)

    # ------------------------------------------------------------------ public
    def receive(self, data: bytes, link: str | None = None, *, datagram: bool = False) -> None:
        """Bytes from a client on ``link`` (default: the API link), any chunking.

        Complete packets are handled at the current time; garbage, bad CRCs and
        truncated packets are counted and dropped, never raised. With ``datagram``
        (UDP) the bytes are one whole datagram: parsing starts fresh, so the partial
        packet a previous datagram ended with cannot swallow this one.
        """
        link = link or self.links[0]
        parser = self._parsers[link]
        if datagram:
            parser.buf, parser.buf_index = bytearray(), 0
            parser.expected_length, parser.have_prefix_error = mavlink2.HEADER_LEN_V1 + 2, False
        try:
            msgs = parser.parse_buffer(bytes(data)) or []
        except Exception as exc:  # pymavlink raises on some malformed input even in robust mode
            logger.warning("parse error on %s: %s", link, exc)
            self.stats["parse_errors"] += 1
            self._parsers[link] = self._new_parser()
            return
        for msg in msgs:
            mtype = msg.get_type()
            if mtype == "BAD_DATA":
                self.stats["bad_data"] += 1
                if "signature" in str(getattr(msg, "reason", "")):
                    self._signature_rejected()
                continue
            if isinstance(msg, mavlink2.MAVLink_unknown):  # unknown id: no CRC check possible
                self.stats["unknown_messages"] += 1
                continue
            raw = bytes(msg.get_msgbuf())
            for tap in self.taps:
                tap("in", link, self.now_us, raw)
            if link == OBSTACLE_LINK:  # obstacle senders take no input: count what reached them
                self.stats["obstacle_link_received"] += 1
                continue
            self.stats["packets_received"] += 1
            try:
                replies = self.autopilot.handle(msg, link, self.now_us, self.vehicle, self._estimate)
            except Exception:  # a handler bug must not kill the vehicle; log it loudly
                logger.exception("error handling %s", msg.get_type())
                self.stats["handler_errors"] += 1
                continue
            for out_link, reply in replies:
                self._send(out_link, self.system_id, COMPID, reply)
        self._check_engaged()
        self._flush_texts()

    def _signature_rejected(self) -> None:
        self.stats["signature_rejected"] += 1
        if self.now_us - self._last_signing_text_us >= 5_000_000:
            self._last_signing_text_us = self.now_us
            self.commander.texts.append(
                (SEV_WARNING, f"Rejected bad or no signature ({self.stats['signature_rejected']} so far)"))

    def advance_to(self, t_us: int) -> list[Packet]:
        """Run until ``t_us`` (us since boot); return the packets sent meanwhile, in order."""
        if t_us < self.now_us:
            raise SimulationError(f"cannot go back in time from {self.now_us} us to {t_us} us")
        while self.now_us < t_us:
            h = min(self.step_us, t_us - self.now_us)
            dt = h * 1e-6
            if self._gps_outages:
                self.commander.position_aiding(self._gps_outage(self.now_us)[1], self.now_us * 1e-6, self.vehicle)
            cmd = self.commander.update(self.now_us * 1e-6, dt, self.vehicle)
            if self._velocity_bias is not None:    # the loop holds the biased estimate on the setpoint
                cmd = dataclasses.replace(cmd, velocity_ned_mps=cmd.velocity_ned_mps
                                          - self._velocity_bias.bias(self.now_us * 1e-6))
            self.vehicle = step(self.vehicle, cmd, dt, self.vparams)
            self.now_us += h
            self.recorder.update(self.now_us * 1e-6, self.vehicle.position_ned_m,
                                 self._obstacle_positions(self.now_us))
            self._emit_due()
        out, self._pending = self._pending, []
        return out

    def drain(self) -> list[Packet]:
        """Packets queued since the last call (e.g. replies to :meth:`receive`)."""
        out, self._pending = self._pending, []
        return out

    @property
    def truth(self) -> Truth:
        """True state now."""
        t = self.now_us * 1e-6
        pos, vel = {}, {}
        for o in self.obstacles:
            p, v = o.track.state(self._motion_s(self.now_us))
            pos[o.name], vel[o.name] = p, v
        v = self.vehicle
        return Truth(t, v.position_ned_m.copy(), v.velocity_ned_mps.copy(), v.yaw_rad, v.on_ground,
                     self.commander.armed, self.commander.mode, pos, vel)

    def trace_rows(self) -> list[dict]:
        """The truth trace (see :meth:`mavsim.truth.TruthRecorder.trace_rows`)."""
        return self.recorder.trace_rows()

    def summary(self) -> dict:
        """JSON-serialisable run summary: truth metrics, final state, link statistics."""
        v = self.vehicle
        out = {
            "scenario": self.scenario.name,
            "seed": self.seed,
            "sim_time_s": self.time_s,
            **self.recorder.summary(),
            "final_position_ned_m": [float(x) for x in v.position_ned_m],
            "final_mode": self.commander.mode,
            "armed": self.commander.armed,
            "obstacles_start": self.obstacles_start,
            "obstacles_started_s": self.obstacles_started_s,
            "mode_changes": [{"t_s": round(t, 6), "mode": m} for t, m in self.commander.mode_changes],
            "link": {**{k: int(n) for k, n in sorted(self.stats.items())},
                     **{k: int(n) for k, n in sorted(self.autopilot.stats.items())}},
        }
        return out
