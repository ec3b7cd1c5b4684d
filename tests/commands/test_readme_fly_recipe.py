"""The README's fly recipe against mavsim, run exactly as written (``make realtime-test``).

The block after ``<!-- fly-recipe: mavsim`` in README.md runs in bash with this checkout's
``mavsim`` and ``companion`` (:mod:`tests.support.recipes`): mavsim on the ground with its
obstacles starting at OFFBOARD, ``companion fly --arm --takeoff-alt 5 --exit-after-goal 1``,
then mavsim stopped. Asserted: the recipe exits 0 (the companion reached the goal and handed
back), mavsim's ground truth shows the goal reached without a collision, the obstacles
started at OFFBOARD, and each came within 4 m of the drone (they meet it: before, two of three
passed 9 m away). About 30 s.
"""

from __future__ import annotations

import json

import pytest

from tests.support.recipes import readme_recipes, run_recipe

pytestmark = [pytest.mark.realtime]


def test_that_the_readme_fly_recipe_against_mavsim_works_as_written(tmp_path):
    recipe = readme_recipes()["mavsim"]
    assert "companion fly" in recipe and "mavsim " in recipe
    proc = run_recipe(recipe, tmp_path, timeout_s=240)
    print(proc.stdout[-3000:], proc.stderr[-3000:])
    assert proc.returncode == 0, proc.stderr[-3000:]
    truth = json.loads((tmp_path / "mavsim.json").read_text())
    print(json.dumps({k: truth[k] for k in ("min_distance_m", "goal_reached", "time_to_goal_s", "obstacles_started_s",
                                            "mode_changes")}, indent=1))
    assert truth["goal_reached"] and not truth["collided"], truth
    assert truth["obstacles_started_s"] is not None
    assert [m["mode"] for m in truth["mode_changes"]][:4] == ["POSCTL", "AUTO.TAKEOFF", "AUTO.LOITER", "OFFBOARD"]
    assert truth["obstacles_started_s"] == next(m["t_s"] for m in truth["mode_changes"] if m["mode"] == "OFFBOARD")
    assert max(truth["min_distance_m"].values()) < 4.0, truth["min_distance_m"]
    assert (tmp_path / "flight.tlog").stat().st_size > 0
