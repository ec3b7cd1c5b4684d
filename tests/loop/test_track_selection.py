"""Many tracks: the planner constrains the riskiest few, in a documented order, and says how many it left out."""

from __future__ import annotations

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.core.planner import Planner
from companion.loop.app import Companion
from companion.loop.config import load_scenario
from companion.loop.planning import InlinePlanning
from companion.loop.track_selection import choose, confidence_radius, rank_by_risk
from tests.support.inbound import px4_offboard_heartbeat, received


def test_that_tracks_rank_by_predicted_clearance_then_time_of_closest_approach():
    path = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    means = np.array([
        [[0.0, 8.0, 0.0]] * 3,                                   # far, stays far
        [[2.0, 3.0, 0.0]] * 3,                                   # 3 m from the last step
        [[1.0, 3.0, 0.0]] * 3,                                   # 3 m from the middle step: same clearance, sooner
        [[0.0, 1.0, 0.0], [1.0, 1.0, 0.0], [2.0, 1.0, 0.0]],     # alongside at 1 m
    ])
    order, clearance, t_close = rank_by_risk(path, means, np.zeros((4, 3)), 0.0, 1.0, 0.3, 2.0)
    assert order.tolist() == [3, 2, 1, 0]
    assert clearance.tolist() == [7.0, 2.0, 2.0, 0.0]
    assert t_close[2] == 0.3 and t_close[1] == 0.6
    # uncertainty counts against clearance: a wide track 4 m away outranks a sharp one 3 m away
    wide = np.array([[[0.0, 4.0, 0.0]] * 3, [[0.0, 3.0, 0.0]] * 3])
    order, _, _ = rank_by_risk(path[:1].repeat(3, 0), wide, np.array([[1.0] * 3, [0.0] * 3]), 0.0, 1.0, 0.3, confidence_radius(0.9))
    assert order.tolist() == [0, 1]
    chosen, rest = choose(np.array([3, 2, 1, 0]), 2)
    assert chosen.tolist() == [2, 3] and rest.tolist() == [1, 0]


def test_that_two_hundred_tracks_are_cut_to_the_limit_with_the_close_one_kept_and_the_rest_reported():
    scenario = load_scenario("configs/antipodal.toml")
    jobs = []

    class Spy(InlinePlanning):
        def submit(self, job):
            jobs.append(job)
            super().submit(job)

    companion = Companion(scenario, planning=Spy(Planner(scenario.planner)))
    hb = px4_offboard_heartbeat()
    rng = np.random.default_rng(4)
    far = np.column_stack([rng.uniform(-5, 25, 200), rng.choice([-1, 1], 200) * rng.uniform(5, 9, 200), np.full(200, -5.0)])
    texts = []
    sent_setpoints = 0
    for i in range(8):
        t = 0.05 * i
        companion.handle(received(hb, (1, 1), t))
        companion.handle(received(mavlink2.MAVLink_local_position_ned_message(int(t * 1000), 0, 0, -5, 0, 0, 0), (1, 1), t))
        for k, p in enumerate(far):
            companion.handle(received(mavlink2.MAVLink_local_position_ned_message(int(t * 1000), *p, 0, 0, 0), (30 + k, 198), t, "obstacles1"))
        companion.handle(received(mavlink2.MAVLink_local_position_ned_message(int(t * 1000), 2.0, 0.2, -5, 0, 0, 0), (20, 197), t, "obstacles1"))
        out = companion.tick(t)
        texts += [m.text for m in out if m.get_type() == "STATUSTEXT"]
        sent_setpoints += sum(m.get_type() == "SET_POSITION_TARGET_LOCAL_NED" for m in out)
    assert len(companion.tracker) == 201
    limit = scenario.companion.max_constrained_tracks
    assert companion.records, "no replan ran"
    rec = companion.records[-1]
    assert rec.tracks_unconstrained == 201 - limit
    assert companion.state.tracks_unconstrained_max == 201 - limit
    assert (20, 197, "obstacles1") in rec.obstacle_positions and len(rec.realised_contour) == 201  # all still tracked and measured
    assert sum(f"{201 - limit} tracks beyond {limit} not constrained" in t for t in texts) == 1  # rate-limited
    assert sent_setpoints == 8
    assert len(jobs) == 2
    for job in jobs:
        assert job.request.num_obstacles == limit + len(scenario.static_obstacles)
        assert (20, 197, "obstacles1") not in job.tracks_unconstrained  # the one 2 m ahead is constrained


