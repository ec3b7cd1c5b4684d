"""Peers along their announced plans, or giving way (companion/loop/peer_intents.py, fleet_config.py)."""

import numpy as np
import pytest

from companion.core.intent import Intent
from companion.errors import ConfigError
from companion.loop.config import MissionConfig, load_scenario
from companion.loop.fleet_config import FleetConfig
from companion.loop.goal import ScenarioGoal
from companion.loop.peer_intents import PeerIntents
from companion.loop.perception import Perception
from companion.loop.request_builder import RequestBuilder

SCENARIO = "configs/antipodal.toml"
PEER = (2, 191, "fleet")        # system 2: outranks system 3, gives way to system 1
TIMES = np.array([10.3, 10.6, 13.0])


def _turning(t0=10.0):
    """A peer heading north at 1 m/s that turns east: where constant velocity would put it is wrong."""
    p = np.array([[0.0, 0.0, -5.0], [1.5, 0.0, -5.0], [2.5, 1.0, -5.0]])
    v = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    return Intent(t0_s=t0, spacing_s=1.5, positions=p, velocities=v)


def test_that_each_coordination_mode_uses_intents_as_documented():
    cov = 0.01 * np.eye(3)
    for mode, own, along, gives_way in [("decentralised", 3, False, False), ("distributed", 3, True, False),
                                       ("distributed", 1, True, False), ("prioritised", 3, True, False),
                                       ("prioritised", 1, False, True)]:
        peers = PeerIntents(FleetConfig(coordination=mode), own_system=own)
        peers.update(PEER, _turning())
        got = peers.predict(PEER, TIMES, cov, t_v=10.2)
        assert (got is not None) is along, (mode, own)
        assert peers.gives_way(PEER, 10.2) is gives_way, (mode, own)
        if along:
            means, covs = got
            assert np.allclose(means[-1], [2.5, 1.0, -5.0])
            assert np.allclose(covs[-1], cov + 0.02 * 3.0 * np.eye(3))   # 3 s after the intent was made


def test_that_a_stale_intent_falls_back_to_constant_velocity_and_a_peer_without_one_never_gives_way():
    peers = PeerIntents(FleetConfig(coordination="prioritised", intent_stale_s=1.0), own_system=1)
    peers.update(PEER, _turning(t0=10.0))
    assert peers.gives_way(PEER, 11.0) and not peers.gives_way(PEER, 11.01)
    high = PeerIntents(FleetConfig(coordination="prioritised", intent_stale_s=1.0), own_system=3)
    high.update(PEER, _turning(t0=10.0))
    assert high.predict(PEER, TIMES, np.eye(3), t_v=11.5) is None and high.counts["stale"] == 1
    assert not peers.gives_way((4, 191, "fleet"), 10.5)            # never announced an intent
    assert not peers.gives_way(("icao", 0xABC), 10.5)              # not a MAVLink system


def test_that_the_store_is_bounded_ignores_old_and_own_intents_and_counts_them():
    peers = PeerIntents(FleetConfig(max_peers=2), own_system=1)
    peers.update((1, 191, "fleet"), _turning())                    # our own, echoed back
    for system, t0 in [(2, 10.0), (3, 11.0), (4, 12.0)]:
        peers.update((system, 191, "fleet"), _turning(t0))
    assert sorted(k[0] for k in peers.keys()) == [3, 4]            # 2 heard from longest ago
    peers.update((3, 191, "fleet"), _turning(5.0))                 # older than the one kept
    assert peers.fresh((3, 191, "fleet"), 11.5).t0_s == 11.0
    peers.update((4, 191, "fleet"), None)
    assert peers.keys() == [(3, 191, "fleet")]
    assert peers.summary() == {"peers_with_intent": 1, "intents_evicted": 1, "intents_out_of_order": 1,
                               "intents_own": 1, "intents_received": 3, "intents_withdrawn": 1}


@pytest.mark.parametrize("raw, key", [
    (dict(coordination="central"), "coordination"), (dict(intent_knot_spacing_s=0.0), "intent_knot_spacing_s"),
    (dict(intent_growth_m2ps=-1.0), "intent_growth_m2ps"), (dict(intent_stale_s=0), "intent_stale_s"),
    (dict(max_peers=0), "max_peers"),
])
def test_that_a_bad_fleet_setting_names_its_key(raw, key):
    with pytest.raises(ConfigError, match=key):
        FleetConfig(**raw)


def _perception(scenario):
    perception = Perception(scenario)
    perception.drone.update(10.0, np.array([0.0, -3.0, -5.0]), np.zeros(3), np.full(3, 0.01), np.full(3, 0.01))
    # the peer's state announcement: heading north at 1 m/s from the origin
    perception.tracker.update(PEER, 10.0, np.array([0.0, 0.0, -5.0]), np.array([1.0, 0.0, 0.0]),
                              0.01 * np.eye(3), 0.01 * np.eye(3))
    perception.tracker.update((9, 1, "obstacles1"), 10.0, np.array([8.0, 0.0, -5.0]), np.zeros(3),
                              0.01 * np.eye(3), 0.01 * np.eye(3))
    return perception


