"""Mission campaigns (``--family mission``): randomised missions guarded in lockstep, against the autopilot alone.

Each episode (:mod:`companion.offline.campaign.mission_episodes`: a mission, its geofence, traffic
across its legs) is flown by mavsim's PX4 mission with the companion beside it, once per method:

- ``hyperplane``, ``deterministic``: ``[offboard] takeover = "guard"`` with that planner
  formulation: the companion arms nothing (the drone hovers armed), starts the mission, takes
  over in OFFBOARD when it predicts a conflict or a fence crossing on the autopilot's path, and
  gives back once the path is clear;
- ``alone``: ``takeover = "watch"``: the autopilot flies the mission by itself (the companion
  starts it and only watches): the baseline.

Scores per run, judged in mavsim's truth: any collision with the traffic, the smallest true
clearance; the drone's body outside the fence (every tick's true position against the
inclusion rectangle and the building, less the drone's radius); the mission completed (every
waypoint reached, by the autopilot or the companion, in order) and when (s after the run's start);
takeovers, their time, and the smallest realised contour of touch while taken over (the
planner's promise: never below ``c_min``). The summary gives per method the rates with exact
(Clopper-Pearson) 95 % intervals, and the time to complete against the same episode flown alone.

Results file: JSON lines (:mod:`companion.offline.campaign.rows_file`), a header (format
``ogccmpc-mission-campaign``, seed, ``c_min``) then one row per run; ``resume`` flies only
the missing runs. A run is a pure function of its task: the same in a pool worker or on Dask.
"""

from __future__ import annotations

import json
import logging
import math
import os
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from companion.core.fence import Fence, PolygonZone
from companion.errors import InputError
from companion.offline.campaign.generate import episode_sim_seed
from companion.offline.campaign.mission_episodes import generate_mission
from companion.offline.campaign.progress import Progress
from companion.offline.campaign.rows_file import RunRow, dash, fly_rows, open_rows, read_rows
from companion.offline.campaign.run import MAX_EPISODES
from companion.offline.campaign.stats import clopper_pearson

logger = logging.getLogger(__name__)

FORMAT = "ogccmpc-mission-campaign"
VERSION = 1
FAMILY = "mission"
ALONE = "alone"
METHODS = ("hyperplane", "deterministic", ALONE)
#: how long the run goes on once the truth has the drone at the last waypoint (s): its last
#: MISSION_ITEM_REACHED comes with the next MISSION_CURRENT
STOP_AFTER_GOAL_S = 2.0


@dataclass(frozen=True)
class MissionTask:
    """One (episode, method) run; picklable."""

    seed: int
    index: int
    method: str
    c_min: float = 0.90


@dataclass
class MissionRun(RunRow):
    """One finished run: its key, its scores (None on error) and its wall time. Metres, seconds."""

    episode: int
    method: str
    sim_seed: int
    waypoints: int = 0
    aircraft: int = 0
    building: bool = False
    collided: bool | None = None
    min_true_clearance_m: float | None = None
    fence_breached: bool | None = None
    min_fence_clearance_m: float | None = None     #: the body's, truth: negative outside the fence
    completed: bool | None = None
    mission_s: float | None = None                 #: the last waypoint reached, s after the run's start
    takeovers: int = 0
    taken_over_s: float = 0.0
    min_realised_contour: float | None = None      #: while taken over (None: never planned)
    slack_replans: int = 0
    failed_plans: int = 0
    wall_time_s: float = 0.0
    error: str | None = None

    @property
    def key(self) -> tuple[int, str]:
        return self.episode, self.method


def _reached(companion) -> list[tuple[float, int]]:
    """Every mission item reached, by the autopilot or the companion, as (link time s, seq), in order."""
    if companion.guard is not None:
        return [(t, seq) for t, seq, _ in companion.guard.items_reached()]
    return sorted(companion.progress.reached)


