"""Statistics of a campaign: exact binomial intervals, the bound, one summary per method."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
from scipy.stats import beta, norm

from companion.core.overlap import touch_radius
from companion.errors import InputError
from companion.offline.campaign.jsonable import to_jsonable
from companion.offline.campaign.reliability import PROMISE_EDGES, ReliabilityBin, observed_over_promised

logger = logging.getLogger(__name__)

#: chi2_3 95 % quantile: a consistent filter's NEES exceeds it in 5 % of steps.
NEES_95 = 7.814727903251178


def clopper_pearson(k: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Exact (Clopper-Pearson) two-sided interval for a binomial proportion ``k / n``.

    ``lower = Beta(a/2; k, n-k+1)``, ``upper = Beta(1-a/2; k+1, n-k)`` with ``a = 1 - confidence``;
    ``lower = 0`` when ``k = 0`` and ``upper = 1`` when ``k = n``.
    """
    if n < 0 or not 0 <= k <= n:
        raise InputError(f"clopper_pearson needs 0 <= k <= n, got k={k}, n={n}")
    if n == 0:
        return 0.0, 1.0
    a = 1.0 - confidence
    lo = 0.0 if k == 0 else float(beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1 - a / 2, k + 1, n - k))
    return lo, hi


def collision_bound(c_min: float, dim: int = 3) -> float:
    """Per-step, per-obstacle collision bound ``Phi(-r_min)``, ``r_min = sqrt(chi2_dim.ppf(c_min))``."""
    return float(norm.cdf(-float(touch_radius(c_min, dim))))


def nees_mean_ci95(per_episode: Sequence[Sequence[float]]) -> tuple[float, float] | None:
    """95 % interval of the pooled mean NEES (every step of every episode), episodes as independent clusters.

    The steps of one episode are not independent (the errors of a filter are correlated in
    time, the more so under correlated noise), so the interval does not count steps: it is the
    normal interval of the ratio estimator ``sum(NEES) / steps`` with the cluster-robust
    standard error over episodes, ``sqrt(E/(E-1) * sum_i (s_i - m n_i)^2) / sum_i n_i`` (``s_i``
    the episode's NEES sum, ``n_i`` its steps, ``m`` the pooled mean, ``E`` the episodes with
    a step). A consistent filter's pooled mean is its dimension (3 for a position); the
    interval says whether the campaign could tell it from that. ``None`` with fewer than two
    episodes.
    """
    sums = np.array([float(np.sum(e)) for e in per_episode if len(e)])
    counts = np.array([len(e) for e in per_episode if len(e)], dtype=float)
    if sums.size < 2:
        return None
    mean = sums.sum() / counts.sum()
    se = float(np.sqrt(sums.size / (sums.size - 1) * np.sum((sums - mean * counts) ** 2)) / counts.sum())
    half = float(norm.ppf(0.975)) * se
    return float(mean - half), float(mean + half)


def reliability_bins(pairs: Sequence[int], hits: Sequence[int], promised_sum: Sequence[float]) -> tuple[ReliabilityBin, ...]:
    """Bins from pooled per-bin counts (pairs, hits) and sums of promised probabilities."""
    out = []
    for b, (n, k, s) in enumerate(zip(pairs, hits, promised_sum)):
        ci = clopper_pearson(int(k), int(n))
        mean = s / n if n else None
        out.append(ReliabilityBin(PROMISE_EDGES[b], PROMISE_EDGES[b + 1], int(n), int(k), mean,
                                  k / n if n else None, ci, bool(n and ci[0] > mean)))
    return tuple(out)


