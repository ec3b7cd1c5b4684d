"""The goal's hand-back (``fly --exit-after-goal``) in lockstep: the loop reports when the vehicle
is settled at its goal, and the sequencer hands back only then (docs/CONFIGURATION.md,
``[offboard] hold_after_goal_s`` and ``goal_settle_max_s``)."""

from __future__ import annotations

import numpy as np

from companion.loop.plan_cycle import GOAL_SETTLE_LOOKAHEAD_S
from companion.mavlink.offboard import OffboardConfig, Phase
from companion.offline.harness import run_lockstep

SCENARIO = "configs/antipodal.toml"


def _hand_back(offboard: OffboardConfig) -> dict:
    """Where the companion's estimate was at the tick it asked for Hold, and when the goal was reached."""
    seen: dict = {}

    def after_tick(companion, t_s, outbox):
        if "t_s" not in seen and companion.sequencer.phase is Phase.HANDING_BACK:
            state = companion.perception.drone.state
            goal = companion.builder.goal.goal
            seen.update(t_s=t_s, goal_t_s=companion.state.goal_reached_t_s,
                        distance_m=float(np.linalg.norm(state.position - goal)),
                        ahead_m=float(np.linalg.norm(state.position + GOAL_SETTLE_LOOKAHEAD_S * state.velocity - goal)),
                        tolerance_m=companion.scenario.mission.goal_tolerance_m)

    run_lockstep(SCENARIO, offboard=offboard, stop_after_goal_s=20.0, after_tick=after_tick)
    assert "t_s" in seen, "never handed back"
    return seen


def test_that_the_vehicle_is_handed_back_settled_inside_the_goals_tolerance():
    at = _hand_back(OffboardConfig(hold_after_goal_s=0.0))
    assert at["distance_m"] <= at["tolerance_m"]
    assert at["ahead_m"] <= at["tolerance_m"] + 0.05         # judged at the last replan, up to 0.3 s before
    assert at["t_s"] > at["goal_t_s"] + 0.3                  # it came in moving: reached is not settled


def test_that_without_the_wait_it_is_handed_back_at_the_goal_moving():
    at = _hand_back(OffboardConfig(hold_after_goal_s=0.0, goal_settle_max_s=0.0))
    assert at["t_s"] - at["goal_t_s"] <= 0.1                 # the tick after the goal was reached
    assert at["ahead_m"] > at["tolerance_m"]                  # and on its way out of the tolerance
