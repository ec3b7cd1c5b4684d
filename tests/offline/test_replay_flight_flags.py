"""``replay`` takes the flags of ``fly`` that change what is commanded, read the same way.

A mission flown in mavsim lockstep from a scenario's ``[mission] plan_file`` (uploaded to
the vehicle first) replays exactly from that scenario, and from the scenario without it
given ``--mission FILE``, the flag ``fly`` would have been given for the same flight; without
either, the replay flies the scenario's single goal and says it did not reproduce the flight.
A scenario with no goal at all needs the flag (as ``fly`` does): given it, the same replay;
without it, one line naming the keys and the flags.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from companion.offline.campaign.toml_writer import write_scenario
from companion.offline.harness import run_lockstep
from tests.loop.test_mission_flight import WPS, _scenario
from tests.support.missions import plan_text

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def mission_flight(tmp_path_factory):
    d = tmp_path_factory.mktemp("mission")
    plan = d / "square.plan"
    plan.write_text(plan_text(WPS[:2]))
    with_plan = _scenario(plan, duration_s=20.0)
    run_lockstep(with_plan, seed=0, stop_after_goal_s=None, tlog_path=d / "flight.tlog")
    without = {k: v for k, v in with_plan.items()}
    without["mission"] = {k: v for k, v in with_plan["mission"].items() if k != "plan_file"}
    without["mission"]["goal_ned_m"] = [10.0, 0.0, -5.0]
    return d, plan, write_scenario(with_plan, d / "with_plan.toml"), write_scenario(without, d / "without.toml")


def _replay(tlog: Path, scenario: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "companion.cli", "replay", str(tlog), "--scenario", str(scenario),
                           "--json", *extra], capture_output=True, text=True, cwd=REPO, timeout=300)


def test_a_mission_flight_replays_exactly_from_its_scenario_and_from_the_mission_flag(mission_flight):
    d, plan, with_plan, without = mission_flight
    results = []
    for scenario, extra in ((with_plan, ()), (without, ("--mission", str(plan)))):
        out = _replay(d / "flight.tlog", scenario, *extra)
        assert out.returncode == 0, out.stderr[-1000:]
        s = json.loads(out.stdout)
        assert s["commands_compared"] == s["commands_recorded"] > 100
        assert s["unmatched_commands"] == 0 and s["max_abs_diff_mps"] == 0.0
        assert s["tick_mismatches"] == 0        # the upload's answers are the requests' (not a tick's)
        results.append((s["commands_compared"], s["replans"]))
    assert results[0] == results[1]


def test_without_the_mission_the_replay_is_not_reproduced_and_names_the_flag(mission_flight):
    d, _, _, without = mission_flight
    out = _replay(d / "flight.tlog", without)
    assert out.returncode == 1
    assert "--mission" in out.stderr.strip().splitlines()[-1], out.stderr[-500:]


def test_a_scenario_without_a_goal_replays_given_the_mission_and_is_refused_without(mission_flight):
    d, plan, _, without = mission_flight
    text = without.read_text()
    goalless = d / "goalless.toml"
    goalless.write_text("\n".join(line for line in text.splitlines() if not line.startswith("goal_ned_m")))
    out = _replay(d / "flight.tlog", goalless, "--mission", str(plan))
    assert out.returncode == 0, out.stderr[-1000:]
    s = json.loads(out.stdout)
    assert s["commands_compared"] == s["commands_recorded"] > 100 and s["max_abs_diff_mps"] == 0.0
    out = _replay(d / "flight.tlog", goalless)
    assert out.returncode == 2
    line = out.stderr.strip().splitlines()[-1]
    assert "goalless.toml [mission]: goal_ned_m is required" in line and "--mission" in line, out.stderr[-500:]