@dataclass(frozen=True)
class MethodSummary:
    """One method's campaign, pooled over its episodes (errors excluded; counts over replan steps)."""

    episodes: int
    errors: int
    collisions: int
    collision_rate: float | None
    collision_ci95: tuple[float, float]  #: 95 % Clopper-Pearson interval of collision_rate
    obstacle_collisions: int
    pair_steps_in_range: int
    pair_step_collisions: int
    pair_step_frequency: float | None  #: true collisions per in-range (step, obstacle) pair
    pair_step_ci95: tuple[float, float]
    bound_phi_minus_r_min: float  #: the promise: Phi(-r_min) per step and obstacle
    contact_time_s: float
    contact_time_share: float | None
    active_pairs: int  #: near pairs: realised contour < ACTIVE_CONTOUR
    active_pair_collisions: int
    active_pair_frequency: float | None
    active_pair_ci95: tuple[float, float]
    predicted_collisions_bound: float  #: sum over pairs of Phi(-r(realised contour))
    drone_nees_mean: float | None
    drone_nees_share_above_chi2_95: float | None
    relative_nees_mean: float | None
    relative_nees_share_above_chi2_95: float | None
    drone_nees_ci95: tuple[float, float] | None  #: 95 % interval of drone_nees_mean, episodes as clusters
    relative_nees_ci95: tuple[float, float] | None
    model_step_error_median_m: float | None
    model_step_error_p95_m: float | None
    model_step_error_max_m: float | None
    contour_pairs: int
    share_pairs_below_c_min: float | None
    steps: int
    share_steps_below_c_min: float | None
    goal_reached: int
    goal_rate: float | None
    time_to_goal_median_s: float | None
    time_to_goal_mean_s: float | None
    replans: int
    failed_plans: int
    failed_share: float | None
    episodes_with_failure: int
    slack_plans: int
    episodes_with_slack: int
    slack_max: float
    slack_violation_contour_max: float  #: deepest c_min - realised contour at a slack replan, any episode
    slack_violation_m_max: float  #: largest missing separation at a slack replan, metres
    reliability: tuple[ReliabilityBin, ...]  #: the estimates' promise against observed, per bin of promised p
    observed_over_promised: float | None  #: hits over the sum of promised p (tracked in-range pairs)
    plan_reliability: tuple[ReliabilityBin, ...]  #: the plan's promise (first step) against the truth one step later
    plan_observed_over_promised: float | None
    solve_time_median_ms: float | None
    solve_time_p99_ms: float | None
    min_realised_contour: list[float | None]  #: one per episode (None: nothing came within range)
    #: episodes with a true contact (``collisions``) in contact at no replan instant: a contact
    #: shorter than a replan period, or with a wall; in ``collisions``, not in ``pair_step_collisions``
    collisions_between_steps: int = 0

    def to_json(self) -> dict:
        """Plain JSON values (intervals as lists, non-finite numbers as ``None``)."""
        return to_jsonable(self)


