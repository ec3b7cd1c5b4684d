"""Several vehicles in one world over UDP (``mavsim --vehicles N``), as PX4's multi-instance SITL.

Vehicle i (0 .. N-1) is a :class:`~mavsim.core.Simulator` of its own: system id ``1 + i``,
its own autopilot, noise (seed ``seed * 1000 + i``) and links, on PX4's multi-instance
ports shifted by i::

    API link:       local api_local_port + i  ->  api_port + i          (14580+i -> 14540+i)
    GCS link:       local gcs_local_port + i  ->  gcs_port              (18570+i -> 14550: one GCS sees all)
    obstacle link:  local obstacle_local_port + i -> obstacle_port + i   (14591+i -> 14601+i)

Its start and goal are the scenario's rotated by ``360 deg * i / N`` about the vertical
through their midpoint (the swap, when they are on opposite sides of a circle); the
world (scripted traffic, walls) is the same for all. Each vehicle's simulator reports the
traffic to its own companion; nothing of one vehicle reaches another's links: companions
know of each other only through what they announce to each other.

With ``obstacles_start = "offboard"`` the traffic of every vehicle waits at its start points
until every vehicle has been armed in OFFBOARD once, and then moves for all of them from that
moment (:class:`EveryVehicleEngaged`): the encounter meets the whole fleet in flight however
long each companion took to start.

Each vehicle runs its :class:`~mavsim.udp.UdpServer` in a thread of its own. The referee:
each simulator judges its vehicle against the traffic; :func:`pair_clearances` judges
every pair of vehicles from their truth traces (10 Hz), with the closest approach of
straight-line motion between samples.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import math
import threading
from collections.abc import Sequence

import numpy as np

from mavsim.core import OBSTACLE_LINK, Simulator
from mavsim.errors import SimulationError
from mavsim.scenario import Scenario
from mavsim.udp import LinkAddress, UdpServer

logger = logging.getLogger(__name__)

__all__ = ["MAX_VEHICLES", "rotated", "rotated_scenarios", "pair_clearances", "EveryVehicleEngaged", "FleetServer"]

#: Most vehicles one mavsim serves.
MAX_VEHICLES = 16


def rotated(start: np.ndarray, goal: np.ndarray | None, i: int, n: int) -> tuple[np.ndarray, np.ndarray | None]:
    """Vehicle i of n's start and goal (NED m): ``start`` and ``goal`` rotated by ``2 pi i / n`` about the
    vertical through their midpoint (about the start alone without a goal)."""
    start = np.asarray(start, dtype=float)
    goal = None if goal is None else np.asarray(goal, dtype=float)
    centre = start if goal is None else 0.5 * (start + goal)
    a = 2.0 * math.pi * i / n
    rot = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
    return centre + rot @ (start - centre), None if goal is None else centre + rot @ (goal - centre)


def rotated_scenarios(scenario: Scenario, n: int) -> list[Scenario]:
    """N copies of ``scenario``, vehicle i's start and goal rotated by ``2 pi i / n`` about the
    vertical through the midpoint of the start and the goal (the start alone without a goal)."""
    if not 1 <= n <= MAX_VEHICLES:
        raise SimulationError(f"--vehicles must be 1 to {MAX_VEHICLES}, got {n}")
    out = []
    for i in range(n):
        start, goal = rotated(scenario.start_ned_m, scenario.goal_ned_m, i, n)
        out.append(dataclasses.replace(scenario, name=f"{scenario.name}-{i + 1}", start_ned_m=start, goal_ned_m=goal))
    return out


def pair_clearances(traces: Sequence[Sequence[dict]], radii: Sequence[float]) -> dict[str, dict]:
    """Every pair's smallest true distance (m), clearance (distance less both radii, m) and when (s),
    from the vehicles' truth traces (rows ``t_s``, ``drone_ned_m``) on their common time span."""
    out: dict[str, dict] = {}
    series = [(np.array([r["t_s"] for r in tr], dtype=float), np.array([r["drone_ned_m"] for r in tr], dtype=float))
              for tr in traces]
    for i, j in itertools.combinations(range(len(series)), 2):
        (ti, pi), (tj, pj) = series[i], series[j]
        if len(ti) < 2 or len(tj) < 2:
            continue
        t = ti[(ti >= max(ti[0], tj[0])) & (ti <= min(ti[-1], tj[-1]))]
        if len(t) < 2:
            continue
        a = np.column_stack([np.interp(t, ti, pi[:, k]) for k in range(3)])
        b = np.column_stack([np.interp(t, tj, pj[:, k]) for k in range(3)])
        r0, dr = (a - b)[:-1], np.diff(a - b, axis=0)
        denom = np.einsum("ij,ij->i", dr, dr)
        s = np.where(denom > 1e-12, np.clip(-np.einsum("ij,ij->i", r0, dr) / np.maximum(denom, 1e-12), 0.0, 1.0), 0.0)
        d = np.linalg.norm(r0 + s[:, None] * dr, axis=1)
        k = int(np.argmin(d))
        out[f"{i + 1}-{j + 1}"] = {"min_distance_m": float(d[k]), "min_clearance_m": float(d[k] - radii[i] - radii[j]),
                                   "t_s": float(t[k] + s[k] * (t[k + 1] - t[k]))}
    return out


