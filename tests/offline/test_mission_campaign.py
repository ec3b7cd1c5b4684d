"""Mission campaigns in guard mode (companion/offline/campaign/missions.py, ``campaign --family mission``)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from companion.cli import main
from companion.core.fence import Fence, PolygonZone
from companion.errors import ConfigError, InputError
from companion.loop.fence_source import place_fence
from companion.loop.mission_file import parse_plan
from companion.offline.campaign.mission_episodes import (
    BUILDING_CLEARANCE_M, END_CLEARANCE_M, MIN_CROSSING_S, ORIGIN, SPAWN_CLEARANCE_M, generate_mission, predicted_times)
from companion.offline.campaign.missions import (
    MissionRun, read_mission_results, run_mission_campaign, summarise_missions)
from companion.offline.harness import run_lockstep

SEED = 1


@pytest.mark.parametrize("index", range(12))
def test_that_an_episode_is_drawn_from_its_index_and_is_a_mission_an_operator_could_upload(index):
    ep = generate_mission(SEED, index)
    assert generate_mission(SEED, index).scenario == ep.scenario and generate_mission(SEED, index + 1).plan != ep.plan
    plan = parse_plan(json.dumps(ep.plan), "episode.plan")
    assert [it.command for it in plan.items] == [178] + [16] * len(ep.waypoints)   # DO_CHANGE_SPEED, the waypoints
    assert plan.items[0].params[1] == pytest.approx(ep.cruise_mps) and 2.0 <= ep.cruise_mps <= 3.0
    # the fence the companion places from the plan is the one drawn, and every waypoint is inside it
    placed = place_fence(plan, ORIGIN.lat_deg, ORIGIN.lon_deg)
    drawn = Fence(polygons=tuple(PolygonZone(ring, inclusion) for ring, inclusion in ep.fence))
    for p in ep.waypoints:
        assert placed.clearance(p) == pytest.approx(drawn.clearance(p), abs=0.01) and drawn.clearance(p) > 1.0
    start = np.array(ep.scenario["vehicle"]["start_ned_m"])
    route = np.vstack([start, ep.waypoints])
    if len(ep.fence) > 1:       # a building across one leg, which the autopilot's straight leg runs into
        building = Fence(polygons=(PolygonZone(ep.fence[1][0], False),))
        along = [route[k] + f * (route[k + 1] - route[k]) for k in range(len(route) - 1) for f in np.linspace(0, 1, 50)]
        assert min(building.clearance(p) for p in along) < -1.0
        assert min(building.clearance(p) for p in route) >= BUILDING_CLEARANCE_M   # not beside a waypoint or the start
    # the last waypoint is not passed on the way (the referee's goal), no aircraft crosses too soon,
    # waits or parks on a waypoint, or beside a leg other than the one it crosses
    last = route[-1]
    for a, b in zip(route[:-2], route[1:-1]):
        f = np.clip(np.dot(last - a, b - a) / np.dot(b - a, b - a), 0.0, 1.0)
        assert np.linalg.norm(last - (a + f * (b - a))) >= END_CLEARANCE_M
    for crossing, ob in zip(ep.crossings, ep.scenario["world"]["obstacles"]):
        assert crossing["predicted_s"] >= MIN_CROSSING_S and ob["start_delay_s"] >= 0.0
        for parked in (np.array(ob["start_ned_m"]), np.array(ob["waypoints_ned_m"][-1])):
            assert np.min(np.linalg.norm(route[:, :2] - parked[:2], axis=1)) >= SPAWN_CLEARANCE_M
            for k, (a, b) in enumerate(zip(route[:-1, :2], route[1:, :2])):
                f = np.clip(np.dot(parked[:2] - a, b - a) / np.dot(b - a, b - a), 0.0, 1.0)
                assert k == crossing["leg"] or np.linalg.norm(parked[:2] - (a + f * (b - a))) >= SPAWN_CLEARANCE_M


def test_that_no_building_stands_beside_the_start_or_a_waypoint():
    """Before the rule, 13 of episodes 0-299 had one nearer than 4 m (episode 185: a waypoint 0.5 m
    off the wall, never reached within its 1 m with the body and contour kept off the wall)."""
    for index in range(300):
        ep = generate_mission(SEED, index)
        if len(ep.fence) > 1:
            building = Fence(polygons=(PolygonZone(ep.fence[1][0], False),))
            route = np.vstack([ep.scenario["vehicle"]["start_ned_m"], ep.waypoints])
            assert min(building.clearance(p) for p in route) >= BUILDING_CLEARANCE_M, index


def test_that_the_autopilot_reaches_each_waypoint_when_the_generator_predicts_it(tmp_path):
    """The traffic is timed on the predicted mission; mavsim's PX4 flying it alone (watched)
    reaches every waypoint within 1.5 s of the prediction."""
    ep = generate_mission(SEED, 4)
    path = tmp_path / "m.plan"
    path.write_text(json.dumps(ep.plan))
    data = json.loads(json.dumps(ep.scenario))
    data["mission"]["plan_file"] = str(path)
    data["offboard"] = {"arm": True, "takeover": "watch"}
    data["world"]["obstacles"] = data["world"]["obstacles"][:1]
    run = run_lockstep(data, seed=0, stop_after_goal_s=2.0)
    reached = {seq: t for t, seq in run.companion.progress.reached}
    flown = np.array([reached[k] for k in range(1, len(ep.waypoints) + 1)])
    predicted = predicted_times(np.array(ep.scenario["vehicle"]["start_ned_m"]), ep.waypoints, ep.cruise_mps)
    assert np.max(np.abs(flown - predicted)) < 1.5, (flown, predicted)


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    path = tmp_path_factory.mktemp("mission") / "mission.jsonl"
    return path, run_mission_campaign(range(2), ["hyperplane", "alone"], SEED, workers=1, results_path=path,
                                      progress="off")


def test_that_the_guard_keeps_clear_where_the_autopilot_alone_collides_and_breaches(campaign):
    """Episodes 0 and 1 of seed 1: a building across a leg and three aircraft each. Alone, the
    autopilot flies into the building (and into traffic); guarded, the traffic and the fence are
    kept with the promise held, every waypoint is reached, a little later than alone."""
    _, result = campaign
    runs = {r.key: r for r in result.runs}
    for episode in (0, 1):
        alone, guarded = runs[(episode, "alone")], runs[(episode, "hyperplane")]
        assert alone.error is None and guarded.error is None
        assert alone.building and alone.fence_breached and alone.takeovers == 0 and alone.min_realised_contour is None
        assert alone.completed
        assert guarded.takeovers >= 1 and guarded.min_realised_contour >= 0.9
    assert any(runs[(e, "alone")].collided for e in (0, 1))
    # episode 1: guarded without a collision or a breach, completed within 1.25x alone's time
    one = runs[(1, "hyperplane")]
    assert not one.collided and not one.fence_breached and one.completed
    assert one.mission_s < 1.25 * runs[(1, "alone")].mission_s


def test_that_the_results_file_resumes_and_refuses_another_campaigns(campaign):
    path, result = campaign
    header, rows = read_mission_results(path)
    assert header["format"] == "ogccmpc-mission-campaign" and header["seed"] == SEED
    assert sorted(rows) == sorted(r.key for r in result.runs)
    again = run_mission_campaign(range(2), ["hyperplane", "alone"], SEED, results_path=path, resume=True, progress="off")
    assert again.runs == result.runs and len(path.read_text().splitlines()) == 5   # nothing flown twice
    with pytest.raises(ConfigError, match="exists"):
        run_mission_campaign(range(1), ["alone"], SEED, results_path=path, progress="off")
    with pytest.raises(ConfigError, match="flown with"):
        run_mission_campaign(range(1), ["alone"], SEED + 1, results_path=path, resume=True, progress="off")
    with pytest.raises(InputError, match="unknown method"):
        run_mission_campaign(range(1), ["paper"], SEED, progress="off")


def test_that_the_summary_gives_rates_intervals_and_the_time_against_alone():
    runs = [MissionRun(0, "alone", 1, collided=True, fence_breached=True, completed=True, mission_s=40.0),
            MissionRun(1, "alone", 2, collided=False, fence_breached=False, completed=True, mission_s=30.0),
            MissionRun(0, "hyperplane", 1, collided=False, fence_breached=False, completed=True, mission_s=50.0,
                       takeovers=2, taken_over_s=12.0, min_realised_contour=0.95),
            MissionRun(1, "hyperplane", 2, collided=False, fence_breached=False, completed=False, takeovers=1,
                       taken_over_s=30.0, min_realised_contour=0.85),
            MissionRun(2, "hyperplane", 3, error="RuntimeError: x")]
    alone, guarded = summarise_missions(runs, ["alone", "hyperplane"], 0.9)
    assert (alone.runs, alone.collisions, alone.fence_breaches, alone.completed) == (2, 1, 1, 2)
    assert alone.collision_ci[0] > 0.0 and alone.time_over_alone_median == 1.0
    assert (guarded.runs, guarded.errors, guarded.collisions, guarded.completed, guarded.promise_broken) == (2, 1, 0, 1, 1)
    assert guarded.collision_ci == (0.0, pytest.approx(0.8419, abs=1e-4))
    assert guarded.time_over_alone_median == 1.25 and guarded.takeovers_per_mission == 1.5
    assert guarded.taken_over_median_s == 21.0 and guarded.min_realised_contour == 0.85


@pytest.mark.parametrize("argv, needle", [
    (["--methods", "paper"], "not a method of --family mission"),
    (["--vehicle", "px4"], "--vehicle is not available with --family mission"),
    (["--duration", "60"], "each mission sets its own length"),
    (["--drones", "3"], "--drones is not available"),
    (["--save-scenario", "x.toml"], "--save-scenario needs --episode"),
])
def test_that_flags_the_mission_family_does_not_take_are_one_line(capsys, tmp_path, argv, needle):
    try:
        code = main(["campaign", "--family", "mission", "--results", str(tmp_path / "r.jsonl"), *argv])
    except SystemExit as stop:
        code = stop.code
    err = capsys.readouterr().err
    assert code == 2 and needle in err and err.count("\n") == 1 and "Traceback" not in err
    assert not (tmp_path / "r.jsonl").exists()                          # nothing flown


def test_that_an_episode_is_saved_as_a_scenario_and_plan_that_fly(capsys, tmp_path):
    out = tmp_path / "ep" / "mission.toml"
    code = main(["campaign", "--family", "mission", "--episode", "1", "--seed", str(SEED), "--methods", "alone",
                 "--save-scenario", str(out), "--progress", "off"])
    assert code == 0 and out.exists() and out.with_suffix(".plan").exists()
    run = run_lockstep(out, seed=0, stop_after_goal_s=2.0)           # guarded, as saved
    assert run.companion.guard is not None and run.companion.guard.summary()["takeovers_count"] >= 1
    assert '"episode": 1, "method": "alone"' in capsys.readouterr().out