def _pooled_bins(rows: Sequence[Any], prefix: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-bin pairs, hits and promised sums of ``{prefix}_pairs`` etc. summed over episode scores
    (rows written before a tally existed hold empty lists and add nothing)."""
    n_bins = len(PROMISE_EDGES) - 1
    pairs, hits, sums = np.zeros(n_bins, int), np.zeros(n_bins, int), np.zeros(n_bins)
    for r in rows:
        if getattr(r, f"{prefix}_pairs"):
            pairs += np.asarray(getattr(r, f"{prefix}_pairs"), dtype=int)
            hits += np.asarray(getattr(r, f"{prefix}_hits"), dtype=int)
            sums += np.asarray(getattr(r, f"{prefix}_sum"), dtype=float)
    return pairs, hits, sums


def summarise(results: Sequence[Any], methods: Sequence[str], c_min: float) -> dict[str, "MethodSummary"]:
    """One summary per method from per-episode results (:class:`~companion.offline.campaign.results.EpisodeResult`)."""
    bound = collision_bound(c_min)
    out = {}
    for m in methods:
        rows = [r.score for r in results if r.method == m and r.score is not None]
        errors = sum(1 for r in results if r.method == m and r.score is None)
        n = len(rows)
        k = sum(r.collided for r in rows)
        k_obs = sum(r.obstacle_collision for r in rows)
        pair_steps = sum(r.pair_steps_in_range for r in rows)
        pair_hits = sum(r.pair_step_collisions for r in rows)
        contour_pairs = sum(r.contour_pairs for r in rows)
        steps = sum(r.steps for r in rows)
        solve = np.array([t for r in rows for t in r.solve_times_s])
        d_nees = np.array([x for r in rows for x in r.drone_nees])
        r_nees = np.array([x for r in rows for x in r.relative_nees])
        model_err = np.array([x for r in rows for x in r.model_step_error_m])
        active = sum(r.active_pairs for r in rows)
        active_hits = sum(r.active_pair_collisions for r in rows)
        ttg = [r.time_to_goal_s for r in rows if r.goal_reached and r.time_to_goal_s is not None]
        replans = sum(r.replans for r in rows)
        bin_pairs, bin_hits, bin_sum = _pooled_bins(rows, "promise")
        plan_pairs, plan_hits, plan_sum = _pooled_bins(rows, "plan_promise")
        out[m] = MethodSummary(
            episodes=n,
            errors=errors,
            collisions=k,
            collision_rate=k / n if n else None,
            collision_ci95=clopper_pearson(k, n),
            obstacle_collisions=k_obs,
            pair_steps_in_range=pair_steps,
            pair_step_collisions=pair_hits,
            pair_step_frequency=pair_hits / pair_steps if pair_steps else None,
            pair_step_ci95=clopper_pearson(pair_hits, pair_steps),
            bound_phi_minus_r_min=bound,
            contact_time_s=sum(r.contact_time_s for r in rows),
            contact_time_share=(sum(r.contact_time_s for r in rows) / pair_time) if (pair_time := sum(r.pair_time_in_range_s for r in rows)) else None,
            active_pairs=active,
            active_pair_collisions=active_hits,
            active_pair_frequency=active_hits / active if active else None,
            active_pair_ci95=clopper_pearson(active_hits, active),
            predicted_collisions_bound=sum(r.predicted_collisions_bound for r in rows),
            drone_nees_mean=float(d_nees.mean()) if d_nees.size else None,
            drone_nees_share_above_chi2_95=float((d_nees > NEES_95).mean()) if d_nees.size else None,
            relative_nees_mean=float(r_nees.mean()) if r_nees.size else None,
            relative_nees_share_above_chi2_95=float((r_nees > NEES_95).mean()) if r_nees.size else None,
            drone_nees_ci95=nees_mean_ci95([r.drone_nees for r in rows]),
            relative_nees_ci95=nees_mean_ci95([r.relative_nees for r in rows]),
            model_step_error_median_m=float(np.median(model_err)) if model_err.size else None,
            model_step_error_p95_m=float(np.percentile(model_err, 95)) if model_err.size else None,
            model_step_error_max_m=float(model_err.max()) if model_err.size else None,
            contour_pairs=contour_pairs,
            share_pairs_below_c_min=sum(r.contour_pairs_below_c_min for r in rows) / contour_pairs if contour_pairs else None,
            steps=steps,
            share_steps_below_c_min=sum(r.steps_below_c_min for r in rows) / steps if steps else None,
            goal_reached=sum(r.goal_reached for r in rows),
            goal_rate=sum(r.goal_reached for r in rows) / n if n else None,
            time_to_goal_median_s=float(np.median(ttg)) if ttg else None,
            time_to_goal_mean_s=float(np.mean(ttg)) if ttg else None,
            replans=replans,
            failed_plans=sum(r.failed_plans for r in rows),
            failed_share=sum(r.failed_plans for r in rows) / replans if replans else None,
            episodes_with_failure=sum(r.failed_plans > 0 for r in rows),
            slack_plans=sum(r.slack_plans for r in rows),
            episodes_with_slack=sum(r.slack_plans > 0 for r in rows),
            slack_max=max((r.slack_max for r in rows), default=0.0),
            slack_violation_contour_max=max((r.slack_violation_contour for r in rows), default=0.0),
            slack_violation_m_max=max((r.slack_violation_m for r in rows), default=0.0),
            reliability=reliability_bins(bin_pairs, bin_hits, bin_sum),
            observed_over_promised=observed_over_promised(int(bin_hits.sum()), float(bin_sum.sum())),
            plan_reliability=reliability_bins(plan_pairs, plan_hits, plan_sum),
            plan_observed_over_promised=observed_over_promised(int(plan_hits.sum()), float(plan_sum.sum())),
            solve_time_median_ms=float(np.median(solve) * 1e3) if solve.size else None,
            solve_time_p99_ms=float(np.percentile(solve, 99) * 1e3) if solve.size else None,
            min_realised_contour=[r.min_realised_contour for r in rows],
            collisions_between_steps=sum(bool(r.collided) and not r.pair_step_collisions for r in rows),
        )
    return out
