"""Slack with c_max is accepted and flagged: the run's summary says how many replans and how deep."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from companion.core.overlap import contour_of_touch, touch_radius
from companion.offline.harness import run_lockstep
from companion.offline.slack import slack_report, violation_m


def _rec(t, status, drone, obstacle, cov=0.04, planned=0.5, slack=0.1):
    key = (101, 197)
    drone, obstacle = np.array(drone, float), np.array(obstacle, float)
    ct = float(contour_of_touch(drone, cov * np.eye(3), obstacle, cov * np.eye(3), 1.0))
    return SimpleNamespace(t_link_s=t, status=status, slack_max=slack, planned_min_contour=planned,
                           realised_contour={key: ct}, drone_position=drone, drone_cov=cov * np.eye(3),
                           obstacle_positions={key: obstacle}, obstacle_covs={key: cov * np.eye(3)})


def test_that_only_slack_replans_count_and_the_violation_is_measured_on_the_current_state():
    records = [
        _rec(0.0, "optimal", [0, 0, 0], [1.5, 0, 0], slack=0.0),     # deep inside, but no slack used: not counted
        _rec(0.3, "slack", [0, 0, 0], [1.3, 0, 0], planned=0.25),
        _rec(0.6, "slack", [0, 0, 0], [0, 1.4, 0], planned=0.28, slack=0.3),
        _rec(0.9, "slack", [0, 0, 0], [30, 0, 0], planned=0.29),     # beyond sensing range: ignored
    ]
    rep = slack_report(records, c_min=0.3, radius_sum_m=1.0, sensing_range_m=10.0)
    assert rep.slack_replans == 3 and rep.slack_max == 0.3 and rep.smallest_planned_contour == 0.25
    ct_at_03 = records[1].realised_contour[(101, 197)]
    assert 0.0 < ct_at_03 < 0.3
    assert rep.largest_violation_contour == pytest.approx(0.3 - ct_at_03) and rep.largest_violation_t_s == 0.3
    # isotropic 0.2 m sigmas along the line of centres: r_min (0.2 + 0.2) + 1.0 - 1.3
    assert rep.largest_violation_m == pytest.approx(touch_radius(0.3, 3) * 0.4 - 0.3)
    assert violation_m(np.zeros(3), 0.04 * np.eye(3), np.array([0, 1.4, 0]), 0.04 * np.eye(3), 1.0, 0.3) \
        == pytest.approx(touch_radius(0.3, 3) * 0.4 - 0.4)
    empty = slack_report(records[:1], c_min=0.3, radius_sum_m=1.0)
    assert empty.slack_replans == 0 and empty.largest_violation_contour == 0.0 and empty.largest_violation_t_s is None


def test_that_the_corridor_with_c_max_reports_its_slack_replans_without_colliding():
    # without the emergency acceleration, which keeps this run (seed 0) free of slack replans
    run = run_lockstep("configs/corridor.toml", seed=0, duration_s=12.0, accel_emergency_mps2=None)
    summary = run.summary()
    slack = summary["slack"]
    n = sum(r.status == "slack" for r in run.companion.records)
    assert n >= 1 and slack["slack_replans"] == n == summary["replans_with_slack"]
    assert 0.0 < slack["largest_violation_contour"] < 0.3 and 0.0 < slack["largest_violation_m"] < 0.5
    assert slack["smallest_planned_contour"] < 0.3  # c_min of the corridor
    assert not run.truth["collided"]
    # flagged to the GCS on every slack replan, numbered, not rate-limited
    flagged = [text for _, text in run.companion.state.events if "slack used" in text]
    assert len(flagged) == n and flagged[-1].endswith(f"#{n}") and all(len(t) <= 50 for t in flagged)
