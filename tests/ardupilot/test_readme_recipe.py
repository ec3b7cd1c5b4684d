"""The README's "Flying ArduPilot" recipe against ArduCopter SITL, run exactly as written (``make ardupilot-test``).

The harness puts ``start-arducopter`` on PATH and sets ARDUPILOT_SITL_DIR to the unpacked build; the block
after ``<!-- fly-recipe: ardupilot`` in README.md then runs verbatim in bash with this checkout's
``companion`` (:mod:`tests.support.recipes`; in a network namespace of its own where ``unshare -n`` works):
SITL instance 3, ``companion fly --autopilot ardupilot --arm --takeoff-alt 5 --exit-after-goal 1``, the
replay, SITL stopped. About 1.5 minutes (ArduCopter's EKF needs about 42 s to be ready).

Asserted: the recipe exits 0 (the goal reached, LOITER confirmed, the replay exact), the companion engaged in
GUIDED after a takeoff to 5 m within 0.3 m in the vehicle's estimate, and handed back to LOITER.
"""

from __future__ import annotations

import json
import re

import pytest

from tests.ardupilot.sitl import _script, available, build_dir, free_instance
from tests.support.recipes import private_network, readme_recipes, run_recipe

pytestmark = pytest.mark.ardupilot

_PRELUDE = 'export PATH="{script_dir}:$PATH" ARDUPILOT_SITL_DIR="{build}"\n'


@pytest.mark.quarantine(reason="not yet through 20 rounds of make flake-check (the ArduCopter stage)")
def test_that_the_readme_fly_recipe_against_arducopter_sitl_works_as_written(tmp_path):
    if not available():
        pytest.fail("no ArduCopter SITL build: set ARDUPILOT_SITL_DIR or put one at ../shared/ardupilot-sitl")
    if not private_network() and free_instance() != 3:
        pytest.skip("instance 3's ports are in use and no private network namespace is available")
    recipe = readme_recipes()["ardupilot"]
    assert "companion fly" in recipe and "--autopilot ardupilot" in recipe
    proc = run_recipe(recipe, tmp_path, timeout_s=240,
                      prelude=_PRELUDE.format(script_dir=_script().parent, build=build_dir()))
    print(proc.stdout[-3000:], proc.stderr[-3000:])
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads((tmp_path / "fly.json").read_text())
    events = [text for _, text in report["events"]]
    assert report["outcome"] == "goal reached" and report["phase"] == "HELD", report["outcome"]
    assert any(t.startswith("ENGAGED: vehicle switched to GUIDED") for t in events), events
    assert any(t.startswith("HELD: vehicle in LOITER") for t in events), events
    height = float(re.search(r"takeoff height reached: ([\d.]+) m", " ".join(events)).group(1))
    assert abs(height - 5.0) <= 0.3, height
    assert re.search(r"max \|difference\| \[m/s\]\s+0 at", proc.stdout), proc.stdout[-2000:]   # the replay exact
