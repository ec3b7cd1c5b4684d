"""The tracking margin (safety rows only) and the initial velocity anchored on the estimate."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.core.planner import Planner
from companion.errors import ConfigError, InputError
from companion.loop.app import Companion
from companion.loop.config import load_scenario
from tests.core.test_planner_scp import exact_contour, scenario_one
from tests.loop.test_request_gating import SCENARIO, HeldPlanner
from tests.support.inbound import px4_offboard_heartbeat, received

MARGIN = 0.04 * np.eye(3)


def test_that_the_margin_widens_the_safety_rows_only():
    cfg, req = scenario_one()
    widened = dataclasses.replace(req, margin_cov=MARGIN)
    np.testing.assert_array_equal(widened.safety_covs, req.drone_covs + MARGIN)
    np.testing.assert_array_equal(widened.drone_covs, req.drone_covs)
    plain, kept_apart = Planner(cfg).solve(req), Planner(cfg).solve(widened)
    assert plain.status == kept_apart.status == "optimal"
    # judged on the drone's own covariance, the widened plan keeps its contours further apart
    assert exact_contour(req, plain, cfg.drone_radius_m).min() == pytest.approx(cfg.c_min, abs=0.01)
    assert exact_contour(req, kept_apart, cfg.drone_radius_m).min() > cfg.c_min + 0.05
    # and its own promise is made on the widened covariances
    assert kept_apart.contour_of_touch.min() >= cfg.c_min - 1e-3


def test_that_the_margin_leaves_the_goal_cost_alone():
    cfg, req = scenario_one()
    free = dataclasses.replace(req, obstacle_means=np.zeros((0, 20, 3)), obstacle_covs=np.zeros((0, 20, 3, 3)),
                               obstacle_radii=np.zeros(0), upper_bound_mask=None)
    a = Planner(cfg).solve(free)
    b = Planner(cfg).solve(dataclasses.replace(free, margin_cov=MARGIN))
    np.testing.assert_allclose(a.positions, b.positions, atol=1e-9)


@pytest.mark.parametrize("margin, word", [(np.diag([0.04, -0.01, 0.04]), "positive definite"),
                                          (np.array([[0.04, 0.01, 0], [0, 0.04, 0], [0, 0, 0.04]]), "symmetric"),
                                          (np.zeros((2, 2)), "shape")])
def test_that_a_bad_margin_is_refused_by_name(margin, word):
    _, req = scenario_one()
    with pytest.raises(InputError, match=f"margin_cov.*{word}"):
        dataclasses.replace(req, margin_cov=margin)


def _companion(planner: dict | None = None, **loop) -> tuple[Companion, HeldPlanner]:
    """The short hop's companion with ``[companion]`` settings ``loop`` (and ``[planner]`` ones ``planner``)."""
    scenario = load_scenario(SCENARIO)
    scenario = dataclasses.replace(scenario, companion=dataclasses.replace(scenario.companion, **loop),
                                   planner=dataclasses.replace(scenario.planner, **(planner or {})))
    service = HeldPlanner(Planner(scenario.planner))
    return Companion(scenario, planning=service), service


def _fly(companion: Companion, service: HeldPlanner, seconds: float = 2.0, drift: np.ndarray | None = None,
         streamed: list | None = None, asked: Callable | None = None) -> list:
    """Poses flying north at 1 m/s (LOCAL_POSITION_NED) at 20 Hz; every job is answered at the next tick.

    ``drift`` (m/s NED) moves the reported position against the reported velocity; ``streamed``
    collects, per tick, the setpoint's velocity with the executor's command and the loop's drift then;
    ``asked(job)`` is called in the tick that asked for a job, before anything else changes.
    """
    jobs, t = [], 0.0
    extra = np.zeros(3) if drift is None else np.asarray(drift, dtype=float)
    while t < seconds:
        p = np.array([t, 0.0, -5.0]) + extra * t
        for msg in (px4_offboard_heartbeat(),
                    mavlink2.MAVLink_local_position_ned_message(int(t * 1000), *p, 1.0, 0.0, 0.0)):
            companion.handle(received(msg, t_s=t))
        for msg in companion.tick(t):
            if streamed is not None and msg.get_type() == "SET_POSITION_TARGET_LOCAL_NED":
                streamed.append((np.array([msg.vx, msg.vy, msg.vz]), companion.executor.command.copy(),
                                 companion.perception.drift_mps()))
        if service.waiting:
            if service.waiting[0] not in jobs:
                jobs.append(service.waiting[0])
                if asked is not None:
                    asked(service.waiting[0])
            elif t - service.waiting[0].t_link_s >= 0.05 - 1e-9:
                service.answer(solve=True)
        t = round(t + 0.05, 2)
    return jobs


