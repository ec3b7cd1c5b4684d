"""``companion replay`` says when it did not reproduce its recording, and exits 1 (not 0)."""

from __future__ import annotations

from pathlib import Path

import pytest

from companion.cli import main
from companion.offline.harness import run_lockstep

ROOT = Path(__file__).resolve().parents[2]
SHORT_HOP = ROOT / "tests" / "data" / "short_hop.toml"


@pytest.fixture(scope="module")
def short_hop_log(tmp_path_factory) -> Path:
    log = tmp_path_factory.mktemp("replay_exit") / "short_hop.tlog"
    run_lockstep(SHORT_HOP, seed=0, tlog_path=log)
    return log


def test_that_a_faithful_replay_exits_0(short_hop_log, capsys):
    assert main(["replay", str(short_hop_log), "--scenario", str(SHORT_HOP)]) == 0
    assert "companion replay:" not in capsys.readouterr().err


def test_that_a_replay_with_another_scenario_is_not_called_a_success(short_hop_log, capsys):
    code = main(["replay", str(short_hop_log), "--scenario", str(ROOT / "configs" / "antipodal.toml")])
    err = capsys.readouterr().err
    assert code == 1
    assert "companion replay: not reproduced:" in err and "give the replay the scenario and the flags the flight used" in err


def test_that_a_replay_comparing_no_command_says_which_flags_it_needs(short_hop_log, capsys, tmp_path):
    # a scenario naming another vehicle (system 9): the replayed companion never streams
    other = tmp_path / "other_vehicle.toml"
    other.write_text(SHORT_HOP.read_text() + "\n[offboard]\ntarget_system = 9\n")
    code = main(["replay", str(short_hop_log), "--scenario", str(other)])
    err = capsys.readouterr().err
    assert code == 1, err
    assert "compared 0 of" in err and "--takeoff-alt" in err


def test_that_replay_times_count_from_the_log_start_not_the_clock_epoch(short_hop_log, capsys):
    import json

    assert main(["replay", str(short_hop_log), "--scenario", str(SHORT_HOP), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert 0.0 < summary["goal_reached_t_s"] < summary["log_duration_s"]
    assert all(0.0 <= t <= summary["log_duration_s"] for t, _ in summary["events"])


def test_that_a_real_time_log_replayed_without_the_flights_flags_exits_1_naming_them(capsys, tmp_path):
    """The issue's case: a flight flown with ``--exit-after-goal`` (here ``demo --realtime``'s fly),
    replayed without it, was called a success. Now exit 1, and the line names the flags to give.
    The scenario maps the autopilot's clock as the flight's companion did (before 8 December 2026)."""
    from tests.offline.test_replay_before_marks import short_hop_of_its_day

    log = ROOT / "tests" / "data" / "realtime_before_marks.tlog"
    scenario = short_hop_of_its_day(tmp_path)
    assert main(["replay", str(log), "--scenario", str(scenario)]) == 1
    last = capsys.readouterr().err.splitlines()[-1]
    assert last.startswith("companion replay: not reproduced: 140 of 140 recorded commands compared")
    assert last.endswith("give the replay the scenario and the flags the flight used "
                         "(--arm, --takeoff-alt, --exit-after-goal, --formulation, --target-system, --goal or "
                         "--mission, --fence)")
    assert main(["replay", str(log), "--scenario", str(scenario), "--exit-after-goal", "1"]) == 0
