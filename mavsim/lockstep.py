"""Lockstep: the simulator behind an in-memory byte link, no sockets, no sleeping.

Contract (docs/ARCHITECTURE.md)::

    sim = LockstepSimulator.from_file("configs/antipodal.toml", seed=0)
    sim.time_s                  # simulated seconds since boot
    sim.write(packet_bytes)     # bytes to the vehicle's API port (any chunking)
    out = sim.advance(0.05)     # [(t_s, packet_bytes), ...] in send order, one packet each (API link)
    obs = sim.take_obstacle_packets()   # what the obstacle link sent meanwhile (transport = "link")
    sim.summary()               # dict (JSON-serialisable)
    sim.truth                   # mavsim.truth.Truth

The physics runs in fixed steps of ``[sim] physics_step_s`` (default 0.01 s); an
``advance`` that does not end on that grid ends with one shorter step. Bytes written
are handled at the current simulated time; their replies come out of the next
``advance`` stamped with that time. Same scenario, seed and call sequence give
byte-identical output (and tlog).
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

from mavsim.core import OBSTACLE_LINK, Simulator
from mavsim.personalities import DEFAULT_PERSONALITY
from mavsim.errors import SimulationError
from mavsim.scenario import Scenario, load_scenario, scenario_from_dict
from mavsim.tlog import LOCKSTEP_EPOCH_US, TlogWriter
from mavsim.truth import Truth

logger = logging.getLogger(__name__)

__all__ = ["LockstepSimulator"]


class LockstepSimulator:
    """Deterministic in-process simulator exchanging raw MAVLink bytes.

    Parameters
    ----------
    scenario : Scenario, dict (parsed TOML) or path
    seed : int
    tlog : path or None
        Record every packet sent and received on the API link, and sent on the obstacle
        link (stamped with
        :data:`mavsim.tlog.LOCKSTEP_EPOCH_US` plus simulated time).
    personality : str
        The autopilot imitated (:data:`mavsim.personalities.PERSONALITIES`).
    system_id : int
        The vehicle's MAVLink system id (default 1; a fleet gives each vehicle its own).
    """

    def __init__(self, scenario: Scenario | dict[str, Any] | str | Path, seed: int = 0,
                 tlog: str | Path | None = None, personality: str = DEFAULT_PERSONALITY, system_id: int = 1) -> None:
        if isinstance(scenario, dict):
            scenario = scenario_from_dict(scenario)
        elif not isinstance(scenario, Scenario):
            scenario = load_scenario(scenario)
        self._sim = Simulator(scenario, seed=seed, links=("api",), personality=personality, system_id=system_id)
        self._tlog = TlogWriter(tlog) if tlog is not None else None
        self._obstacle_packets: list[tuple[float, bytes]] = []
        if self._tlog is not None:
            # The boot packets were queued before the tap existed; record them on output.
            self._sim.taps.append(self._record_in)

    @classmethod
    def from_file(cls, path: str | Path, seed: int = 0, tlog: str | Path | None = None,
                  personality: str = DEFAULT_PERSONALITY) -> "LockstepSimulator":
        """Load a scenario file (raises :class:`mavsim.ScenarioError` naming file/section/key)."""
        return cls(load_scenario(path), seed=seed, tlog=tlog, personality=personality)

    def _record_in(self, direction: str, link: str, t_us: int, data: bytes) -> None:
        if direction == "in" and self._tlog is not None:
            self._tlog.write(LOCKSTEP_EPOCH_US + t_us, data)

    @property
    def time_s(self) -> float:
        """Simulated seconds since boot."""
        return self._sim.time_s

    @property
    def simulator(self) -> Simulator:
        """The underlying :class:`mavsim.core.Simulator` (for tests and tools)."""
        return self._sim

    def write(self, data: bytes) -> None:
        """Bytes a client sends to the vehicle's API port."""
        self._sim.receive(data)

    def advance(self, dt_s: float) -> list[tuple[float, bytes]]:
        """Advance ``dt_s`` seconds; return ``[(t_s, packet), ...]`` in send order."""
        if not math.isfinite(dt_s) or dt_s < 0:
            raise SimulationError(f"advance needs a finite dt_s >= 0, got {dt_s}")
        packets = self._sim.advance_to(self._sim.now_us + round(dt_s * 1e6))
        api = [(t_us, data) for t_us, link, data in packets if link == "api"]
        self._obstacle_packets.extend((t_us * 1e-6, data) for t_us, link, data in packets if link == OBSTACLE_LINK)
        if self._tlog is not None:  # the API link and the obstacle link: what a companion hears
            for t_us, link, data in packets:
                if link in ("api", OBSTACLE_LINK):
                    self._tlog.write(LOCKSTEP_EPOCH_US + t_us, data)
        return [(t_us * 1e-6, data) for t_us, data in api]

    @property
    def has_obstacle_link(self) -> bool:
        """Whether some obstacle sends on the separate obstacle link."""
        return OBSTACLE_LINK in self._sim.links

    def take_obstacle_packets(self) -> list[tuple[float, bytes]]:
        """``[(t_s, packet), ...]`` the obstacle link sent since the last call, in send order."""
        out, self._obstacle_packets = self._obstacle_packets, []
        return out

    def summary(self) -> dict:
        """Run summary (see :meth:`mavsim.core.Simulator.summary`)."""
        return self._sim.summary()

    def trace_rows(self) -> list[dict]:
        """The truth trace (see :meth:`mavsim.truth.TruthRecorder.trace_rows`)."""
        return self._sim.trace_rows()

    @property
    def goal_reached_t_s(self) -> float | None:
        """When the truth first reached the goal, simulation seconds, or None (the summary's
        ``time_to_goal_s``, without building the summary)."""
        return self._sim.goal_reached_t_s

    @property
    def truth(self) -> Truth:
        """True state of the drone and obstacles now."""
        return self._sim.truth

    def close(self) -> None:
        """Flush and close the tlog, if any."""
        if self._tlog is not None:
            self._tlog.close()

    def __enter__(self) -> "LockstepSimulator":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
