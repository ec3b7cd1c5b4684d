"""How far slack replans went inside ``c_min``: the report behind the ``c_max`` corridor decision.

With ``c_max`` on, the upper bound deliberately flies the plan on the ``c_min``
boundary; an estimate update between two replans can then put the current state inside
the ``c_min`` contour, and the next plan needs safety slack to exist at all. That is
accepted and flagged (issue 15, option a): the companion sends a STATUSTEXT when a plan
uses slack, and this report says how many replans used slack and how deep the largest
violation went, as a contour of touch and in metres.

The violation of one (replan, obstacle) pair is measured on the estimates the replan
started from (the current state, the one the slack was needed for):

- in contour: ``c_min - c``, ``c`` the realised contour of touch (physical radii included);
- in metres: the separation missing along the minmax normal ``n`` for the inflated
  ``c_min`` ellipsoids to touch, ``r_min (s_d + s_o) + R - n.(mu_o - mu_d)``, with
  ``s_k = sqrt(n' S_k n)`` (NED metres).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any, Iterable

import numpy as np

from companion.core.overlap import minmax, touch_radius

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class SlackReport:
    """Slack replans of one run and their largest violation of ``c_min`` (see the module docstring)."""

    slack_replans: int
    slack_max: float                    #: largest slack in the QP rows (row units: metres for hyperplane and walls)
    largest_violation_contour: float    #: max of c_min - realised contour over slack replans (0: never inside)
    largest_violation_t_s: float | None  #: link time of that replan, seconds
    largest_violation_m: float          #: max missing separation over the same pairs, metres (0: never inside)
    smallest_planned_contour: float | None  #: smallest contour a slack plan itself kept (in-range obstacles)

    def to_json(self) -> dict:
        """Plain JSON values."""
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in self.__dict__.items()}


def violation_m(drone_position: np.ndarray, drone_cov: np.ndarray, obstacle_position: np.ndarray,
                obstacle_cov: np.ndarray, radius_sum_m: float, c_min: float) -> float:
    """Separation (m) missing along the minmax normal for the ``c_min`` ellipsoids to touch; <= 0: none."""
    res = minmax(drone_position, drone_cov, obstacle_position, obstacle_cov)
    spread = float(res.s1 + res.s2)
    gap = float(np.dot(res.normal, np.asarray(obstacle_position) - np.asarray(drone_position)))
    return float(touch_radius(c_min, 3)) * spread + radius_sum_m - gap


def slack_report(records: Iterable[Any], c_min: float, radius_sum_m: float, sensing_range_m: float = math.inf) -> SlackReport:
    """Summarise the slack replans among ``records`` (:class:`~companion.loop.app.ReplanRecord`).

    Parameters
    ----------
    records : replan records of one run.
    c_min : the contour the plans must keep.
    radius_sum_m : drone radius plus the obstacle radius the companion assumes, metres.
    sensing_range_m : obstacles farther than this (estimated centre distance) are ignored,
        as the planner ignores them.
    """
    n_slack = 0
    slack_max = 0.0
    worst_c, worst_m, worst_t = 0.0, 0.0, None
    planned = math.inf
    for rec in records:
        if rec.status != "slack":
            continue
        n_slack += 1
        slack_max = max(slack_max, float(rec.slack_max))
        if math.isfinite(rec.planned_min_contour):
            planned = min(planned, float(rec.planned_min_contour))
        for key, ct in rec.realised_contour.items():
            mu_o = rec.obstacle_positions[key]
            if np.linalg.norm(mu_o - rec.drone_position) > sensing_range_m or ct >= c_min:
                continue
            if c_min - float(ct) > worst_c:
                worst_c, worst_t = c_min - float(ct), float(rec.t_link_s)
            worst_m = max(worst_m, violation_m(rec.drone_position, rec.drone_cov, mu_o, rec.obstacle_covs[key],
                                               radius_sum_m, c_min))
    return SlackReport(n_slack, slack_max, worst_c, worst_t, worst_m, None if not math.isfinite(planned) else planned)


def companion_slack_report(companion: Any) -> SlackReport:
    """:func:`slack_report` of a :class:`~companion.loop.app.Companion` after a run, with its own settings."""
    cfg = companion.planner_config
    return slack_report(companion.records, cfg.c_min, cfg.drone_radius_m + companion.settings.obstacle_radius_m,
                        cfg.sensing_range_m)
