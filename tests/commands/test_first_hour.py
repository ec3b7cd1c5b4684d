"""The first hour of a new user: resource and validation holes of the ``companion`` command line.

Each test pins one hole of the issue "The first hour of a new user" by the exit code and
the one line the user sees (through :func:`companion.cli.main`, in process).
"""

from __future__ import annotations

import os

import pytest

from companion.cli import main as companion_main
from tests.commands.test_bad_input import ROOT, assert_one_line, edited, run_companion, scenario

CPUS = os.cpu_count() or 1


# --- campaign: bounded workers, episodes and duration; errored runs exit non-zero ------------------

@pytest.mark.parametrize(
    ("argv", "line"),
    [
        (["--workers", "100000"],
         f"companion campaign: error: argument --workers: must be an integer from 1 to {4 * CPUS} "
         f"(4 per CPU, {CPUS} CPUs), got 100000 (see --help)"),
        (["--workers", "0"],
         f"companion campaign: error: argument --workers: must be an integer from 1 to {4 * CPUS} "
         f"(4 per CPU, {CPUS} CPUs), got 0 (see --help)"),
        (["--episodes", "1000000000000"],
         "companion campaign: error: argument --episodes: must be an integer from 1 to 100000 "
         "(the most one campaign holds), got 1000000000000 (see --help)"),
        (["--episode", "100000"],
         "companion campaign: error: argument --episode: must be an integer from 0 to 99999, got 100000 (see --help)"),
        (["--duration", "1e308"],
         "companion campaign: error: argument --duration: must be > 0 s and at most 3600 s (one hour), "
         "got 1e308 (see --help)"),
        (["--duration", "3601"],
         "companion campaign: error: argument --duration: must be > 0 s and at most 3600 s (one hour), "
         "got 3601 (see --help)"),
    ],
    ids=["workers-huge", "workers-0", "episodes-huge", "episode-index", "duration-1e308", "duration-over-an-hour"],
)
def test_that_campaign_sizes_are_bounded_with_one_line(capsys, argv, line):
    code, err = run_companion(capsys, ["campaign", *argv])
    assert_one_line(code, err)
    assert err == line + "\n"


def test_that_run_campaign_itself_refuses_what_the_command_line_refuses():
    from companion.errors import InputError
    from companion.offline.campaign import run_campaign

    with pytest.raises(InputError, match="workers = 100000 must be from 1 to"):
        run_campaign("antipodal", [0], ["hyperplane"], 0, workers=100_000)
    with pytest.raises(InputError, match="duration_s = 1e.308 must be > 0 and at most 3600 s"):
        run_campaign("antipodal", [0], ["hyperplane"], 0, duration_s=1e308)
    with pytest.raises(InputError, match="at most 100000 episodes"):
        run_campaign("antipodal", range(100_001), ["hyperplane"], 0)


