"""Swap campaigns per coordination mode (companion/offline/campaign/fleet.py, `campaign --family swap`)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from companion.cli import main
from companion.errors import ConfigError
from companion.loop.config import scenario_from_dict
from companion.offline.campaign.fleet import (FleetRun, generate_swap, read_fleet_results, run_fleet_campaign,
                                              summarise_fleet)


def test_that_an_episode_is_drawn_from_its_seed_and_index_alone():
    a, b = generate_swap(0, 3, 4), generate_swap(0, 3, 4)
    assert a == b and generate_swap(0, 4, 4) != a
    starts = np.array([s["vehicle"]["start_ned_m"] for s in a])
    radius = np.linalg.norm(starts[:, :2], axis=1)
    assert np.allclose(radius, radius[0]) and 5.0 <= radius[0] <= 8.0
    speeds = [ob["speed_mps"] for ob in a[0]["world"]["obstacles"]]
    assert len(speeds) == 2 and all(1.0 <= v <= 2.0 for v in speeds)
    assert all(s["planner"]["c_min"] == 0.9 for s in a)
    # reports and announcements planned around from 30 m, the sensing range left at 10 m
    loaded = scenario_from_dict(a[1], "episode.toml")
    assert loaded.traffic.range_m == 30.0 and loaded.traffic.policy("fleet", 1).range_m == 30.0
    assert loaded.planner.sensing_range_m == 10.0


def test_that_a_campaign_writes_its_runs_resumes_them_and_refuses_another_campaigns_file(tmp_path):
    path = tmp_path / "swap.jsonl"
    first = run_fleet_campaign(2, range(1), ["distributed"], 0, workers=1, duration_s=20.0, results_path=path,
                               progress="off")
    (row,) = first.runs
    assert row.error is None and row.goal_reached and not row.collided and row.pair_ticks > 0
    header, rows = read_fleet_results(path)
    assert header["drones"] == 2 and list(rows) == [(0, "distributed")]
    # resumed with one more episode: only that one is flown
    second = run_fleet_campaign(2, range(2), ["distributed"], 0, workers=1, duration_s=20.0, results_path=path,
                                resume=True, progress="off")
    assert [r.episode for r in second.runs] == [0, 1] and second.runs[0] == row
    assert len(path.read_text().splitlines()) == 3
    with pytest.raises(ConfigError, match="exists"):
        run_fleet_campaign(2, range(1), ["distributed"], 0, results_path=path, progress="off")
    with pytest.raises(ConfigError, match="flown with"):
        run_fleet_campaign(3, range(1), ["distributed"], 0, results_path=path, resume=True, progress="off")


def test_that_the_summary_counts_collisions_broken_promises_and_deadlocks_per_mode():
    runs = [FleetRun(0, "distributed", 2, 1, collided=False, goal_reached=True, time_to_all_goals_s=10.0,
                     min_pair_clearance_m=0.5, min_peer_realised_contour=0.95, pair_ticks=100),
            FleetRun(1, "distributed", 2, 2, collided=True, drone_drone_collisions=1, goal_reached=True,
                     time_to_all_goals_s=14.0, min_pair_clearance_m=-0.1, min_peer_realised_contour=0.0,
                     deadlocks=2, pair_ticks=100, pair_contact_ticks=3),
            FleetRun(2, "distributed", 2, 3, error="RuntimeError: x")]
    (s,) = summarise_fleet(runs, ["distributed"], 0.9)
    assert (s.runs, s.errors, s.collisions, s.drone_drone, s.promise_broken, s.deadlock_runs) == (2, 1, 1, 1, 1, 1)
    assert s.time_to_all_goals_median_s == 12.0 and s.step_frequency == pytest.approx(3 / 200)
    assert s.collision_ci[0] > 0.0 and s.collision_ci[1] < 1.0


def test_that_the_command_flies_a_swap_campaign_and_checks_its_flags(tmp_path, capsys):
    out = tmp_path / "c.json"
    assert main(["campaign", "--family", "swap", "--drones", "2", "--episodes", "1", "--methods", "prioritised",
                 "--duration", "20", "--workers", "1", "--progress", "off", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "| prioritised | 1 | 0 [" in text and (tmp_path / "c.jsonl").exists()
    assert json.loads(out.read_text())["summary"][0]["mode"] == "prioritised"
    for argv, words in ((["--family", "swap"], "--drones"), (["--family", "swap", "--drones", "2", "--methods", "paper"],
                        "not a coordination mode"), (["--drones", "2"], "--family swap"),
                        (["--methods", "distributed"], "coordination mode")):
        assert main(["campaign", *argv, "--episodes", "1", "--results", str(tmp_path / "x.jsonl")]) == 2
        err = capsys.readouterr().err.strip()
        assert words in err and len(err.splitlines()) == 1, err