def run_mission_episode(task: MissionTask) -> MissionRun:
    """Generate, fly and score one (episode, method) run; never raises (errors are reported)."""
    from companion.offline.harness import run_lockstep

    sim_seed = episode_sim_seed(task.seed, task.index)
    t0 = time.perf_counter()
    try:
        ep = generate_mission(task.seed, task.index, c_min=task.c_min)
        data = json.loads(json.dumps(ep.scenario))
        if task.method != ALONE:
            data["planner"]["formulation"] = task.method
        data["offboard"] = {"arm": True, "takeover": "watch" if task.method == ALONE else "guard"}
        with tempfile.TemporaryDirectory(prefix="mission-") as tmp:
            plan = Path(tmp) / "mission.plan"
            plan.write_text(json.dumps(ep.plan))
            data["mission"]["plan_file"] = str(plan)
            run = run_lockstep(data, seed=sim_seed, stop_after_goal_s=STOP_AFTER_GOAL_S, truth_every_tick=True)
        c = run.companion
        radius = float(ep.scenario["vehicle"]["radius_m"])
        fence = Fence(polygons=tuple(PolygonZone(np.asarray(ring, dtype=float), inclusion) for ring, inclusion in ep.fence))
        trace = run.extra["truth_trace"]
        fence_clear = min(fence.clearance(p) for _, p in trace) - radius if trace else None
        # the waypoints are items 1..K (item 0 the DO_CHANGE_SPEED): each reached, the first time in order
        first: dict[int, float] = {}
        for t, seq in _reached(c):
            first.setdefault(seq, t)
        wanted = range(1, len(ep.waypoints) + 1)
        times = [first.get(seq) for seq in wanted]
        completed = all(t is not None for t in times) and times == sorted(times)
        takeovers = c.guard.summary()["takeovers"] if c.guard is not None else []
        taken = sum((k["end_s"] if k["end_s"] is not None else run.sim_time_s) - k["start_s"] for k in takeovers)
        statuses = [r.status for r in c.records]
        clearances = [v for v in run.truth.get("min_clearance_m", {}).values() if v is not None]
        return MissionRun(
            episode=task.index, method=task.method, sim_seed=sim_seed, waypoints=len(ep.waypoints),
            aircraft=len(ep.crossings), building=len(ep.fence) > 1, collided=bool(run.truth.get("collided")),
            min_true_clearance_m=min(clearances) if clearances else None,
            fence_breached=fence_clear is not None and fence_clear < 0.0,
            min_fence_clearance_m=None if fence_clear is None else round(float(fence_clear), 4),
            completed=completed, mission_s=times[-1] if completed else None, takeovers=len(takeovers),
            taken_over_s=round(float(taken), 3), min_realised_contour=c.state.min_realised_contour,
            slack_replans=statuses.count("slack"), failed_plans=statuses.count("failed"),
            wall_time_s=time.perf_counter() - t0)
    except Exception as exc:  # one bad episode must not end a campaign of hundreds
        logger.error("mission episode %d method %s failed: %s: %s", task.index, task.method, type(exc).__name__, exc)
        return MissionRun(episode=task.index, method=task.method, sim_seed=sim_seed,
                          error=f"{type(exc).__name__}: {exc}", wall_time_s=time.perf_counter() - t0)


def mission_header(seed: int, c_min: float) -> dict:
    return {"format": FORMAT, "version": VERSION, "family": FAMILY, "seed": int(seed), "c_min": float(c_min)}


def read_mission_results(path: Path) -> tuple[dict | None, dict[tuple[int, str], MissionRun]]:
    """The header and the rows of a mission campaign's results file."""
    return read_rows(path, FORMAT, "mission campaign", lambda obj: MissionRun(**obj))


@dataclass
class MissionSummary:
    """One method's row of the table (rates over the runs that ended without an error)."""

    method: str
    runs: int
    errors: int
    collisions: int
    collision_ci: tuple[float, float]
    fence_breaches: int
    fence_ci: tuple[float, float]
    completed: int
    completed_ci: tuple[float, float]
    mission_median_s: float | None
    time_over_alone_median: float | None    #: per episode completed by both, this method's time over alone's
    takeovers_per_mission: float
    taken_over_median_s: float | None
    promise_broken: int                     #: runs whose realised contour fell below c_min while taken over
    min_realised_contour: float | None
    min_true_clearance_m: float | None
    min_fence_clearance_m: float | None
    slack_replans: int
    failed_plans: int

    def to_json(self) -> dict:
        return asdict(self)


