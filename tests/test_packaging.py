"""The built wheel carries every package and the shipped scenarios, and flies from any directory.

Builds the wheel with pip (as a user would), unpacks it as an installed ``site-packages``
would hold it, and runs ``companion demo antipodal --json`` from an empty directory with
only that tree on the path: no source checkout, no ``configs/`` next to the working directory.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_that_a_built_wheel_flies_the_shipped_antipodal_scenario_from_anywhere(tmp_path):
    dist = tmp_path / "dist"
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(dist), str(ROOT)],
        check=True, capture_output=True, timeout=300,
    )
    (wheel,) = dist.glob("ogccmpc-*.whl")
    site = tmp_path / "site"
    with zipfile.ZipFile(wheel) as zf:
        names = set(zf.namelist())
        zf.extractall(site)
    for scenario in ("antipodal", "corridor", "single_obstacle", "mission_survey"):
        assert f"companion/scenarios/{scenario}.toml" in names
    assert "companion/scenarios/mission_survey.plan" in names      # the mission and fence it names

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"} | {"PYTHONPATH": str(site)}
    done = subprocess.run(
        [sys.executable, "-P", "-m", "companion.cli", "demo", "antipodal", "--json"],
        cwd=elsewhere, env=env, capture_output=True, text=True, timeout=300,
    )
    assert done.returncode == 0, done.stderr
    where = subprocess.run(
        [sys.executable, "-P", "-c", "import companion.scenarios as s; print(s.__file__)"],
        cwd=elsewhere, env=env, capture_output=True, text=True, timeout=60, check=True,
    )
    assert Path(where.stdout.strip()).is_relative_to(site), "the run did not use the wheel's files"
    summary = json.loads(done.stdout)
    assert summary["goal_reached"] and not summary["collided"]