class EveryVehicleEngaged:
    """The fleet's obstacle start: vehicle i's :meth:`gate` lets its traffic move once every
    vehicle of the ``n`` has reported itself engaged (each from its own server thread)."""

    def __init__(self, n: int) -> None:
        self._engaged = [False] * int(n)

    @property
    def engaged(self) -> list[bool]:
        """Which vehicles have engaged so far."""
        return list(self._engaged)

    def gate(self, i: int):
        """Vehicle i's ``obstacles_gate`` (:class:`~mavsim.core.Simulator`)."""
        def ready(engaged: bool) -> bool:
            if engaged:
                self._engaged[i] = True   # one list slot a thread: no lock needed
            return all(self._engaged)
        return ready


class FleetServer:
    """N vehicles, each its own simulator and :class:`~mavsim.udp.UdpServer`, served in threads.

    Parameters
    ----------
    scenarios : one per vehicle (:func:`rotated_scenarios`).
    seed : vehicle i's noise seed is ``seed * 1000 + i``.
    api_port, api_local_port, gcs_port, gcs_local_port, obstacle_port, obstacle_local_port :
        vehicle 0's ports (see the module docstring); ``None`` GCS ports: no GCS link.
    bind, target_host : as for one vehicle.
    **sim_kwargs : passed to every :class:`~mavsim.core.Simulator` (personality, signing, obstacles_start).
    """

    def __init__(self, scenarios: Sequence[Scenario], *, seed: int, api_port: int, api_local_port: int,
                 gcs_port: int | None, gcs_local_port: int | None, obstacle_port: int, obstacle_local_port: int,
                 bind: str = "127.0.0.1", target_host: str = "127.0.0.1", speed: float = 1.0, **sim_kwargs) -> None:
        if not 1 <= len(scenarios) <= MAX_VEHICLES:
            raise SimulationError(f"a fleet has 1 to {MAX_VEHICLES} vehicles, got {len(scenarios)}")
        self.sims: list[Simulator] = []
        self.servers: list[UdpServer] = []
        self.engagement = EveryVehicleEngaged(len(scenarios))
        try:
            for i, sc in enumerate(scenarios):
                links = [LinkAddress("api", _shift(api_local_port, i), api_port + i, bind, target_host)]
                if gcs_port is not None and gcs_local_port is not None:
                    links.append(LinkAddress("gcs", _shift(gcs_local_port, i), gcs_port, bind, target_host))
                sim = Simulator(sc, seed=int(seed) * 1000 + i, links=tuple(link.name for link in links),
                                system_id=1 + i, obstacles_gate=self.engagement.gate(i), **sim_kwargs)
                if OBSTACLE_LINK in sim.links:
                    links.append(LinkAddress(OBSTACLE_LINK, _shift(obstacle_local_port, i), obstacle_port + i, bind,
                                             target_host))
                self.sims.append(sim)
                self.servers.append(UdpServer(sim, links, speed=speed))
        except SimulationError:
            self.close()
            raise

    @property
    def local_ports(self) -> list[dict[str, int]]:
        return [s.local_ports for s in self.servers]

    def run(self, duration_s: float | None) -> None:
        """Serve every vehicle until ``duration_s`` simulated seconds or :meth:`stop`."""
        errors: list[BaseException] = []

        def serve(server: UdpServer) -> None:
            try:
                server.run(duration_s)
            except BaseException as exc:   # one vehicle's failure stops the fleet, and is raised below
                errors.append(exc)
                self.stop()

        threads = [threading.Thread(target=serve, args=(s,), name=f"mavsim-vehicle-{i + 1}", daemon=True)
                   for i, s in enumerate(self.servers)]
        for t in threads:
            t.start()
        for t in threads:
            while t.is_alive():
                t.join(0.2)   # short joins: the main thread stays free to take a signal
        if errors:
            raise errors[0]

    def stop(self) -> None:
        for s in self.servers:
            s.stop()

    def close(self) -> None:
        for s in self.servers:
            s.close()

    def summary(self) -> dict:
        """Each vehicle's own summary (``vehicles``), every pair's (``pairs``), and the fleet's verdict."""
        per = [sim.summary() for sim in self.sims]
        pairs = pair_clearances([sim.trace_rows() for sim in self.sims], [sim.scenario.vehicle_radius_m for sim in self.sims])
        return {
            "vehicles": len(per),
            "collided": any(p.get("collided") for p in per) or any(v["min_clearance_m"] < 0.0 for v in pairs.values()),
            "goal_reached": all(p.get("goal_reached") for p in per),
            "min_pair_clearance_m": min((v["min_clearance_m"] for v in pairs.values()), default=None),
            "pairs": pairs,
            "per_vehicle": per,
        }

    def __enter__(self) -> "FleetServer":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _shift(port: int, i: int) -> int:
    """Vehicle i's local port: ``port + i`` (0 stays 0: any free port)."""
    return 0 if port == 0 else port + i