def test_that_the_request_carries_the_margin_and_the_realised_contour_is_judged_without_it():
    companion, service = _companion(tracking_margin_m2=0.04)
    jobs = _fly(companion, service, 1.0)
    assert jobs
    for job in jobs:
        np.testing.assert_array_equal(job.request.margin_cov, MARGIN)
        np.testing.assert_allclose(job.request.safety_covs, job.request.drone_covs + MARGIN)
        np.testing.assert_array_equal(job.drone_cov, job.request.drone_covs[0])   # the estimate's, no margin
    plain, service = _companion()
    assert not np.any(_fly(plain, service, 1.0)[0].request.margin_cov)


def test_that_the_initial_velocity_follows_the_plan_chain_or_the_estimate_as_configured():
    chained, service = _companion()
    v_plan = [j.request.velocity for j in _fly(chained, service)]
    anchored, service = _companion(initial_velocity="estimate")
    jobs = _fly(anchored, service)
    lead = [j.t_vehicle_s - anchored.vehicle_time(j.t_link_s) for j in jobs]
    # the estimate (1 m/s north, filtered) moved by what the plan in force does over the lead
    estimate_now = [j.drone_velocity for j in jobs]
    assert any(abs(a[0] - b[0]) > 0.05 for a, b in zip(v_plan[1:], estimate_now[1:]))   # the chain strays from it
    for job, est, dt in zip(jobs, estimate_now, lead):
        if dt == 0.0:
            np.testing.assert_allclose(job.request.velocity, est, atol=1e-12)
    assert max(np.linalg.norm(j.request.velocity - e) for j, e in zip(jobs, estimate_now)) < 0.5


def test_that_the_loop_settings_are_checked_by_name():
    scenario = load_scenario(SCENARIO)
    with pytest.raises(ConfigError, match="initial_velocity"):
        dataclasses.replace(scenario.companion, initial_velocity="measured")
    with pytest.raises(ConfigError, match="tracking_margin_m2"):
        dataclasses.replace(scenario.companion, tracking_margin_m2=-0.1)


def test_that_the_tracking_error_sums_residuals_in_fixed_memory():
    from companion.loop.records import TrackingError

    te = TrackingError()
    assert te.summary() is None
    for r in ([0.3, 0.0, -0.4], [0.0, 0.1, 0.0], [-0.3, -0.1, 0.0]):
        te.add(np.array(r))
    s = te.summary()
    assert s["samples"] == 3 and s["largest_m"] == pytest.approx(0.5)
    np.testing.assert_allclose(s["rms_ned_m"], [np.sqrt(0.18 / 3), np.sqrt(0.02 / 3), np.sqrt(0.16 / 3)])


def _short_hop(sim_lag_s: float) -> dict:
    import tomllib

    with open(SCENARIO, "rb") as f:
        tables = tomllib.load(f)
    tables.setdefault("sim", {})["velocity_time_constant_s"] = sim_lag_s
    return tables


def test_that_the_report_says_how_far_the_vehicle_strays_from_its_plans_and_more_when_the_model_is_wrong():
    from companion.offline.harness import run_lockstep
    from companion.offline.report import companion_report, format_report

    matched = companion_report(run_lockstep(_short_hop(0.3), seed=0).companion)["tracking_error"]
    slower = companion_report(run_lockstep(_short_hop(1.2), seed=0).companion)
    assert matched["samples"] >= 5 and slower["tracking_error"]["samples"] >= 5
    # the planner's 0.3 s lag is the vehicle's: what is left is estimate noise
    assert max(matched["rms_ned_m"]) < 0.1
    # a vehicle four times slower than the planner thinks strays further from every plan
    assert slower["tracking_error"]["rms_ned_m"][0] > 2.0 * matched["rms_ned_m"][0]
    assert "strayed from the plan in force" in format_report(slower)
