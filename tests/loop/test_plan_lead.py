"""Real-time plans start where the drone will be when they take over; lockstep plans where it is.

The goal is judged on the estimate now in both."""

from __future__ import annotations

import numpy as np

from companion.core.planner import Planner
from companion.loop.app import Companion
from companion.loop.config import load_scenario
from companion.offline.harness import run_lockstep
from tests.loop.test_request_gating import SCENARIO, HeldPlanner, _feed


def test_that_each_plan_starts_the_recent_arrival_delay_after_its_request_from_where_the_plan_in_force_goes():
    scenario = load_scenario(SCENARIO)
    service = HeldPlanner(Planner(scenario.planner))
    companion = Companion(scenario, planning=service)
    judged = []                      # the positions the goal is judged on
    reached = companion.builder.goal.reached
    companion.builder.goal.reached = lambda position: judged.append(np.array(position)) or reached(position)
    t, jobs = 0.0, []
    while len(jobs) < 6 and t < 20.0:
        _feed(companion, t)
        if service.waiting and service.waiting[0] not in jobs:
            jobs.append(service.waiting[0])
        job = service.waiting[0] if service.waiting else None
        if job is not None and t - job.t_link_s >= 0.05 - 1e-9:  # solved by the next tick, taken at the one after
            service.answer(solve=True)
        t = round(t + 0.05, 2)
    assert len(jobs) == 6
    t_v = [companion.vehicle_time(j.t_link_s) for j in jobs]
    assert abs(jobs[0].t_vehicle_s - t_v[0]) < 1e-9  # nothing has arrived yet: no lead
    assert jobs[0].position.tolist() == [0.0, 0.0, -5.0]  # the estimate (the test's drone never moves)
    for job, tv in zip(jobs[1:], t_v[1:]):
        assert abs(job.t_vehicle_s - (tv + 0.1)) < 1e-9  # two ticks: the delay the plans took
        # from where the plan in force takes the drone in those 0.1 s, not from the estimate
        assert 0.0 < np.linalg.norm(job.position - [0.0, 0.0, -5.0]) < 0.1 * 3.0
        assert np.array_equal(job.request.position, job.position)
        assert job.position_now.tolist() == [0.0, 0.0, -5.0]   # the estimate, without the lead
    assert abs(companion.plan_lead_s() - 0.1) < 1e-9
    # the goal is judged on the estimate now, never on where the next plan starts (on the way
    # in, a lead closer to the goal than the drone)
    assert len(judged) >= 6 and all(p.tolist() == [0.0, 0.0, -5.0] for p in judged)


def test_that_the_lead_is_capped_a_setpoint_short_of_the_replan_period():
    scenario = load_scenario(SCENARIO)
    companion = Companion(scenario, planning=HeldPlanner(Planner(scenario.planner)))
    companion.cycle._arrival_delays.extend([0.05, 2.0])
    cap = min(scenario.companion.plan_lead_max_s, scenario.planner.replan_period_s - 1.0 / scenario.companion.setpoint_rate_hz)
    assert companion.plan_lead_s() == cap > 0.0


def test_that_lockstep_plans_start_at_their_request():
    result = run_lockstep(SCENARIO, seed=0)
    records = result.companion.records
    assert records and all(abs(r.t_vehicle_s - r.t_link_s) < 1e-9 for r in records)  # lockstep: one clock
    assert result.companion.plan_lead_s() == 0.0
