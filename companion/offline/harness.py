"""Run the bundled simulator and the companion together in one process, in lockstep.

This is the one place where ``companion`` imports ``mavsim`` (the dependency rule's
exception, see ``docs/ARCHITECTURE.md``): ``companion demo``, ``companion campaign`` and
the closed-loop tests use it. The two sides exchange real MAVLink bytes through a
:class:`~companion.mavlink.link.MemoryLink`; there are no sockets and no sleeping, and the same
seed gives the same run. Packet loss and other link faults are applied here, between
the two sides, by dropping whole packets.

Each step of :func:`run_lockstep` advances mavsim by one setpoint period, delivers what it
sent, and has the loop's :class:`~companion.loop.driver.Driver` receive every message and
tick once at mavsim's time; the harness decides only when (mavsim's clock) and what the
packets meet on the way (loss). The driver has no recorder here: the memory links record
what crosses them (``tlog_path``), so a lockstep tlog has no marks.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from companion.core import jit
from companion.loop.app import Companion
from companion.loop.driver import Driver
from companion.mavlink.link import MemoryLink
from companion.mavlink.offboard import OffboardConfig
from companion.offline.report import run_report
from companion.offline.slack import companion_slack_report
from companion.loop.config import CompanionScenario, load_scenario, scenario_from_dict
from mavsim.lockstep import LockstepSimulator
from mavsim.scenario import scenario_from_dict as sim_scenario_from_dict
from mavsim.tlog import LOCKSTEP_EPOCH_US

logger = logging.getLogger(__name__)

#: ``drop(t_s, direction, packet) -> bool``; direction is ``"to_companion"`` or ``"to_vehicle"``.
PacketFilter = Callable[[float, str, bytes], bool]

#: mavsim's lockstep epoch (2024-01-01T00:00:00Z) in seconds: the stamp of simulated time 0 in lockstep tlogs.
LOCKSTEP_EPOCH_S = LOCKSTEP_EPOCH_US / 1_000_000


@dataclass
class RunResult:
    """Outcome of one lockstep run: the simulator's truth and the companion's own records."""

    scenario: str
    seed: int
    formulation: str
    truth: dict
    companion: Companion
    sim_time_s: float
    dropped_packets: int = 0
    tlog_path: Path | None = None
    extra: dict = field(default_factory=dict)

    def summary(self) -> dict:
        """The numbers ``companion demo`` prints (JSON-serialisable): truth plus the companion's view,
        and under ``slack`` the slack replans and how far inside ``c_min`` they went."""
        return {"seed": self.seed, "dropped_packets": self.dropped_packets, **run_report(self.companion, self.truth),
                "slack": companion_slack_report(self.companion).to_json()}


class StepPort:
    """The lockstep driver's :class:`~companion.loop.driver.Port`: the companion's memory link.

    Everything sent in a step reaches mavsim together at the step's end, and is stamped in the
    link's tlog with the link's clock (mavsim's time then: a tick's time, and for an answer to
    a message received during the step, the step's end), as lockstep logs always were.
    """

    def __init__(self, link: MemoryLink) -> None:
        self.link = link

    def send(self, msg, t_s: float) -> bytes:
        """Send ``msg`` on the memory link (``t_s``, s, is not used: see the class docstring)."""
        return self.link.send(msg)


#: A scenario as ``run_lockstep`` takes it: a TOML file, or its parsed tables (``tomllib`` output).
ScenarioSource = str | Path | Mapping[str, Any]


def run_lockstep(
    scenario: ScenarioSource,
    *,
    seed: int = 0,
    duration_s: float | None = None,
    tlog_path: str | Path | None = None,
    sim_tlog_path: str | Path | None = None,
    drop: PacketFilter | None = None,
    loss_probability: float = 0.0,
    offboard: OffboardConfig | None = None,
    stop_after_goal_s: float | None = 2.0,
    inject: Callable[[float], list[bytes]] | None = None,
    inject_vehicle: Callable[[float], list[bytes]] | None = None,
    after_tick: Callable[[Companion, float, list], None] | None = None,
    autopilot: str | None = None,
    replan_history: int | None = None,
    truth_every_tick: bool = False,
    **planner_overrides,
) -> RunResult:
    """Fly one scenario in lockstep: ``mavsim`` and the companion over MAVLink bytes.

    Parameters
    ----------
    scenario : scenario TOML file, or its parsed tables (a dict, e.g. a generated campaign
        episode): both programs read it, parsed once; the companion never reads the
        obstacles' scripted paths.
    seed : seeds the simulator's noise and the packet loss.
    duration_s : simulated time limit (default: the scenario's ``duration_s``).
    tlog_path : record the companion's link as a tlog (what ``companion replay`` reads).
    sim_tlog_path : record the simulator's API link as a tlog.
    drop : extra packet filter (fault injection); ``loss_probability`` drops packets at
        random in both directions.
    stop_after_goal_s : end the run this long after the truth says the goal was reached.
    inject : ``inject(t_s) -> [packet, ...]`` extra packets delivered to the companion.
    inject_vehicle : ``inject_vehicle(t_s) -> [packet, ...]`` extra packets written to the vehicle
        after each tick's outbox (another ground station on its link: a mode switch).
    after_tick : ``after_tick(companion, t_s, outbox)`` after every tick (a view, :mod:`companion.view`).
    autopilot : the autopilot mavsim imitates (a name of ``mavsim.personalities.PERSONALITIES``,
        e.g. ``"ardupilot"``); None: mavsim's default (PX4).
    replan_history : keep only the latest this many replan records, as ``companion fly`` does
        (``Companion(replan_history=...)``); None keeps every one.
    truth_every_tick : keep the drone's true position (NED m) after every tick in
        ``extra["truth_trace"]`` as (sim time s, position) (a mission the autopilot flies
        itself has no replans to judge it at).
    **planner_overrides : replace ``[planner]`` keys (e.g. ``formulation``, ``c_max``).
    """
    if isinstance(scenario, (str, Path)):
        config = load_scenario(scenario, **planner_overrides)
        sim = LockstepSimulator.from_file(scenario, seed=seed, tlog=sim_tlog_path, **_personality(autopilot))
    else:
        config, sim_scenario = _parse(scenario, planner_overrides)
        sim = LockstepSimulator(sim_scenario, seed=seed, tlog=sim_tlog_path, **_personality(autopilot))
    companion = Companion(config, offboard=offboard, replan_history=replan_history)
    jit.warm_up()  # load the compiled kernels now, not inside the first solve (its reported solve time)
    link = MemoryLink(clock=lambda: sim.time_s, tlog=tlog_path, tlog_offset_s=LOCKSTEP_EPOCH_S)
    # Obstacles with transport = "link" arrive on their own receive-only link, as on a vehicle.
    # Recorded in the same tlog (replay routes other systems' traffic back to an obstacle link).
    obstacle_link = (MemoryLink(clock=lambda: sim.time_s, name="obstacles1", receive_only=True, tlog=link.tlog,
                                tlog_offset_s=LOCKSTEP_EPOCH_S)
                     if sim.has_obstacle_link else None)
    driver = Driver(companion, StepPort(link))  # no recorder: the links record what crosses them, no marks
    rng = np.random.default_rng([seed, 0xC0FFEE])
    dt = 1.0 / config.companion.setpoint_rate_hz
    limit = config.duration_s if duration_s is None else float(duration_s)
    dropped = 0
    goal_t: float | None = None
    # True state at each replan (campaign: per-step collision truth beside the estimates).
    replan_truth: list[tuple[float, np.ndarray, dict]] = []
    truth_trace: list[tuple[float, np.ndarray]] = []

    def lost(t_s: float, direction: str, packet: bytes) -> bool:
        if loss_probability > 0.0 and rng.random() < loss_probability:
            return True
        return drop is not None and drop(t_s, direction, packet)

    try:
        n_ticks = int(math.ceil(limit / dt - 1e-9))
        for _ in range(n_ticks):
            for t_pkt, packet in sim.advance(dt):
                if lost(t_pkt, "to_companion", packet):
                    dropped += 1
                    continue
                link.deliver(t_pkt, packet)
            if inject is not None:
                for packet in inject(sim.time_s):
                    link.deliver(sim.time_s, packet)
            for rx in link.poll():
                driver.receive(rx)
            if obstacle_link is not None:
                for t_pkt, packet in sim.take_obstacle_packets():
                    if lost(t_pkt, "to_companion", packet):
                        dropped += 1
                        continue
                    obstacle_link.deliver(t_pkt, packet)
                for rx in obstacle_link.poll():
                    driver.receive(rx)  # nothing answers obstacle traffic
            n_records = len(companion.records)
            outbox = driver.tick(sim.time_s)
            if after_tick is not None:
                after_tick(companion, sim.time_s, outbox)
            if truth_every_tick:
                truth_trace.append((sim.time_s, sim.truth.drone_position_ned_m.copy()))
            if len(companion.records) > n_records:
                tr = sim.truth
                replan_truth.append((tr.t_s, tr.drone_position_ned_m, tr.obstacle_positions_ned_m))
            for packet in link.take_outbound():
                if lost(sim.time_s, "to_vehicle", packet):
                    dropped += 1
                    continue
                sim.write(packet)
            if inject_vehicle is not None:
                for packet in inject_vehicle(sim.time_s):
                    sim.write(packet)
            if stop_after_goal_s is not None:
                if goal_t is None and sim.goal_reached_t_s is not None:   # not summary(): every tick
                    goal_t = sim.time_s
                if goal_t is not None and sim.time_s - goal_t >= stop_after_goal_s:
                    break
        truth = sim.summary()
        return RunResult(
            scenario=config.name,
            seed=seed,
            formulation=config.planner.formulation,
            truth=truth,
            companion=companion,
            sim_time_s=sim.time_s,
            dropped_packets=dropped,
            extra={"replan_truth": replan_truth, **({"truth_trace": truth_trace} if truth_every_tick else {})},
            tlog_path=Path(tlog_path) if tlog_path else None,
        )
    finally:
        link.close()
        if obstacle_link is not None:
            obstacle_link.close()
        sim.close()


def _personality(autopilot: str | None) -> dict:
    """LockstepSimulator's ``personality`` keyword for ``autopilot`` (none: mavsim's default)."""
    return {} if autopilot is None else {"personality": autopilot}


def _parse(data: Mapping[str, Any], planner_overrides: dict) -> tuple[CompanionScenario, Any]:
    """Both programs' views of one parsed scenario (errors name the scenario's ``name``)."""
    name = data.get("scenario", {}).get("name", "scenario")
    source = f"<scenario {name}>"
    return (scenario_from_dict(dict(data), source, **planner_overrides),
            sim_scenario_from_dict(dict(data), source))
