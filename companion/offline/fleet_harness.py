"""Fly a fleet in lockstep: N vehicles in one world, each with its own autopilot and companion.

Vehicle i is a :class:`mavsim.lockstep.LockstepSimulator` with system id ``1 + i`` and its
own scenario (start, goal); the world's traffic is the same scripted aircraft in every
one of them (each vehicle's simulator reports them with its own noise, as each drone's
own sensing would). Its companion (:class:`~companion.loop.app.Companion` with
``fleet=True``) hears its vehicle and its obstacle link, and a fleet link (``"fleet"``,
its identity the vehicle's system id, component 191) on which every other companion's
announcements arrive one tick after they were sent. The drones know of each other only
through those announcements: nothing passes between the simulators.

Referee. Each simulator judges its own vehicle against the traffic; the harness judges
every pair of vehicles, on their true positions at each tick with the closest approach
between ticks (straight-line motion over the 50 ms tick): a collision is a distance below
the sum of the two radii.

Deterministic: a seed fixes every byte (vehicle i's noise is seeded ``(seed, i)``).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from companion.core import jit
from companion.loop.app import Companion
from companion.loop.config import read_scenario_toml
from companion.loop.driver import Driver
from companion.loop.intake.traffic_config import FLEET_LINK
from companion.mavlink.link import MemoryLink
from companion.offline.harness import LOCKSTEP_EPOCH_S, RunResult, ScenarioSource, StepPort, _parse
from companion.offline.report import min_peer_contour, run_report
from mavsim.lockstep import LockstepSimulator

__all__ = ["FleetResult", "run_fleet_lockstep", "FLEET_COMPONENT", "FLEET_LINK", "PAIR_RANGE_M"]

#: The component id a companion announces its vehicle under (MAV_COMP_ID_ONBOARD_COMPUTER).
FLEET_COMPONENT = 191
#: Pairs of vehicles at most this far apart (m) count in the per-step collision frequency (the sensing range).
PAIR_RANGE_M = 10.0


@dataclass
class FleetResult:
    """Outcome of one fleet run.

    Attributes
    ----------
    drones : each vehicle's :class:`~companion.offline.harness.RunResult` (its truth against the traffic).
    pair_min_distance_m : {(i, j): smallest true distance between vehicles i < j, m}.
    pair_min_clearance_m : {(i, j): that distance less the two radii, m (< 0: collided)}.
    sim_time_s : simulated seconds flown.
    fleet_packets : announcements carried between companions.
    pair_ticks, pair_contact_ticks : (pair, tick) samples with the two vehicles within
        :data:`PAIR_RANGE_M` of each other, and of those the ones in contact (distance below both
        radii): the per-step collision frequency between drones is their ratio.
    """

    drones: list[RunResult]
    pair_min_distance_m: dict
    pair_min_clearance_m: dict
    sim_time_s: float
    fleet_packets: int = 0
    pair_ticks: int = 0
    pair_contact_ticks: int = 0
    extra: dict = field(default_factory=dict)

    def summary(self) -> dict:
        """The fleet's figures (JSON-serialisable): any collision, all goals, per drone and per pair."""
        per = [d.summary() for d in self.drones]
        pairs = {f"{i + 1}-{j + 1}": round(c, 4) for (i, j), c in sorted(self.pair_min_clearance_m.items())}
        drone_collided = [bool(p.get("collided")) for p in per]
        pair_collided = [c < 0.0 for c in self.pair_min_clearance_m.values()]
        times = [p.get("time_to_goal_s") for p in per]
        peer_contour = [min_peer_contour(d.companion) for d in self.drones]
        peer_contour = [c for c in peer_contour if c is not None]
        return {
            "drones": len(self.drones),
            "collided": any(drone_collided) or any(pair_collided),
            "drone_traffic_collisions": sum(drone_collided),
            "drone_drone_collisions": sum(pair_collided),
            "goal_reached": all(p.get("goal_reached") for p in per),
            "time_to_all_goals_s": None if any(t is None for t in times) else round(max(times), 3),
            "min_pair_clearance_m": min(self.pair_min_clearance_m.values()) if self.pair_min_clearance_m else None,
            "pair_min_clearance_m": pairs,
            "min_peer_realised_contour": min(peer_contour) if peer_contour else None,
            "fleet_packets": self.fleet_packets,
            "deadlocks": sum(_deadlocks(d.companion) for d in self.drones),
            "pair_ticks": self.pair_ticks,
            "pair_contact_ticks": self.pair_contact_ticks,
            "sim_time_s": round(self.sim_time_s, 3),
            "per_drone": [{k: (round(p[k], 3) if isinstance(p.get(k), float) else p.get(k))
                           for k in ("collided", "goal_reached", "time_to_goal_s", "min_true_clearance_m",
                                     "replans", "replans_with_slack", "failed_plans", "min_realised_contour")}
                          for p in per],
        }


