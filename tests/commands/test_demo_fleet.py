"""``companion demo SCENARIO --drones N``: a fleet in lockstep, from the command line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from companion.cli import main

ROOT = Path(__file__).resolve().parents[2]
SWAP = str(ROOT / "configs" / "swap.toml")


def test_that_two_drones_swap_and_the_summary_says_so(tmp_path, capsys):
    assert main(["demo", SWAP, "--drones", "2", "--json", "--out", str(tmp_path)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["drones"] == 2 and summary["coordination"] == "distributed"
    assert summary["goal_reached"] and not summary["collided"]
    assert summary["min_peer_realised_contour"] >= summary["c_min"]
    assert json.loads((tmp_path / "summary.json").read_text())["drones"] == 2


@pytest.mark.parametrize("argv, words", [
    (["--drones", "17"], "2 to 16"),
    (["--drones", "2", "--realtime", "--crowd", "5"], "not available with --drones"),
    (["--drones", "0"], "--drones"),
])
def test_that_a_fleet_it_cannot_fly_is_one_line_and_exit_2(argv, words, capsys):
    with pytest.raises(SystemExit) as info:
        code = main(["demo", SWAP, *argv])
        raise SystemExit(code)
    err = capsys.readouterr().err.strip()
    assert info.value.code == 2 and words in err and len(err.splitlines()) == 1