def test_that_the_request_builder_takes_each_tracks_radius_from_its_lookup():
    from companion.loop.perception import Perception
    from companion.loop.request_builder import RequestBuilder

    scenario = load_scenario("configs/antipodal.toml")
    perception = Perception(scenario)
    perception.drone.update(0.0, np.array([0.0, 0.0, -5.0]), np.zeros(3), np.full(3, 0.01), np.full(3, 0.01))
    big, default = ("icao", 0xABC), (20, 197, "obstacles1")
    for key, pos in ((big, [6.0, 0.0, -5.0]), (default, [0.0, 6.0, -5.0])):
        perception.tracker.update(key, 0.0, np.array(pos), np.zeros(3), 0.01 * np.eye(3), 0.01 * np.eye(3))
    radii = {big: 10.0}
    lookup = lambda key: radii.get(key, scenario.companion.obstacle_radius_m)  # noqa: E731
    plain = RequestBuilder(scenario).build(seq=0, t_s=0.0, t_v=0.0, perception=perception,
                                           initial_velocity=np.zeros(3), warm_start=None)
    sized = RequestBuilder(scenario, obstacle_radius=lookup).build(seq=0, t_s=0.0, t_v=0.0, perception=perception,
                                                                   initial_velocity=np.zeros(3), warm_start=None)
    n_tracks = 2
    assert plain.request.obstacle_radii[:n_tracks].tolist() == [scenario.companion.obstacle_radius_m] * 2
    assert sized.request.obstacle_radii[:n_tracks].tolist() == [10.0, scenario.companion.obstacle_radius_m]
    # the bigger body reaches the drone's contour sooner: a smaller realised contour of touch
    assert sized.realised_contour[big] < plain.realised_contour[big]
    assert sized.realised_contour[default] == plain.realised_contour[default]


def test_that_a_sources_range_reaches_the_plan_request():
    """``[traffic] range_m`` and a source rule's, from the intake through the request to the plan:
    a report 15 m out is planned around with 20 m, not with the 10 m sensing range."""
    import dataclasses

    from companion.loop.intake.traffic_config import traffic_from_toml

    base = load_scenario("configs/antipodal.toml")
    assert base.planner.sensing_range_m == 10.0
    traffic = traffic_from_toml({"range_m": 20.0, "source": [{"link": "obstacles", "system": 21, "range_m": 5.0}]}, "t")
    jobs = []

    class Spy(InlinePlanning):
        def submit(self, job):
            jobs.append(job)
            super().submit(job)

    for scenario in (base, dataclasses.replace(base, traffic=traffic)):
        jobs.clear()
        companion = Companion(scenario, planning=Spy(Planner(scenario.planner)))
        for i in range(8):
            t = 0.05 * i
            companion.handle(received(px4_offboard_heartbeat(), (1, 1), t))
            companion.handle(received(mavlink2.MAVLink_local_position_ned_message(int(t * 1000), 0, 0, -5, 0, 0, 0), (1, 1), t))
            for sysid, north in ((20, 15.0), (21, 4.0)):
                companion.handle(received(mavlink2.MAVLink_local_position_ned_message(int(t * 1000), north, 0.0, -5, -1, 0, 0),
                                          (sysid, 197), t, "obstacles1"))
            companion.tick(t)
        job = jobs[-1]
        keys = list(job.tracks_constrained)
        ranges = dict(zip(keys, job.request.obstacle_ranges_m))
        statics = job.request.obstacle_ranges_m[len(keys):]
        assert statics.tolist() == [10.0] * len(scenario.static_obstacles)    # not tracks: the sensing range
        if scenario is base:
            assert ranges == {(20, 197, "obstacles1"): 10.0, (21, 197, "obstacles1"): 10.0}
        else:
            assert ranges == {(20, 197, "obstacles1"): 20.0, (21, 197, "obstacles1"): 5.0}
        in_range = dict(zip(keys, Planner(scenario.planner).solve(job.request).in_range))
        assert in_range[(20, 197, "obstacles1")] == (scenario is not base)


def test_that_beyond_walls_checks_the_trackers_own_prediction_at_every_step():
    from estimator import ObstacleTracker, TrackerConfig

    from companion.loop.track_selection import beyond_walls

    tracker = ObstacleTracker(TrackerConfig(accel_noise_psd_m2ps3=0.05))
    walls_n, walls_b = np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]]), np.array([1.5, 1.5])  # |y| <= 1.5
    rng = np.random.default_rng(7)
    for k in range(60):
        p = np.array([rng.uniform(-5, 30), rng.choice([-1, 1]) * rng.uniform(0.0, 9.0), -5.0])
        v = np.array([rng.uniform(-1, 1), rng.uniform(-1.5, 1.5), 0.0])
        tracker.update(k, 0.0, p, v, rng.uniform(0.01, 0.3) * np.eye(3), 0.05 * np.eye(3))
    keys = tracker.keys()
    times = 0.4 + 0.3 * np.arange(1, 21)
    states = [tracker.state(k) for k in keys]
    radii = rng.uniform(0.3, 1.0, len(keys))
    r = confidence_radius(0.3)
    got = beyond_walls(np.array([s.mean for s in states]), np.array([s.cov for s in states]),
                       times[None, :] - np.array([s.t_s for s in states])[:, None], 0.05, walls_n, walls_b, radii, r)
    for j, key in enumerate(keys):  # the same question asked step by step of the tracker's prediction
        means, covs = tracker.predict(key, times)
        clear = [max(a @ m - b - r * np.sqrt(a @ c @ a) - radii[j] for a, b in zip(walls_n, walls_b))
                 for m, c in zip(means, covs)]
        assert got[j] == (min(clear) >= 0.0), (key, min(clear))
    assert 0 < got.sum() < len(keys)  # both kinds drawn
    assert not beyond_walls(np.zeros((2, 6)), np.tile(np.eye(6), (2, 1, 1)), np.ones((2, 3)), 0.1,
                            np.zeros((0, 3)), np.zeros(0), np.ones(2), r).any()  # no walls: nothing set apart


