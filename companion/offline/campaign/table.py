"""The campaign's terminal table: one row per method, then the near-pair and filter view."""

from __future__ import annotations

import logging
from typing import Any

from companion.core.overlap import touch_radius
from companion.offline.campaign.results import CampaignResult
from companion.offline.campaign.score import ACTIVE_CONTOUR
from companion.offline.campaign.stats import collision_bound

logger = logging.getLogger(__name__)


def _fmt(x: Any, spec: str) -> str:
    if x is None:
        width = "".join(ch for ch in spec.split(".")[0] if ch.isdigit())
        return format("-", f">{width}") if width else "-"
    return format(x, spec)


def format_table(result: CampaignResult) -> str:
    """The terminal table: one row per method."""
    bound = collision_bound(result.c_min)
    head = (f"{'method':<14}{'eps':>5}{'hit eps':>8}  {'rate [95% CI]':<22}{'step hits':>9}  {'step freq [95% CI]':<28}"
            f"{'<c_min':>8}{'goal':>7}{'t_goal':>8}{'failed':>8}{'slack':>7}{'solve med/p99 ms':>18}")
    lines = [f"campaign {result.family}, seed {result.seed}, {len(result.episodes)} episodes, c_min = {result.c_min:.2f}: "
             f"bound Phi(-r_min) = {bound:.4g} per step and obstacle (r_min = {float(touch_radius(result.c_min, 3)):.4f})",
             head, "-" * len(head)]
    for m, s in result.summary.items():
        lo, hi = s.collision_ci95
        plo, phi = s.pair_step_ci95
        rate = f"{_fmt(s.collision_rate, '.3f')} [{lo:.3f}, {hi:.3f}]"
        step = f"{_fmt(s.pair_step_frequency, '.2e')} [{plo:.1e}, {phi:.1e}]"
        lines.append(
            f"{m:<14}{s.episodes:>5}{s.collisions:>8}  {rate:<22}{s.pair_step_collisions:>9}  {step:<28}"
            f"{_fmt(s.share_pairs_below_c_min, '8.4f')}{_fmt(s.goal_rate, '7.3f')}{_fmt(s.time_to_goal_median_s, '8.1f')}"
            f"{_fmt(s.failed_share, '8.4f')}{s.episodes_with_slack:>7}"
            f"{_fmt(s.solve_time_median_ms, '9.1f')}/{_fmt(s.solve_time_p99_ms, '<8.1f')}"
        )
    lines.append("")
    lines.append(f"{'method':<14}{'near pairs':>11}{'hits':>6}  {'near freq [95% CI]':<28}{'E[coll] bound':>14}{'observed':>9}{'contact share':>14}"
                 f"{'NEES drone':>11}{'>95%':>7}{'NEES rel':>10}{'>95%':>7}{'step err med/p95 m':>20}")
    for m, s in result.summary.items():
        alo, ahi = s.active_pair_ci95
        near = f"{_fmt(s.active_pair_frequency, '.2e')} [{alo:.1e}, {ahi:.1e}]"
        lines.append(
            f"{m:<14}{s.active_pairs:>11}{s.active_pair_collisions:>6}  {near:<28}{s.predicted_collisions_bound:>14.2f}"
            f"{s.pair_step_collisions:>9}{_fmt(s.contact_time_share, '14.2e')}{_fmt(s.drone_nees_mean, '11.2f')}{_fmt(s.drone_nees_share_above_chi2_95, '7.3f')}"
            f"{_fmt(s.relative_nees_mean, '10.2f')}{_fmt(s.relative_nees_share_above_chi2_95, '7.3f')}"
            f"{_fmt(s.model_step_error_median_m, '12.3f')}/{_fmt(s.model_step_error_p95_m, '<7.3f')}"
        )
    lines.append(f"(near: (step, obstacle) pairs with realised contour < {ACTIVE_CONTOUR}; E[coll] bound: sum over pairs of "
                 f"Phi(-r(realised contour)); contact share: seconds in true contact per in-range obstacle-second; NEES: 3 and 5 % above the chi2_3 95 % quantile if the filters are consistent; "
                 f"step err: true displacement over one step minus tau * V_1)")
    lines.append(f"(hit eps: episodes with a true contact at any physics step, with an obstacle or a wall; rate: their share; "
                 f"step hits: in-range (step, obstacle) pairs in true contact at the replan instant; step freq: step hits per "
                 f"in-range (step, obstacle) pair, the quantity the bound Phi(-r_min) is about; <c_min: share of in-range (step, obstacle) "
                 f"pairs whose realised contour of touch fell below c_min; failed: share of replans; slack: episodes "
                 f"with slack; {result.wall_time_s:.0f} s on {result.workers} worker(s))")
    for m, s in result.summary.items():
        for what, bins, ratio in (("plan's promise (first step)", s.plan_reliability, s.plan_observed_over_promised),
                                  ("estimates' promise", s.reliability, s.observed_over_promised)):
            used = [b for b in bins if b.pairs]
            over = [f"[{b.lo:.0e}, {b.hi:.0e}): {b.hits}/{b.pairs} [{b.observed_ci95[0]:.1e}, {b.observed_ci95[1]:.1e}] "
                    f"against {b.promised_mean:.1e}" for b in used if b.exceeds_promise]
            lines.append(f"{m}: {what} against truth over {sum(b.pairs for b in used)} pairs, {sum(b.hits for b in used)} hit(s): "
                         f"observed/promised = {_fmt(ratio, '.3g')}; bins above their promise: {'; '.join(over) or 'none'}")
    for m, s in result.summary.items():
        if s.collisions:
            lines.append(f"{m}: {s.collisions} episode(s) with a true contact ({s.obstacle_collisions} with an obstacle), "
                         f"{s.collisions_between_steps} of them in contact at no replan instant (a contact between two "
                         f"replans, or with a wall): in hit eps, not in step hits")
    for m, s in result.summary.items():
        if s.slack_plans:
            lines.append(f"{m}: {s.slack_plans} slack replan(s) in {s.episodes_with_slack} episode(s), accepted and flagged; "
                         f"deepest inside c_min: {s.slack_violation_contour_max:.3f} in contour, "
                         f"{s.slack_violation_m_max:.3f} m of separation")
    errors = sum(s.errors for s in result.summary.values())
    if errors:
        lines.append(f"{errors} run(s) ended with an error (see the JSON file)")
    if result.lost:
        lines.append(f"{result.lost} run(s) lost with their worker: not counted above; --resume runs them again")
    return "\n".join(lines)
