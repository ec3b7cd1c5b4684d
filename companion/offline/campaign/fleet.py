"""Fleet campaigns: randomised swaps of N drones, flown per coordination mode.

Episode ``i`` of a campaign with seed ``S`` draws from ``np.random.default_rng([S, i, N])``:
a circle of radius 5-8 m turned by a random angle, N drones on it bound for the opposite
points (:func:`companion.offline.swap.swap_scenarios`), and two aircraft crossing it on
random chords (bearing any, 0-0.5 radius off the centre, 1.0-2.0 m/s). Every drone takes
the aircraft's reports and the other drones' announcements from :data:`REPORT_RANGE_M`
(``[traffic] range_m``), not from the planner's 10 m sensing range: both come by radio, and
two drones closing at 5 m/s have 2 s inside 10 m. The simulators' seed is
``episode_sim_seed(S, i)``. Each (episode, mode) run is
:func:`~companion.offline.fleet_harness.run_fleet_lockstep` with that coordination mode; a
run is a pure function of its task, so it runs the same in a pool worker or on a Dask
cluster (:func:`companion.offline.campaign.run.open_executor`).

Scores per run: any collision (drone to drone in the harness's truth, drone to traffic in
each simulator's), all goals, time to all goals, the smallest clearance and realised
contour between drones, deadlocks, and the (pair, tick) samples within 10 m and in contact
(the per-step collision frequency between drones, against ``Phi(-r_min)``).

Results file: JSON lines, a header (format ``ogccmpc-fleet-campaign``, family, drones, seed,
``c_min``, duration, report range) then one row per finished run; ``resume`` flies only the
missing runs and refuses a file whose header differs.
"""

from __future__ import annotations

import logging
import math
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from companion.errors import InputError
from companion.loop.fleet_config import COORDINATION_MODES
from companion.offline.campaign.generate import episode_sim_seed
from companion.offline.campaign.progress import Progress
from companion.offline.campaign.rows_file import RunRow, dash, fly_rows, open_rows, read_rows
from companion.offline.campaign.stats import clopper_pearson, collision_bound

logger = logging.getLogger(__name__)

FORMAT = "ogccmpc-fleet-campaign"
VERSION = 1
FAMILY = "swap"
RADIUS_RANGE_M = (5.0, 8.0)
TRAFFIC_SPEED_MPS = (1.0, 2.0)
#: m: how far out every drone plans around the aircraft and the other drones (``[traffic] range_m``).
REPORT_RANGE_M = 30.0


def generate_swap(seed: int, index: int, drones: int, *, c_min: float = 0.90, duration_s: float = 40.0) -> list[dict]:
    """Episode ``index`` of a swap campaign: one scenario dict per drone (see the module docstring)."""
    from companion.offline.swap import SWAP_BASE, swap_scenarios

    rng = np.random.default_rng([int(seed), int(index), int(drones)])
    radius = float(rng.uniform(*RADIUS_RANGE_M))
    rotation = float(rng.uniform(0.0, 2.0 * math.pi / drones))
    traffic = [(float(rng.uniform(0.0, 2.0 * math.pi)), float(rng.uniform(-0.5, 0.5)),
                float(rng.uniform(*TRAFFIC_SPEED_MPS))) for _ in range(2)]
    scenarios = swap_scenarios(drones, radius_m=radius, rotation_rad=rotation, traffic_specs=traffic, base=SWAP_BASE,
                               duration_s=duration_s)
    for s in scenarios:
        s["planner"] = {**s.get("planner", {}), "c_min": float(c_min)}
        s["traffic"] = {**s.get("traffic", {}), "range_m": REPORT_RANGE_M}
    return scenarios


@dataclass(frozen=True)
class FleetTask:
    """One (episode, mode) run; picklable."""

    seed: int
    index: int
    drones: int
    mode: str
    c_min: float = 0.90
    duration_s: float = 40.0