def test_that_a_drone_kept_inside_a_wall_and_a_track_beyond_it_never_touch_at_c_min():
    """The claim :func:`beyond_walls` rests on, checked with the exact contour of touch (point bodies)."""
    from companion.core.overlap import contour_of_touch

    rng = np.random.default_rng(3)
    r = confidence_radius(0.9)
    worst = 1.0
    for _ in range(500):
        a = rng.normal(size=3)
        a /= np.linalg.norm(a)
        b = rng.uniform(-3.0, 3.0)
        s_d, s_o = (m @ m.T * rng.uniform(0.01, 2.0) + 0.01 * np.eye(3) for m in rng.normal(size=(2, 3, 3)))
        slide_d, slide_o = (t - a * (a @ t) for t in rng.normal(size=(2, 3)) * 5.0)  # anywhere along the wall
        drone = a * (b - r * np.sqrt(a @ s_d @ a)) + slide_d    # on its wall limit (the exact wall recheck)
        track = a * (b + r * np.sqrt(a @ s_o @ a)) + slide_o    # just beyond, as beyond_walls demands
        worst = min(worst, float(contour_of_touch(drone, s_d, track, s_o)))
    assert worst >= 0.9 - 1e-9


def test_that_in_a_corridor_the_crowd_outside_its_walls_needs_no_rows_and_a_track_heading_in_does():
    from companion.loop.perception import Perception
    from companion.loop.request_builder import RequestBuilder

    scenario = load_scenario("configs/corridor.toml")
    perception = Perception(scenario)
    perception.drone.update(0.0, np.array([0.0, 0.0, -5.0]), np.zeros(3), np.full(3, 0.01), np.full(3, 0.01))
    rng = np.random.default_rng(5)
    crowd = np.column_stack([rng.uniform(-5, 30, 200), rng.choice([-1, 1], 200) * rng.uniform(6, 10, 200), np.full(200, -5.0)])
    for k, p in enumerate(crowd):
        perception.tracker.update((30 + k, 198, "obstacles1"), 0.0, p, np.zeros(3), 0.04 * np.eye(3), 0.01 * np.eye(3))
    leader, inbound = (2, 1, "obstacles1"), (3, 1, "obstacles1")
    perception.tracker.update(leader, 0.0, np.array([3.0, 0.0, -5.0]), np.array([1.0, 0.0, 0.0]), 0.02 * np.eye(3), 0.01 * np.eye(3))
    perception.tracker.update(inbound, 0.0, np.array([12.0, 8.0, -5.0]), np.array([0.0, -2.0, 0.0]),  # through the wall in 3 s
                              0.02 * np.eye(3), 0.01 * np.eye(3))
    job = RequestBuilder(scenario).build(seq=0, t_s=0.0, t_v=0.0, perception=perception,
                                         initial_velocity=np.zeros(3), warm_start=None)
    assert set(job.tracks_constrained) == {leader, inbound}
    assert len(job.tracks_beyond_walls) == 200 and not job.tracks_unconstrained
    assert job.request.num_obstacles == 2 + len(scenario.static_obstacles)
    assert len(job.realised_contour) == 202  # still measured, every one


def test_that_the_left_out_tracks_estimates_now_are_each_track_s_estimate_moved_on_without_noise():
    """The vectorised pass gives, per track, ``F x`` and ``F P F'`` with ``F = [I, lag I]`` (lag >= 0)."""
    from companion.loop.request_builder import RequestBuilder

    rng = np.random.default_rng(11)
    keys = [("a", i) for i in range(6)]
    t_est = np.array([0.0, 0.3, 1.0, 1.2, 2.5, 3.0])      # the last two are newer than t_v: lag 0
    mean = rng.normal(size=(6, 6))
    m = rng.normal(size=(6, 6, 6))
    cov = m @ np.swapaxes(m, 1, 2) + 0.1 * np.eye(6)
    row = {k: 5 - i for i, k in enumerate(keys)}        # rows need not follow the keys' order
    stack = (t_est[::-1].copy(), mean[::-1].copy(), cov[::-1].copy())
    t_v = 2.0
    now = RequestBuilder._estimates_now(keys[1:], stack, row, t_v)
    assert list(now) == keys[1:]
    for i, key in enumerate(keys[1:], 1):
        lag = max(t_v - t_est[i], 0.0)
        f = np.hstack([np.eye(3), lag * np.eye(3)])
        pos, pos_cov = now[key]
        assert np.allclose(pos, f @ mean[i], rtol=1e-13, atol=1e-13)
        assert np.allclose(pos_cov, f @ cov[i] @ f.T, rtol=1e-13, atol=1e-12)
    assert RequestBuilder._estimates_now([], None, {}, t_v) == {}