def summarise_missions(runs: Sequence[MissionRun], methods: Sequence[str], c_min: float) -> list[MissionSummary]:
    alone = {r.episode: r.mission_s for r in runs if r.method == ALONE and r.error is None and r.completed}
    out = []
    for method in methods:
        rs = [r for r in runs if r.method == method]
        ok = [r for r in rs if r.error is None]
        n = len(ok)
        k_col = sum(bool(r.collided) for r in ok)
        k_fence = sum(bool(r.fence_breached) for r in ok)
        k_done = sum(bool(r.completed) for r in ok)
        times = [r.mission_s for r in ok if r.completed]
        ratios = [r.mission_s / alone[r.episode] for r in ok if r.completed and alone.get(r.episode)]
        taken = [r.taken_over_s for r in ok if r.takeovers]
        contours = [r.min_realised_contour for r in ok if r.min_realised_contour is not None]
        clear = [r.min_true_clearance_m for r in ok if r.min_true_clearance_m is not None]
        fence = [r.min_fence_clearance_m for r in ok if r.min_fence_clearance_m is not None]
        out.append(MissionSummary(
            method=method, runs=n, errors=len(rs) - n, collisions=k_col, collision_ci=clopper_pearson(k_col, n),
            fence_breaches=k_fence, fence_ci=clopper_pearson(k_fence, n), completed=k_done,
            completed_ci=clopper_pearson(k_done, n), mission_median_s=float(np.median(times)) if times else None,
            time_over_alone_median=float(np.median(ratios)) if ratios else None,
            takeovers_per_mission=sum(r.takeovers for r in ok) / n if n else 0.0,
            taken_over_median_s=float(np.median(taken)) if taken else None,
            promise_broken=sum(c < c_min for c in contours), min_realised_contour=min(contours) if contours else None,
            min_true_clearance_m=min(clear) if clear else None, min_fence_clearance_m=min(fence) if fence else None,
            slack_replans=sum(r.slack_replans for r in ok), failed_plans=sum(r.failed_plans for r in ok)))
    return out


def _ci(k: int, ci: tuple[float, float]) -> str:
    return f"{k} [{100 * ci[0]:.1f}, {100 * ci[1]:.1f} %]"


def format_mission_table(rows: Sequence[MissionSummary], c_min: float) -> str:
    lines = [f"mission campaign, c_min {c_min:g} (alone: the autopilot flies the mission by itself, watched)",
             "| method | runs | collisions [95 % CI] | fence breaches [95 % CI] | completed [95 % CI] | median time s "
             "| time / alone (median) | takeovers per mission | median time taken over s | contour < c_min "
             "| smallest realised contour | smallest true clearance m | smallest body clearance to the fence m |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r.method} | {r.runs}{f' (+{r.errors} errors)' if r.errors else ''} | {_ci(r.collisions, r.collision_ci)} "
            f"| {_ci(r.fence_breaches, r.fence_ci)} | {_ci(r.completed, r.completed_ci)} | {dash(r.mission_median_s, 1)} "
            f"| {dash(r.time_over_alone_median, 3)} | {r.takeovers_per_mission:.2f} | {dash(r.taken_over_median_s, 1)} "
            f"| {r.promise_broken} | {dash(r.min_realised_contour, 4)} | {dash(r.min_true_clearance_m, 3)} "
            f"| {dash(r.min_fence_clearance_m, 3)} |")
    return "\n".join(lines)


@dataclass
class MissionCampaign:
    seed: int
    c_min: float
    runs: list[MissionRun]
    summary: list[MissionSummary]
    wall_s: float
    workers: int
    extra: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"family": FAMILY, "seed": self.seed, "c_min": self.c_min,
                "summary": [s.to_json() for s in self.summary], "runs": [r.to_json() for r in self.runs],
                "wall_s": self.wall_s, "workers": self.workers, **self.extra}


def run_mission_campaign(episodes: Sequence[int], methods: Sequence[str], seed: int, *, workers: int | None = None,
                         c_min: float = 0.90, results_path: str | Path | None = None, resume: bool = False,
                         scheduler: str | None = None, progress: str = "auto") -> MissionCampaign:
    """Fly ``episodes`` of the mission family with every method (see the module docstring)."""
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise InputError(f"unknown method(s) {', '.join(unknown) or '(none given)'} for --family mission "
                         f"(known: {', '.join(METHODS)})")
    if not (math.isfinite(c_min) and 0.0 < c_min < 1.0):
        raise InputError(f"c_min = {c_min!r} must be between 0 and 1")
    keys = [(int(i), m) for i in episodes for m in methods]
    if any(not 0 <= i < MAX_EPISODES for i, _ in keys):
        raise InputError(f"episode indices run from 0 to {MAX_EPISODES - 1}")
    out, done = open_rows(results_path, mission_header(seed, c_min), resume, "mission campaign",
                          lambda obj: MissionRun(**obj))
    todo = [MissionTask(seed, i, m, c_min) for i, m in keys if (i, m) not in done]
    workers = max(1, min(workers or os.cpu_count() or 1, len(todo) or 1))
    bar = Progress("campaign mission", len(keys), len(keys) - len(todo), mode=progress)
    n_workers, lost, wall_s = fly_rows(run_mission_episode, todo, workers, scheduler, out, done, bar)
    runs = [done[k] for k in keys if k in done]
    return MissionCampaign(int(seed), float(c_min), runs, summarise_missions(runs, methods, c_min), wall_s,
                           n_workers, extra={"lost": lost})