def _job(scenario, peers, plan_in_force=None):
    goal = ScenarioGoal(MissionConfig(goal_ned_m=np.array([0.0, 12.0, -5.0]), goal_tolerance_m=0.3, waypoint_spacing_m=4.0))
    goal.start(np.array([0.0, -3.0, -5.0]))
    return RequestBuilder(scenario, goal=goal, sources=(), peers=peers).build(
        seq=0, t_s=10.0, t_v=10.0, perception=_perception(scenario), initial_velocity=np.zeros(3), warm_start=None,
        plan_in_force=plan_in_force)


def test_that_the_request_predicts_a_peer_along_its_intent_and_leaves_out_one_that_gives_way():
    scenario = load_scenario(SCENARIO)
    n, tau = scenario.planner.horizon_steps, scenario.planner.step_s
    cv = _job(scenario, None)
    assert cv.tracks_constrained == (PEER, (9, 1, "obstacles1")) and cv.tracks_along_intent == ()
    assert np.allclose(cv.request.obstacle_means[0, -1, :2], [n * tau, 0.0])   # constant velocity: north

    peers = PeerIntents(FleetConfig(coordination="distributed"), own_system=3)
    peers.update(PEER, _turning(t0=10.0))
    along = _job(scenario, peers)
    assert along.tracks_along_intent == (PEER,)
    t_end = 10.0 + n * tau
    assert np.allclose(along.request.obstacle_means[0, -1], [2.5 + 0.0, 1.0 + (t_end - 13.0), -5.0])
    grow = along.request.obstacle_covs[0, -1] - cv.request.obstacle_covs[0, 0]
    assert np.all(np.diag(along.request.obstacle_covs[0, -1]) > np.diag(cv.request.obstacle_covs[0, 0]))
    assert np.allclose(along.request.obstacle_means[1], cv.request.obstacle_means[1])   # the other track as before
    assert grow.shape == (3, 3)

    yielding = PeerIntents(FleetConfig(coordination="prioritised"), own_system=1)
    yielding.update(PEER, _turning(t0=10.0))
    job = _job(scenario, yielding)
    assert job.tracks_giving_way == (PEER,) and job.tracks_constrained == ((9, 1, "obstacles1"),)
    assert job.request.num_obstacles == 1
    assert PEER in job.realised_contour                               # still judged, though not planned around


def test_that_a_lower_priority_peer_whose_plan_comes_inside_ours_is_planned_around():
    """Prioritised: a peer gives way by planning around this drone's announced plan. When its own
    announced plan comes inside this drone's plan in force (it could not give way: a plan with
    slack), it is planned around like any other peer, and counted."""
    from companion.core.intent import intent_means

    scenario = load_scenario(SCENARIO)
    peers = PeerIntents(FleetConfig(coordination="prioritised"), own_system=1)
    intent = _turning(t0=10.0)
    peers.update(PEER, intent)
    hovering = lambda t: np.broadcast_to([0.0, -3.0, -5.0], (len(t), 3))   # noqa: E731  3 m and more from the peer's plan
    job = _job(scenario, peers, plan_in_force=hovering)
    assert job.tracks_giving_way == (PEER,) and peers.counts["not_giving_way"] == 0
    # this drone's plan 0.8 m beside the peer's, all the way: bodies (0.5 m each) nearly touch
    beside = lambda t: intent_means(intent, t) + np.array([0.0, -0.8, 0.0])   # noqa: E731
    job = _job(scenario, peers, plan_in_force=beside)
    assert job.tracks_giving_way == () and PEER in job.tracks_constrained
    assert job.tracks_along_intent == ()        # a lower-priority peer: its intent is not a fixed plan to us
    assert peers.counts["not_giving_way"] == 1
    # no plan in force yet (the first plan): the peer gives way as announced
    job = _job(scenario, peers, plan_in_force=lambda t: None)
    assert job.tracks_giving_way == (PEER,)


def test_that_a_peer_along_its_intent_carries_the_tracking_margin_as_this_drone_does():
    """Both vehicles stray from their plans in force between replans: the peer's announced plan
    carries ``tracking_margin_m2`` too, in the safety rows only (the realised contour is judged
    on the estimates alone), and an obstacle that is not a peer does not."""
    import dataclasses

    base = load_scenario(SCENARIO)
    scenario = dataclasses.replace(base, companion=dataclasses.replace(base.companion, tracking_margin_m2=0.04))

    def job(sc):
        peers = PeerIntents(FleetConfig(coordination="distributed"), own_system=3)
        peers.update(PEER, _turning(t0=10.0))
        return _job(sc, peers)

    without, with_margin = job(base), job(scenario)
    assert with_margin.tracks_along_intent == (PEER,)
    assert np.allclose(with_margin.request.margin_cov, 0.04 * np.eye(3))
    extra = with_margin.request.obstacle_covs[0] - without.request.obstacle_covs[0]
    assert np.allclose(extra, 0.04 * np.eye(3)[None])                           # every step
    assert np.allclose(with_margin.request.obstacle_covs[1], without.request.obstacle_covs[1])
    assert with_margin.realised_contour == without.realised_contour
