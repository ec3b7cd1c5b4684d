"""The SITL flights' command line (:func:`tests.support.runs.fly_runs`): each run judged once, printed, tallied."""

from __future__ import annotations

import json

from tests.support.runs import fly_runs


def test_that_each_run_is_judged_once_printed_and_a_failed_run_fails_the_whole():
    judged = []

    def judge(r: dict) -> list[str]:
        judged.append(r["seed"])
        return [] if r["seed"] != 1 else ["too close"]

    assert fly_runs(lambda i: {"seed": i}, judge, 2) == 1
    assert judged == [0, 1]
    assert fly_runs(lambda i: {"seed": i}, judge, 1) == 0


def test_that_the_figures_and_the_tally_are_printed(capsys):
    fly_runs(lambda i: {"seed": i}, lambda r: [], 2)
    out = capsys.readouterr().out
    assert out.strip().endswith("passed 2 of 2")
    first = json.loads(out[:out.index("}") + 1])
    assert first == {"seed": 0, "failed": []}