def _deadlocks(companion: Companion) -> int:
    row = companion.builder.right_of_way
    return 0 if row is None else row.watch.deadlocks


def _closest_approach(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> float:
    """Smallest distance between two points moving straight from a0 to a1 and b0 to b1 over the same interval."""
    r0, dr = a0 - b0, (a1 - a0) - (b1 - b0)
    denom = float(dr @ dr)
    s = 0.0 if denom < 1e-12 else min(1.0, max(0.0, -float(r0 @ dr) / denom))
    return float(np.linalg.norm(r0 + s * dr))


def run_fleet_lockstep(scenarios: Sequence[ScenarioSource], *, seed: int = 0, duration_s: float | None = None,
                       coordination: str | None = None, stop_after_goal_s: float | None = 2.0,
                       autopilot: str | None = None, signing_key: bytes | None = None,
                       silent_after_s: dict[int, float] | None = None,
                       inject: Callable[[float], list[bytes]] | None = None) -> FleetResult:
    """Fly N drones together in lockstep (see the module docstring).

    Parameters
    ----------
    scenarios : one scenario per drone (parsed-TOML dicts, e.g. :func:`companion.offline.swap.swap_scenarios`,
        or files); drone i gets system id ``1 + i``. Their worlds must be the same.
    seed : seeds every vehicle's noise.
    duration_s : simulated time limit (default: the longest scenario's).
    coordination : replaces every drone's ``[fleet] coordination`` (None: each scenario's own).
    stop_after_goal_s : end the run this long after the truth says every drone reached its goal.
    autopilot : the autopilot mavsim imitates (None: PX4).
    signing_key : every fleet link signs with this 32-byte key and drops unsigned or badly signed
        packets (counted in ``extra["signature_rejected"]``, per drone).
    silent_after_s : {drone index: simulated s}: that drone's announcements stop reaching the others
        then (its companion keeps flying and sending; a radio that died).
    inject : ``inject(t_s) -> [packet, ...]``: packets put on the fleet bus at each tick, delivered to
        every drone (a forger on the fleet's radio).
    """
    if not 1 <= len(scenarios) <= 100:
        raise ValueError(f"a fleet has 1 to 100 drones, got {len(scenarios)}")
    configs, sims, companions, drivers, links, obstacle_links, fleet_links = [], [], [], [], [], [], []
    for i, source in enumerate(scenarios):
        data = source if isinstance(source, dict) else read_scenario_toml(source)
        config, sim_scenario = _parse(data, {})
        sim = LockstepSimulator(sim_scenario, seed=int(seed) * 1000 + i, system_id=1 + i,
                                **({} if autopilot is None else {"personality": autopilot}))
        if coordination is not None:
            config = dataclasses.replace(config, fleet=dataclasses.replace(config.fleet, coordination=coordination))
        companion = Companion(config, fleet=True)
        clock = (lambda s=sim: s.time_s)
        link = MemoryLink(clock=clock, tlog_offset_s=LOCKSTEP_EPOCH_S)
        obstacle_link = (MemoryLink(clock=clock, name="obstacles1", receive_only=True, tlog_offset_s=LOCKSTEP_EPOCH_S)
                         if sim.has_obstacle_link else None)
        fleet_link = MemoryLink(clock=clock, name=FLEET_LINK, source_system=1 + i, source_component=FLEET_COMPONENT,
                                signing_key=signing_key)
        configs.append(config)
        sims.append(sim)
        companions.append(companion)
        links.append(link)
        obstacle_links.append(obstacle_link)
        fleet_links.append(fleet_link)
        drivers.append(Driver(companion, StepPort(link), fleet_port=StepPort(fleet_link)))
    jit.warm_up()
    n = len(sims)
    dt = 1.0 / configs[0].companion.setpoint_rate_hz
    if any(abs(1.0 / c.companion.setpoint_rate_hz - dt) > 1e-12 for c in configs):
        raise ValueError("every drone of a lockstep fleet must tick at the same setpoint rate")
    limit = max(c.duration_s for c in configs) if duration_s is None else float(duration_s)
    radii = [c.drone_radius_m for c in configs]
    pairs = list(itertools.combinations(range(n), 2))
    pair_min = {p: math.inf for p in pairs}
    positions = [s.truth.drone_position_ned_m.copy() for s in sims]
    bus: list[tuple[int, bytes]] = []   # (sender, packet) sent at the last tick, delivered at this one
    carried = 0
    pair_ticks = pair_contacts = 0
    all_goals_t: float | None = None
    try:
        for _ in range(int(math.ceil(limit / dt - 1e-9))):
            sent: list[tuple[int, bytes]] = []
            for i in range(n):
                sim, link, driver = sims[i], links[i], drivers[i]
                for t_pkt, packet in sim.advance(dt):
                    link.deliver(t_pkt, packet)
                for rx in link.poll():
                    driver.receive(rx)
                if obstacle_links[i] is not None:
                    for t_pkt, packet in sim.take_obstacle_packets():
                        obstacle_links[i].deliver(t_pkt, packet)
                    for rx in obstacle_links[i].poll():
                        driver.receive(rx)
                for sender, packet in bus:
                    if sender != i:
                        fleet_links[i].deliver(sim.time_s, packet)
                        carried += sender >= 0
                for rx in fleet_links[i].poll():
                    driver.receive(rx)
                driver.tick(sim.time_s)
                for packet in link.take_outbound():
                    sim.write(packet)
                sent.extend((i, p) for p in fleet_links[i].take_outbound())
            silent = silent_after_s or {}
            bus = [(k, p) for k, p in sent if not (k in silent and sims[0].time_s >= silent[k])]
            if inject is not None:
                bus.extend((-1, p) for p in inject(sims[0].time_s))
            now = [s.truth.drone_position_ned_m.copy() for s in sims]
            for (i, j) in pairs:
                d = _closest_approach(positions[i], now[i], positions[j], now[j])
                if d < pair_min[(i, j)]:
                    pair_min[(i, j)] = d
                now_d = float(np.linalg.norm(now[i] - now[j]))
                if now_d <= PAIR_RANGE_M:
                    pair_ticks += 1
                    pair_contacts += now_d < radii[i] + radii[j]
            positions = now
            if stop_after_goal_s is not None:
                if all_goals_t is None and all(s.goal_reached_t_s is not None for s in sims):
                    all_goals_t = sims[0].time_s
                if all_goals_t is not None and sims[0].time_s - all_goals_t >= stop_after_goal_s:
                    break
        drones = [RunResult(scenario=configs[i].name, seed=int(seed) * 1000 + i,
                            formulation=configs[i].planner.formulation, truth=sims[i].summary(),
                            companion=companions[i], sim_time_s=sims[i].time_s) for i in range(n)]
        return FleetResult(
            drones=drones,
            pair_min_distance_m=dict(pair_min),
            pair_min_clearance_m={(i, j): d - radii[i] - radii[j] for (i, j), d in pair_min.items()},
            sim_time_s=sims[0].time_s,
            fleet_packets=carried,
            pair_ticks=pair_ticks,
            pair_contact_ticks=int(pair_contacts),
            extra={"signature_rejected": [link.stats.signature_rejected for link in fleet_links]},
        )
    finally:
        for link in (*links, *fleet_links, *(o for o in obstacle_links if o is not None)):
            link.close()
        for sim in sims:
            sim.close()


def fleet_report(result: FleetResult) -> dict:
    """:meth:`FleetResult.summary` with each drone's full report under ``reports``."""
    return {**result.summary(), "reports": [run_report(d.companion, d.truth) for d in result.drones]}
