"""Scoring one flown episode: what the simulator's truth says happened, beside the companion's view.

The promise under test: with the chance constraint the probability of a collision with
one obstacle at one step is at most ``Phi(-r)``, ``r = sqrt(chi2_3.ppf(c))`` for the
contour of touch ``c`` the plan kept. :func:`score_run` counts steps, (step, obstacle)
pairs, true collisions, realised contours and filter consistency (NEES) for one run.
"""

from __future__ import annotations

import hashlib
import logging
import math
import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from companion.loop.config import LoopConfig
from companion.offline.campaign.jsonable import to_jsonable
from companion.offline.campaign.reliability import PromiseTally, promised_probability
from companion.offline.slack import slack_report

logger = logging.getLogger(__name__)

#: (step, obstacle) pairs whose realised contour of touch is below this are *near*: the
#: collision constraint is close to active there (far pairs sit at c = 1.0).
ACTIVE_CONTOUR = 0.99


@dataclass(frozen=True)
class EpisodeScore:
    """What one (episode, method) run measured. Counts are over replan steps; NED metres, seconds.

    The three per-step lists and ``solve_times_s`` are pooled into the method's summary;
    the campaign's JSON report leaves them out of its per-episode rows (``POOLED``), the
    results file keeps them so that the summary can be computed from it.
    """

    n_obstacles: int
    collided: bool                       #: truth: any contact (obstacle or wall)
    obstacle_collision: bool             #: truth: contact with an obstacle
    collisions: int                      #: truth: number of contacts
    min_true_clearance_m: float | None   #: truth: smallest surface gap over the run
    goal_reached: bool
    time_to_goal_s: float | None
    steps: int                           #: replans on the replan_period_s grid
    pair_steps_in_range: int             #: (step, obstacle) pairs with the obstacle within sensing range
    pair_step_collisions: int            #: ... whose true centre distance was below the radius sum
    pair_time_in_range_s: float
    contact_time_s: float                #: seconds in true contact with an obstacle
    contour_pairs: int                   #: in-range (step, tracked obstacle) pairs with a realised contour
    contour_pairs_below_c_min: int
    steps_below_c_min: int
    min_realised_contour: float | None
    active_pairs: int                    #: near pairs (realised contour < ACTIVE_CONTOUR)
    active_pair_collisions: int
    predicted_collisions_bound: float    #: sum over pairs of Phi(-r(realised contour))
    drone_nees: list[float]
    relative_nees: list[float]
    model_step_error_m: list[float]
    replans: int
    failed_plans: int
    slack_plans: int
    slack_max: float
    slack_violation_contour: float       #: deepest c_min - realised contour at a slack replan (companion.offline.slack)
    slack_violation_m: float             #: ... and the largest missing separation, metres
    promise_pairs: list[int]             #: tracked in-range pairs per bin of promised p (reliability.PROMISE_EDGES), estimates' contour
    promise_hits: list[int]              #: ... of which the bodies truly overlapped
    promise_sum: list[float]             #: ... and the sum of their promised p
    solve_times_s: list[float]
    sim_time_s: float
    commands_sha256: str
    truth: dict = field(default_factory=dict)
    plan_promise_pairs: list[int] = field(default_factory=list)  #: constrained pairs per bin of the plan's promised p at its first step
    plan_promise_hits: list[int] = field(default_factory=list)   #: ... of which the bodies truly overlapped one step later
    plan_promise_sum: list[float] = field(default_factory=list)  #: ... and the sum of their promised p

    #: Per-step lists pooled into the summary and left out of the JSON report's rows.
    POOLED = ("solve_times_s", "drone_nees", "relative_nees", "model_step_error_m")

    def to_json(self, *, pooled: bool = True) -> dict:
        """Plain JSON values; without the per-step lists unless ``pooled``."""
        out = to_jsonable(self)
        return out if pooled else {k: v for k, v in out.items() if k not in self.POOLED}

    @classmethod
    def from_json(cls, row: dict) -> "EpisodeScore":
        """Inverse of :meth:`to_json` (``pooled=True``); unknown keys are ignored."""
        names = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in row.items() if k in names})