def test_that_campaign_help_shows_each_default_once_and_the_limits(capsys):
    with pytest.raises(SystemExit):
        companion_main(["campaign", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "(default: None)" not in out and "(default: False)" not in out
    assert f"local worker processes, at most 4 per CPU ({4 * CPUS} here) (default: the CPU count, {CPUS})" in out
    assert "number of episodes (indices 0..N-1), at most 100000 (default: 20)" in out
    assert "simulated seconds per episode, at most 3600 (default: 40.0)" in out
    assert "``" not in out


def test_that_a_campaign_whose_runs_errored_exits_1_saying_how_many(tmp_path, capsys, monkeypatch):
    import companion.offline.campaign.run as campaign_run

    def broken(*args, **kwargs):
        raise RuntimeError("scenario\ngenerator broke")

    monkeypatch.setattr(campaign_run, "generate_scenario", broken)
    results = tmp_path / "runs.jsonl"
    code = companion_main(["campaign", "--episodes", "2", "--methods", "hyperplane,paper", "--workers", "1",
                           "--progress", "off", "--results", str(results)])
    captured = capsys.readouterr()
    assert code == 1
    assert captured.err.splitlines()[-1] == (
        "companion campaign: error: 4 of 4 runs ended with an error (first: episode 0 hyperplane: "
        f"RuntimeError: scenario generator broke); the runs are in {results}")
    assert "4 run(s) ended with an error" in captured.out
    assert "Traceback" not in captured.err
    assert len(results.read_text().splitlines()) == 1 + 4  # the header and the four errored runs


# --- physically wrong scenario values --------------------------------------------------------------

@pytest.mark.parametrize(
    ("old", "new", "line"),
    [
        ("goal_ned_m = [24.0, 0.0, -5.0]", "goal_ned_m = [24, 0, 5]",
         "[mission]: goal_ned_m = [24.0, 0.0, 5.0] is 5 m below the local origin (NED: z is down, so z > 0 is under "
         "the ground at home); z must be at most 0.5 (e.g. -5 for 5 m up)"),
        ("step_s = 0.3 ", "step_s = 300 ", "[planner]: step_s = 300 must be at most 5 s"),
        ("replan_period_s = 0.3 ", "replan_period_s = 6.0 ", "[planner]: replan_period_s = 6.0 must be at most 5 s"),
        ("velocity_max_mps = [3.0, 3.0, 1.0]", "velocity_max_mps = [300.0, 3.0, 1.0]",
         "[planner]: velocity_max_mps = [300.0, 3.0, 1.0] must be at most 30 m/s on every axis (a multirotor's)"),
        ("accel_max_mps2 = [0.5, 0.5, 0.5]", "accel_max_mps2 = [0.5, 25, 0.5]",
         "[planner]: accel_max_mps2 = [0.5, 25, 0.5] must be at most 20 m/s^2 on every axis (a multirotor's)"),
        ("accel_max_mps2 = [0.5, 0.5, 0.5]", "accel_max_mps2 = [0.5, 0.5, 0.5]\naccel_emergency_mps2 = 40.0",
         "[planner]: accel_emergency_mps2 = 40.0 must be at most 20 m/s^2 on every axis (a multirotor's)"),
    ],
    ids=["goal-underground", "step-300", "replan-6", "speed-300", "accel-25", "emergency-accel-40"],
)
@pytest.mark.parametrize("command", ["plan", "demo"])
def test_that_physically_wrong_values_are_one_line_with_the_range(tmp_path, capsys, old, new, line, command):
    path = scenario(tmp_path, edited(old, new))
    argv = ["plan", str(path)] if command == "plan" else ["demo", str(path), "--out", str(tmp_path / "out")]
    code, err = run_companion(capsys, argv)
    assert_one_line(code, err)
    assert err == f"companion {command}: error: {path} {line}\n"


def test_that_a_goal_at_most_half_a_metre_below_the_origin_is_accepted(tmp_path, capsys):
    path = scenario(tmp_path, edited("goal_ned_m = [24.0, 0.0, -5.0]", "goal_ned_m = [24.0, 0.0, 0.5]"))
    from companion.loop.config import load_scenario

    assert load_scenario(path).mission.goal[2] == 0.5


@pytest.mark.parametrize(
    ("old", "new", "needle"),
    [
        ("goal_ned_m = [24.0, 0.0, -5.0]", "goal_ned_m = [24, 0, 5]",
         "[mission] goal_ned_m: z = 5 is below the ground at the local origin (NED, z down); must be at most 0.5"),
        ("accel_max_mps2 = 4.0", "accel_max_mps2 = 400.0", "[sim] accel_max_mps2: must be <= 20.0, got 400.0"),
    ],
)
def test_that_mavsim_refuses_a_goal_under_the_ground_and_a_rocket(tmp_path, capsys, old, new, needle):
    from tests.commands.test_bad_input import run_mavsim

    path = scenario(tmp_path, edited(old, new))
    assert_one_line(*run_mavsim(capsys, ["--scenario", str(path), "--lockstep", "--duration", "1"]), str(path), needle)


def test_that_both_programs_bound_the_goal_alike():
    from companion.loop import config as companion_config
    from companion.core.planner import config as planner_config
    from mavsim import scenario as mavsim_scenario

    assert companion_config.GOAL_BELOW_ORIGIN_MAX_M == mavsim_scenario.GOAL_BELOW_ORIGIN_MAX_M
    assert planner_config.MAX_ACCEL_MPS2 == mavsim_scenario.MAX_ACCEL_MPS2


@pytest.mark.parametrize("path", sorted((ROOT / "configs").glob("*.toml")), ids=lambda p: p.name)
def test_that_every_shipped_scenario_still_loads_in_both_programs(path):
    from companion.offline.scenario_file import load_both

    load_both(path)


# --- the campaign table counts what its columns say ---------------------------------------------------

def _score(**values):
    import dataclasses

    from companion.offline.campaign import EpisodeScore

    neutral = {f.name: 0 for f in dataclasses.fields(EpisodeScore)}
    lists = {"drone_nees": [], "relative_nees": [], "model_step_error_m": [], "solve_times_s": [0.01],
             "promise_pairs": [], "promise_hits": [], "promise_sum": []}
    return EpisodeScore(**{**neutral, **lists, "truth": {}, **values})


def test_that_a_contact_between_replans_shows_as_a_hit_episode_with_no_step_hits():
    """The 20-episode campaign printed 'coll 1' beside 'step freq 0.00e+00': the episode
    count is of contacts at any physics step, the frequency of contacts at replan instants."""
    from companion.offline.campaign import CampaignResult, EpisodeResult, format_table, summarise

    rows = [EpisodeResult(episode=i, method="deterministic", family="antipodal", seed=0, sim_seed=i,
                          score=_score(collided=i == 0, obstacle_collision=i == 0, collisions=int(i == 0),
                                       steps=100, pair_steps_in_range=50, goal_reached=True))
            for i in range(3)]
    result = CampaignResult("antipodal", 0, (0, 1, 2), ("deterministic",), 0.9, 40.0, tuple(rows),
                            summarise(rows, ["deterministic"], 0.9), 1.0, 1)
    table = format_table(result).splitlines()
    head = table[1].split()
    assert head[:7] == ["method", "eps", "hit", "eps", "rate", "[95%", "CI]"] and "step" in head and "hits" in head
    row = table[3].split()
    assert row[:3] == ["deterministic", "3", "1"]       # one episode with a true contact
    assert row[6] == "0" and row[7] == "0.00e+00"       # ... never at a replan instant
    assert ("deterministic: 1 episode(s) with a true contact (1 with an obstacle), 1 of them in contact at no replan "
            "instant (a contact between two replans, or with a wall): in hit eps, not in step hits") in table
    assert any(line.startswith("(hit eps: episodes with a true contact at any physics step") for line in table)


# --- help texts -----------------------------------------------------------------------------------------

@pytest.mark.parametrize("command", ["campaign", "demo", "fly", "identify", "overlap", "plan", "reliability", "replay"])
def test_that_help_is_plain_text_without_none_defaults(capsys, command):
    with pytest.raises(SystemExit) as info:
        companion_main([command, "--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert "`" not in out, out
    assert "(default: None)" not in out and "(default: False)" not in out


def test_that_plan_help_keeps_its_paragraphs_without_markup(capsys):
    with pytest.raises(SystemExit):
        companion_main(["plan", "--help"])
    out = capsys.readouterr().out
    assert "companion plan: one trajectory optimisation with the obstacles' motion known.\n\n" in out
    assert "taken from the scenario file's [[world.obstacles]] (which" in out


# --- the real-time demo: a bad signing key, a child that failed ----------------------------------------

@pytest.mark.parametrize("content", ["not a key\n", None], ids=["not-hex", "missing"])
def test_that_a_realtime_demo_with_a_bad_signing_key_is_one_line_before_anything_starts(tmp_path, capsys, content):
    """It printed only its counters and exited 0: the key is now read by ``demo`` itself."""
    key = tmp_path / "BAD"
    if content is not None:
        key.write_text(content)
        os.chmod(key, 0o600)
    code, err = run_companion(capsys, ["demo", "--realtime", "--signing-key-file", str(key), "--out", str(tmp_path / "o")])
    assert_one_line(code, err)
    assert err.startswith(f"companion demo: error: {key}: ")
    assert ("64 hexadecimal digits" if content else "cannot read signing key") in err
    assert not (tmp_path / "o" / "companion.tlog").exists()


def test_that_a_realtime_demo_whose_fly_failed_exits_1_saying_so(tmp_path, capsys, monkeypatch):
    import companion.commands.demo as demo

    monkeypatch.setattr(demo, "_run_realtime", lambda *a, **k: {
        "mode": "realtime", "fly_error": "Traceback (most recent call last):\n  ...\nRuntimeError: planner died\n"})
    code, err = run_companion(capsys, ["demo", "--realtime", "--out", str(tmp_path / "o")])
    assert code == 1
    assert err == "companion demo: error: companion fly failed: RuntimeError: planner died\n"


# --- fly's text summary leads with how the run ended ------------------------------------------------

def test_that_the_fly_summary_leads_with_the_outcome_goal_clearance_and_mode(tmp_path):
    """The summary had no goal, clearance or final-mode line, and counted a stale estimate under
    "failsafe events"; with no autopilot, fly was silent for 25 s. With no autopilot for 5.5 s:
    one line saying so after 5 s, exit 6, the outcome first, counters named (about 8 s)."""
    import socket
    import subprocess
    import sys

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    run = subprocess.run([sys.executable, "-m", "companion.cli", "fly", "--connect", f"udpin:127.0.0.1:{port}",
                          "--scenario", str(ROOT / "tests" / "data" / "short_hop.toml"), "--duration", "5.5"],
                         capture_output=True, text=True, timeout=60, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert run.returncode == 6, run.stderr[-2000:]
    assert "Traceback" not in run.stderr
    assert run.stderr == (f"companion fly: no autopilot heard on udpin:127.0.0.1:{port} after 5 s "
                          "(is it sending to this port? Ctrl-C stops)\n")
    labels = [line[:48].rstrip() for line in run.stdout.splitlines()]
    assert labels[:5] == ["outcome", "stop requested by", "goal reached at [s] (companion's estimate)",
                          "smallest clearance to a track, estimated [m]", "autopilot's last mode"]
    assert run.stdout.splitlines()[0].split(None, 1)[1] == "link lost"
    assert "stale-estimate events" in labels and not any("failsafe" in label for label in labels)


@pytest.mark.parametrize("command", ["fly", "demo", "replay"])
def test_that_formulation_help_lists_its_choices(capsys, command):
    """``fly --formulation`` listed no choices."""
    with pytest.raises(SystemExit):
        companion_main([command, "--help"])
    assert "--formulation {hyperplane,paper,deterministic,bhattacharyya}" in capsys.readouterr().out
