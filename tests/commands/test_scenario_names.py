"""Every command resolves a scenario the same way: a TOML path, or a shipped scenario's name."""

from __future__ import annotations

from pathlib import Path

import pytest

from companion.cli import main
from companion.commands._argtypes import shipped_scenarios


def test_that_every_shipped_scenario_is_named():
    assert {"antipodal", "antipodal_px4", "antipodal_px4sim", "corridor", "single_obstacle"} <= set(shipped_scenarios())


@pytest.mark.parametrize("name", ["single_obstacle", "single_obstacle.toml"])
def test_that_plan_takes_a_shipped_name(name, capsys):
    assert main(["plan", name, "--json"]) == 0
    assert '"status"' in capsys.readouterr().out


@pytest.mark.parametrize("argv", [["plan", "nosuch"], ["demo", "nosuch"], ["replay", "x.tlog", "--scenario", "nosuch"],
                                  ["fly", "--scenario", "nosuch"],
                                  ["identify", "x.tlog", "--write-scenario", "copy.toml", "--into", "nosuch"]])
def test_that_an_unknown_name_is_one_line_listing_the_shipped_ones(argv, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv)
    err = capsys.readouterr().err
    assert info.value.code == 2 and err.count("\n") == 1
    assert "nosuch: no such scenario file, and not a shipped scenario (antipodal, " in err and "antipodal_px4," in err


def test_that_mavsim_takes_a_shipped_name_as_companion_does(capsys):
    """``mavsim --scenario single_obstacle`` said "cannot read scenario file": a wheel user could
    not reach the shipped scenarios from mavsim (nor from ``mavsim traffic``, the same loader)."""
    import json

    from mavsim.cli import main as mavsim_main

    assert mavsim_main(["--scenario", "single_obstacle", "--lockstep", "--duration", "1", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["scenario"] == "single_obstacle"


@pytest.mark.parametrize("argv", [["--scenario", "nosuch", "--lockstep", "--duration", "1"],
                                  ["traffic", "--scenario", "nosuch", "--duration", "1"]])
def test_that_mavsim_names_the_shipped_scenarios_for_an_unknown_name(argv, capsys):
    from mavsim.cli import main as mavsim_main

    try:
        code = mavsim_main(argv)
    except SystemExit as exc:
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    # every shipped scenario, in order, and nothing else
    shipped = ", ".join(sorted(shipped_scenarios()))
    assert f"nosuch: no such scenario file, and not a shipped scenario ({shipped})" in err, err


def test_that_demo_single_obstacle_says_why_it_misses_its_goal(capsys):
    """``companion demo single_obstacle`` ended "goal reached False" with no reason given: the
    demo now prints the scenario's description, which says why and what reaches the goal."""
    # the file itself: a shipped name resolves to the installed copy, which may be another checkout's
    assert main(["demo", str(Path(__file__).resolve().parents[2] / "configs" / "single_obstacle.toml")]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert any(line.split() == ["goal", "reached", "False"] for line in lines)
    why = next(line for line in lines if line.startswith("the scenario says: "))
    assert "does not reach its goal" in why and "weight_progress = 0.05" in why


def test_that_a_demo_reaching_its_goal_prints_no_excuse(capsys):
    assert main(["demo", "tests/data/short_hop.toml"]) == 0
    out = capsys.readouterr().out
    assert "goal reached                                    True" in out and "the scenario says" not in out


def test_that_identify_into_takes_a_shipped_name(tmp_path, capsys):
    """``identify LOG --into antipodal`` said "antipodal: scenario file not found"."""
    from companion.loop.config import load_scenario

    log = Path(__file__).resolve().parents[2] / "tests" / "data" / "px4_steps.tlog"
    copy = tmp_path / "antipodal_identified.toml"
    assert main(["identify", str(log), "--into", "antipodal", "--write-scenario", str(copy)]) == 0
    assert f"scenario: {copy} (a copy of " in capsys.readouterr().out
    assert load_scenario(copy).name == "antipodal"