def _truth_one_step_later(replan_truth: list, step: float) -> list:
    """For each replan, the truth at the replan ``step`` seconds later (``None`` when there was none)."""
    out = []
    for i, (t, _, _) in enumerate(replan_truth):
        later = None
        for j in range(i + 1, len(replan_truth)):
            dt = replan_truth[j][0] - t
            if abs(dt - step) < 1e-6:
                later = replan_truth[j]
            if dt > step + 1e-6:
                break
        out.append(later)
    return out


def score_run(run: Any, data: dict) -> EpisodeScore:
    """Per-episode metrics from a :class:`~companion.offline.harness.RunResult` and its scenario dict.

    Steps are replans at least ``replan_period_s`` apart: the companion replans every
    ``replan_period_s``, also while it brakes after a failed plan, so normally every
    replan is a step (a replan closer than that to the previous step is not counted
    twice). An obstacle is *in range* at a step when its true centre distance is within
    sensing range; a *step collision* is an in-range obstacle whose true distance is below the
    sum of the physical radii. The realised contour of touch (from the estimates,
    ``ReplanRecord.realised_contour``) is counted for tracked obstacles within range. The
    plan's promise (``ReplanRecord.planned_contour``, its first step) is scored against the
    truth at the replan ``step_s`` later (the time of that step), when there is one.
    """
    truth = run.truth
    comp = run.companion
    records = comp.records
    replan_truth = run.extra["replan_truth"]
    if len(replan_truth) != len(records):
        raise RuntimeError(f"truth at replans ({len(replan_truth)}) does not match replans ({len(records)})")
    planner = data["planner"]
    period, c_min, sensing = planner["replan_period_s"], planner["c_min"], planner["sensing_range_m"]
    step = planner.get("step_s", period)
    obstacles = data["world"]["obstacles"]
    names = [o["name"] for o in obstacles]
    radius_sum = data["vehicle"]["radius_m"] + np.array([o["radius_m"] for o in obstacles])

    sysid_base = data["world"].get("obstacle_sysid_base", 101)
    steps = pair_steps = pair_hits = contour_pairs = contour_below = steps_below = 0
    active_pairs = active_hits = 0
    bound_sum = 0.0
    min_contour = math.inf
    drone_nees: list[float] = []
    rel_nees: list[float] = []
    model_err: list[float] = []
    estimates_promise, plan_promise = PromiseTally(), PromiseTally()
    truth_next = _truth_one_step_later(replan_truth, step)
    prev = None  # (t, true drone position, planned displacement over the first step)
    last_t = -math.inf
    for rec, (_, p_true, obs_true), after in zip(records, replan_truth, truth_next):
        if rec.t_link_s < last_t + period - 1e-6:
            continue
        if after is not None:
            for key, ct in rec.planned_contour.items():
                j = key[0] - sysid_base
                if 0 <= j < len(names):
                    plan_promise.add(promised_probability(ct), bool(np.linalg.norm(after[2][names[j]] - after[1]) < radius_sum[j]))
        if prev is not None and abs(rec.t_link_s - prev[0] - step) < 1e-6:
            # model mismatch: true displacement over one step against the planner's tau * V_1
            model_err.append(float(np.linalg.norm((p_true - prev[1]) - prev[2])))
        prev = (rec.t_link_s, p_true, None if rec.status == "failed" else rec.plan_positions[0] - rec.drone_position)
        if prev[2] is None:
            prev = None
        last_t = rec.t_link_s
        steps += 1
        e = rec.drone_position - p_true
        drone_nees.append(float(e @ np.linalg.solve(rec.drone_cov, e)))   # e' S^-1 e ~ chi2_3 if consistent
        if names:
            d = np.linalg.norm(np.array([obs_true[n] for n in names]) - p_true, axis=1)
            in_range = d <= sensing
            pair_steps += int(in_range.sum())
            pair_hits += int((in_range & (d < radius_sum)).sum())
        below_here = False
        for key, ct in rec.realised_contour.items():
            rel_est = rec.obstacle_positions[key] - rec.drone_position
            if np.linalg.norm(rel_est) > sensing:
                continue
            contour_pairs += 1
            min_contour = min(min_contour, ct)
            promise = promised_probability(ct)
            bound_sum += promise
            if ct < c_min:
                contour_below += 1
                below_here = True
            j = key[0] - sysid_base
            if 0 <= j < len(names):
                rel_true = obs_true[names[j]] - p_true
                err = rel_est - rel_true
                rel_nees.append(float(err @ np.linalg.solve(rec.drone_cov + rec.obstacle_covs[key], err)))
                estimates_promise.add(promise, bool(np.linalg.norm(rel_true) < radius_sum[j]))
                if ct < ACTIVE_CONTOUR:
                    active_pairs += 1
                    active_hits += int(np.linalg.norm(rel_true) < radius_sum[j])
        steps_below += below_here
    statuses = [r.status for r in records]
    radius_assumed = data["vehicle"]["radius_m"] + data.get("companion", {}).get("obstacle_radius_m", LoopConfig.obstacle_radius_m)
    slack = slack_report(records, c_min, radius_assumed, sensing)
    commands = np.array([r.command for r in records]).reshape(-1, 3)
    obstacle_collisions = [c for c in truth.get("collisions", []) if c.get("kind") == "obstacle"]
    # continuous-time view of the same quantity: seconds in contact (truth checks every physics step)
    contact_s = sum((c["t_end_s"] if c.get("t_end_s") is not None else run.sim_time_s) - c["t_start_s"]
                    for c in obstacle_collisions)
    return EpisodeScore(
        n_obstacles=len(names),
        collided=bool(truth.get("collided")),
        obstacle_collision=bool(obstacle_collisions),
        collisions=len(truth.get("collisions", [])),
        min_true_clearance_m=min((v for v in truth.get("min_clearance_m", {}).values() if v is not None), default=None),
        goal_reached=bool(truth.get("goal_reached")),
        time_to_goal_s=truth.get("time_to_goal_s"),
        steps=steps,
        pair_steps_in_range=pair_steps,
        pair_step_collisions=pair_hits,
        pair_time_in_range_s=pair_steps * period,
        contact_time_s=float(contact_s),
        contour_pairs=contour_pairs,
        contour_pairs_below_c_min=contour_below,
        steps_below_c_min=steps_below,
        min_realised_contour=None if not math.isfinite(min_contour) else float(min_contour),
        active_pairs=active_pairs,
        active_pair_collisions=active_hits,
        predicted_collisions_bound=bound_sum,
        drone_nees=drone_nees,
        relative_nees=rel_nees,
        model_step_error_m=model_err,
        replans=len(records),
        failed_plans=statuses.count("failed"),
        slack_plans=statuses.count("slack"),
        slack_max=max((r.slack_max for r in records if r.status != "failed"), default=0.0),  # failed: inf
        slack_violation_contour=slack.largest_violation_contour,
        slack_violation_m=slack.largest_violation_m,
        promise_pairs=estimates_promise.pairs,
        promise_hits=estimates_promise.hits,
        promise_sum=estimates_promise.sums,
        plan_promise_pairs=plan_promise.pairs,
        plan_promise_hits=plan_promise.hits,
        plan_promise_sum=plan_promise.sums,
        solve_times_s=[float(r.solve_time_s) for r in records],
        sim_time_s=float(run.sim_time_s),
        commands_sha256=hashlib.sha256(np.ascontiguousarray(commands).tobytes()).hexdigest(),
        truth={k: truth[k] for k in ("collided", "collisions", "min_distance_m", "goal_reached",
                                        "time_to_goal_s", "path_length_m") if k in truth},
    )