@dataclass
class FleetRun(RunRow):
    """One finished run: its key, its scores (None on error) and its wall time."""

    episode: int
    mode: str
    drones: int
    sim_seed: int
    collided: bool | None = None
    drone_drone_collisions: int = 0
    drone_traffic_collisions: int = 0
    goal_reached: bool | None = None
    time_to_all_goals_s: float | None = None
    min_pair_clearance_m: float | None = None
    min_peer_realised_contour: float | None = None
    deadlocks: int = 0
    pair_ticks: int = 0
    pair_contact_ticks: int = 0
    slack_replans: int = 0
    failed_plans: int = 0
    wall_time_s: float = 0.0
    error: str | None = None

    @property
    def key(self) -> tuple[int, str]:
        return self.episode, self.mode


def run_fleet_episode(task: FleetTask) -> FleetRun:
    """Generate, fly and score one (episode, mode) run; never raises (errors are reported)."""
    from companion.offline.fleet_harness import run_fleet_lockstep

    sim_seed = episode_sim_seed(task.seed, task.index)
    t0 = time.perf_counter()
    try:
        scenarios = generate_swap(task.seed, task.index, task.drones, c_min=task.c_min, duration_s=task.duration_s)
        s = run_fleet_lockstep(scenarios, seed=sim_seed, coordination=task.mode, stop_after_goal_s=0.5).summary()
        return FleetRun(
            episode=task.index, mode=task.mode, drones=task.drones, sim_seed=sim_seed, collided=s["collided"],
            drone_drone_collisions=s["drone_drone_collisions"], drone_traffic_collisions=s["drone_traffic_collisions"],
            goal_reached=s["goal_reached"], time_to_all_goals_s=s["time_to_all_goals_s"],
            min_pair_clearance_m=s["min_pair_clearance_m"], min_peer_realised_contour=s["min_peer_realised_contour"],
            deadlocks=s["deadlocks"], pair_ticks=s["pair_ticks"], pair_contact_ticks=s["pair_contact_ticks"],
            slack_replans=sum(d["replans_with_slack"] or 0 for d in s["per_drone"]),
            failed_plans=sum(d["failed_plans"] or 0 for d in s["per_drone"]),
            wall_time_s=time.perf_counter() - t0)
    except Exception as exc:  # one bad episode must not end a campaign
        logger.error("swap episode %d mode %s failed: %s: %s", task.index, task.mode, type(exc).__name__, exc)
        return FleetRun(episode=task.index, mode=task.mode, drones=task.drones, sim_seed=sim_seed,
                        error=f"{type(exc).__name__}: {exc}", wall_time_s=time.perf_counter() - t0)


def fleet_header(drones: int, seed: int, c_min: float, duration_s: float) -> dict:
    return {"format": FORMAT, "version": VERSION, "family": FAMILY, "drones": int(drones), "seed": int(seed),
            "c_min": float(c_min), "duration_s": float(duration_s), "report_range_m": REPORT_RANGE_M}


def read_fleet_results(path: Path) -> tuple[dict | None, dict[tuple[int, str], FleetRun]]:
    """The header and the rows of a results file (:func:`companion.offline.campaign.rows_file.read_rows`)."""
    return read_rows(path, FORMAT, "fleet campaign", lambda obj: FleetRun(**obj))


@dataclass
class ModeSummary:
    """One coordination mode's row of the table."""

    mode: str
    runs: int
    errors: int
    collisions: int
    collision_ci: tuple[float, float]
    drone_drone: int
    drone_traffic: int
    goals: int
    time_to_all_goals_median_s: float | None
    min_pair_clearance_m: float | None
    promise_broken: int
    min_peer_realised_contour: float | None
    deadlock_runs: int
    pair_ticks: int
    pair_contact_ticks: int
    step_frequency: float | None
    bound: float

    def to_json(self) -> dict:
        return asdict(self)


