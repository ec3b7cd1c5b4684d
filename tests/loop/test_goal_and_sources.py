"""The goal source and the obstacle sources the request builder plugs in (companion/loop/goal.py, obstacle_sources.py)."""

import numpy as np

from companion.loop.app import Companion
from companion.loop.config import MissionConfig, load_scenario
from companion.loop.goal import ScenarioGoal, leads_the_way
from companion.loop.obstacle_sources import ObstacleHorizon, StaticObstacles
from companion.loop.request_builder import RequestBuilder
from companion.loop.perception import Perception

SCENARIO = "configs/antipodal.toml"


def test_that_the_scenario_goal_leads_along_the_straight_route_and_is_reached_within_its_tolerance():
    goal = ScenarioGoal(MissionConfig(goal_ned_m=np.array([24.0, 0.0, -5.0]), goal_tolerance_m=0.5, waypoint_spacing_m=6.0))
    goal.start(np.array([0.0, 0.0, -5.0]))
    goal.start(np.array([5.0, 5.0, -5.0]))  # later calls do not move the route
    assert np.allclose(goal.target(np.array([2.0, 3.0, -5.0])), [8.0, 0.0, -5.0])   # projection 2 + spacing 6
    assert np.allclose(goal.target(np.array([20.0, 0.0, -5.0])), [24.0, 0.0, -5.0])  # capped at the goal
    assert goal.reached(np.array([23.6, 0.0, -5.0])) and not goal.reached(np.array([23.4, 0.0, -5.0]))


def test_that_only_an_obstacle_between_the_drone_and_the_goal_leads_the_way():
    here, goal = np.zeros(3), np.array([10.0, 0.0, 0.0])
    assert leads_the_way(goal, here, np.array([5.0, 1.0, 0.0]))
    assert not leads_the_way(goal, here, np.array([-1.0, 0.0, 0.0]))   # behind
    assert not leads_the_way(goal, here, np.array([11.0, 0.0, 0.0]))   # past the goal
    assert not leads_the_way(None, here, np.array([5.0, 0.0, 0.0]))    # no goal
    # only an obstacle in the way leads: within block_m of the line to the goal
    assert leads_the_way(goal, here, np.array([5.0, 1.0, 0.0]), block_m=1.3)
    assert not leads_the_way(goal, here, np.array([5.0, 1.5, 0.0]), block_m=1.3)   # beside the way


def test_that_a_leader_just_past_the_goal_does_not_lead_when_the_last_bit_to_the_goal_is_vertical():
    # issue 46: the corridor's drone 0.37 m under its goal, the leader 1.7 m on; its projection on
    # the (vertical) line to the goal fell between, and the drone was told to follow it downwards
    here, goal, leader = np.array([23.99, -0.02, -4.63]), np.array([24.0, 0.0, -5.0]), np.array([25.66, 0.0, -4.88])
    assert leads_the_way(goal, here, leader)                      # the projection alone
    assert not leads_the_way(goal, here, leader, block_m=1.3)     # it is not in the way


class _Shared:
    """A source that knows one obstacle's path: 1 m/s east from (0.5, 3, -5), as another drone's shared plan would."""

    def horizon(self, times_s):
        t = np.asarray(times_s) - times_s[0]
        means = np.array([0.5, 3.0, -5.0]) + np.outer(t, [0.0, 1.0, 0.0])
        return ObstacleHorizon(means[None], np.broadcast_to(0.02 * np.eye(3), (1, len(t), 3, 3)).copy(),
                               np.array([0.4]), np.array([True]))


