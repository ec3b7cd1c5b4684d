"""``companion plan``: the scenario-1 run from the command line, JSON and figure."""

from __future__ import annotations

import json

import numpy as np
import pytest

from companion.core import overlap
from companion.cli import main


@pytest.mark.parametrize("formulation", ["hyperplane", "paper"])
def test_that_plan_json_reaches_the_goal_with_contours_apart(formulation, capsys):
    assert main(["plan", "configs/single_obstacle.toml", "--formulation", formulation, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    for key in ("status", "iterations", "solve_time_s", "positions", "velocities", "drone_covariances", "obstacles",
                "drone_radius", "c_min", "c_max", "contour_of_touch"):
        assert key in out
    assert out["status"] == "optimal" and out["formulation"] == formulation
    pos = np.array(out["positions"])
    assert pos.shape == (20, 3) and np.array(out["drone_covariances"]).shape == (20, 3, 3)
    assert np.linalg.norm(pos[-1] - [10.0, 0.0, -5.0]) <= 0.1
    ob = out["obstacles"][0]
    c = overlap.contour_of_touch(pos, np.array(out["drone_covariances"]), np.array(ob["means"]),
                                 np.array(ob["covariances"]), ob["radius"] + out["drone_radius"])
    assert c.min() >= 0.599
    np.testing.assert_allclose(np.array(out["contour_of_touch"])[0], c, atol=1e-9)
    # the scenario models a 0.3 s velocity lag: the commands lead the planned velocities
    assert out["velocity_time_constant_s"] == 0.3
    cmd, vel = np.array(out["commands"]), np.array(out["velocities"])
    assert cmd.shape == (20, 3) and not np.allclose(cmd, vel, atol=1e-3)


def test_that_plan_plot_writes_a_png(tmp_path, capsys):
    target = tmp_path / "fig" / "plan.png"
    assert main(["plan", "configs/single_obstacle.toml", "--plot", str(target)]) == 0
    assert target.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "optimal" in capsys.readouterr().out


def test_that_a_bad_scenario_is_a_clear_error(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('[planner]\nc_min = 1.5\n[mission]\ngoal_ned_m = [1.0, 0.0, -5.0]\ngoal_tolerance_m = 0.3\n')
    assert main(["plan", str(bad)]) == 2
    assert "c_min = 1.5" in capsys.readouterr().err


def test_that_plan_moves_scripted_obstacles_by_mavsims_model_with_delay_and_loop(tmp_path):
    from companion.commands.plan import build_request

    path = tmp_path / "delayed.toml"
    path.write_text(
        "[vehicle]\nstart_ned_m = [0.0, 0.0, -5.0]\n"
        "[mission]\ngoal_ned_m = [10.0, 0.0, -5.0]\ngoal_tolerance_m = 0.3\n"
        "[planner]\nhorizon_steps = 20\nstep_s = 0.5\n"
        "[[world.obstacles]]\nname = 'late'\nstart_ned_m = [5.0, 5.0, -5.0]\nvelocity_ned_mps = [1.0, 0.0, 0.0]\n"
        "start_delay_s = 4.0\n"
        "[[world.obstacles]]\nname = 'shuttle'\nstart_ned_m = [0.0, 8.0, -5.0]\nwaypoints_ned_m = [[2.0, 8.0, -5.0]]\n"
        "speed_mps = 1.0\nloop = true\n"
    )
    _, req, info = build_request(path)
    assert info["names"] == ["late", "shuttle"]
    t = 0.5 * np.arange(1, 21)
    late, shuttle = req.obstacle_means
    np.testing.assert_allclose(late[:, 0], 5.0 + np.maximum(0.0, t - 4.0))      # still until 4 s, then 1 m/s
    s = np.mod(t, 4.0)                                                          # 2 m out, 2 m back, again
    np.testing.assert_allclose(shuttle[:, 0], np.where(s <= 2.0, s, 4.0 - s), atol=1e-12)