def summarise_fleet(runs: Sequence[FleetRun], modes: Sequence[str], c_min: float) -> list[ModeSummary]:
    out = []
    bound = collision_bound(c_min)
    for mode in modes:
        rs = [r for r in runs if r.mode == mode]
        ok = [r for r in rs if r.error is None]
        k = sum(bool(r.collided) for r in ok)
        times = [r.time_to_all_goals_s for r in ok if r.time_to_all_goals_s is not None]
        clear = [r.min_pair_clearance_m for r in ok if r.min_pair_clearance_m is not None]
        contour = [r.min_peer_realised_contour for r in ok if r.min_peer_realised_contour is not None]
        ticks, contacts = sum(r.pair_ticks for r in ok), sum(r.pair_contact_ticks for r in ok)
        out.append(ModeSummary(
            mode=mode, runs=len(ok), errors=len(rs) - len(ok), collisions=k, collision_ci=clopper_pearson(k, len(ok)),
            drone_drone=sum(r.drone_drone_collisions > 0 for r in ok), drone_traffic=sum(r.drone_traffic_collisions > 0 for r in ok),
            goals=sum(bool(r.goal_reached) for r in ok),
            time_to_all_goals_median_s=float(np.median(times)) if times else None,
            min_pair_clearance_m=min(clear) if clear else None,
            promise_broken=sum(c < c_min for c in contour), min_peer_realised_contour=min(contour) if contour else None,
            deadlock_runs=sum(r.deadlocks > 0 for r in ok), pair_ticks=ticks, pair_contact_ticks=contacts,
            step_frequency=contacts / ticks if ticks else None, bound=bound))
    return out


def format_fleet_table(drones: int, rows: Sequence[ModeSummary], c_min: float) -> str:
    lines = [f"swap campaign, {drones} drones, c_min {c_min:g}",
             "| coordination | runs | collisions [95 % CI] | drone-drone | drone-traffic | all goals | median time to all goals s "
             "| smallest pair clearance m | realised contour < c_min | smallest realised contour | deadlocks | pair-step collision freq. (bound) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        freq = "-" if r.step_frequency is None else f"{r.step_frequency:.2e}"
        lines.append(
            f"| {r.mode} | {r.runs}{f' (+{r.errors} errors)' if r.errors else ''} | {r.collisions} "
            f"[{100 * r.collision_ci[0]:.1f}, {100 * r.collision_ci[1]:.1f} %] | {r.drone_drone} | {r.drone_traffic} | "
            f"{r.goals} | {dash(r.time_to_all_goals_median_s, 2)} | {dash(r.min_pair_clearance_m, 3)} | {r.promise_broken} | "
            f"{dash(r.min_peer_realised_contour, 4)} | {r.deadlock_runs} | {freq} ({r.bound:.2e}) |")
    return "\n".join(lines)


@dataclass
class FleetCampaign:
    drones: int
    seed: int
    c_min: float
    runs: list[FleetRun]
    summary: list[ModeSummary]
    wall_s: float
    workers: int
    extra: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"family": FAMILY, "drones": self.drones, "seed": self.seed, "c_min": self.c_min,
                "summary": [s.to_json() for s in self.summary], "runs": [r.to_json() for r in self.runs],
                "wall_s": self.wall_s, "workers": self.workers}


def run_fleet_campaign(drones: int, episodes: Sequence[int], modes: Sequence[str], seed: int, *,
                       workers: int | None = None, c_min: float = 0.90, duration_s: float = 40.0,
                       results_path: str | Path | None = None, resume: bool = False, scheduler: str | None = None,
                       progress: str = "auto") -> FleetCampaign:
    """Fly ``episodes`` of the swap with ``drones`` drones per coordination mode (see the module docstring)."""
    if not 2 <= int(drones) <= 16:
        raise InputError(f"a swap campaign flies 2 to 16 drones, got {drones}")
    unknown = [m for m in modes if m not in COORDINATION_MODES]
    if unknown or not modes:
        raise InputError(f"unknown coordination mode(s) {', '.join(unknown) or '(none given)'} "
                         f"(known: {', '.join(COORDINATION_MODES)})")
    keys = [(int(i), m) for i in episodes for m in modes]
    out, done = open_rows(results_path, fleet_header(drones, seed, c_min, duration_s), resume, "fleet campaign",
                          lambda obj: FleetRun(**obj))
    todo = [FleetTask(seed, i, drones, m, c_min, duration_s) for i, m in keys if (i, m) not in done]
    workers = max(1, min(workers or os.cpu_count() or 1, len(todo) or 1))
    bar = Progress(f"campaign swap x{drones}", len(keys), len(keys) - len(todo), mode=progress)
    n_workers, lost, wall_s = fly_rows(run_fleet_episode, todo, workers, scheduler, out, done, bar)
    runs = [done[k] for k in keys if k in done]
    return FleetCampaign(int(drones), int(seed), float(c_min), runs, summarise_fleet(runs, modes, c_min),
                         wall_s, n_workers, extra={"lost": lost})