def test_that_the_request_takes_its_target_from_the_goal_source_and_each_sources_obstacles_after_the_tracks():
    scenario = load_scenario(SCENARIO)
    n = scenario.planner.horizon_steps
    perception = Perception(scenario)
    perception.drone.update(0.0, np.array([0.0, 0.0, -5.0]), np.zeros(3), np.full(3, 0.01), np.full(3, 0.01))
    perception.tracker.update((20, 197, "obstacles1"), 0.0, np.array([6.0, 0.0, -5.0]), np.zeros(3),
                              0.01 * np.eye(3), 0.01 * np.eye(3))
    goal = ScenarioGoal(MissionConfig(goal_ned_m=np.array([0.0, 12.0, -5.0]), goal_tolerance_m=0.3, waypoint_spacing_m=4.0))
    goal.start(np.array([0.0, 0.0, -5.0]))
    job = RequestBuilder(scenario, goal=goal, sources=(_Shared(),)).build(
        seq=0, t_s=0.0, t_v=0.0, perception=perception, initial_velocity=np.zeros(3), warm_start=None)
    req = job.request
    assert np.allclose(req.target, [0.0, 4.0, -5.0])                      # the goal source's waypoint, not [mission]'s
    assert req.obstacle_means.shape == (2, n, 3)                         # the track, then the shared plan
    assert np.allclose(req.obstacle_means[1, :, 1], 3.0 + scenario.planner.step_s * np.arange(n))
    assert req.obstacle_radii.tolist() == [scenario.companion.obstacle_radius_m, 0.4]
    assert req.upper_bound_mask.tolist() == [False, True]                # the shared plan is between the drone and the goal
    default = RequestBuilder(scenario).build(seq=0, t_s=0.0, t_v=0.0, perception=perception,
                                             initial_velocity=np.zeros(3), warm_start=None)
    assert default.request.num_obstacles == 1 + len(scenario.static_obstacles)


class _SharedAt(_Shared):
    """The same shared plan, standing still at ``where``."""

    def __init__(self, where):
        self.where = np.asarray(where, dtype=float)

    def horizon(self, times_s):
        h = super().horizon(times_s)
        return ObstacleHorizon(np.broadcast_to(self.where, h.means.shape).copy(), h.covs, h.radii, h.may_lead)


def test_that_only_an_obstacle_in_the_way_is_marked_to_be_followed():
    # issue 46: an obstacle whose projection falls between the drone and its goal but which stands
    # off the way (farther than both bodies and both c_min reaches) is not followed under c_max
    scenario = load_scenario(SCENARIO)
    perception = Perception(scenario)
    perception.drone.update(0.0, np.array([0.0, 0.0, -5.0]), np.zeros(3), np.full(3, 0.01), np.full(3, 0.01))
    goal = ScenarioGoal(MissionConfig(goal_ned_m=np.array([0.0, 12.0, -5.0]), goal_tolerance_m=0.3, waypoint_spacing_m=4.0))
    goal.start(np.array([0.0, 0.0, -5.0]))
    sources = (_SharedAt([0.8, 6.0, -5.0]), _SharedAt([3.0, 6.0, -5.0]), _SharedAt([0.0, 6.0, -7.5]))
    job = RequestBuilder(scenario, goal=goal, sources=sources).build(
        seq=0, t_s=0.0, t_v=0.0, perception=perception, initial_velocity=np.zeros(3), warm_start=None)
    assert job.request.upper_bound_mask.tolist() == [True, False, False]   # in the way; 3 m beside it; 2.5 m above it


class _Goal(ScenarioGoal):
    pass


def test_that_a_companion_plans_for_its_injected_goal_and_every_source_after_the_tracks():
    scenario = load_scenario(SCENARIO)
    mission = MissionConfig(goal_ned_m=np.array([0.0, 12.0, -5.0]), goal_tolerance_m=0.3)
    companion = Companion(scenario, goal=_Goal(mission), obstacle_sources=(_Shared(), StaticObstacles(())))
    assert companion.goal.goal.tolist() == [0.0, 12.0, -5.0]
    builder: RequestBuilder = companion.builder
    h = builder.sources[0].horizon(np.arange(1, scenario.planner.horizon_steps + 1) * scenario.planner.step_s)
    assert h.means.shape == (1, scenario.planner.horizon_steps, 3)
    assert StaticObstacles(()).horizon(np.arange(3.0)).means.shape == (0, 3, 3)
