"""A PX4 SITL flight recorded before the autopilot boundary replays exactly today (issue "One loop", Must show).

``tests/data/px4_encounter_before_boundary.tlog`` is the companion's tlog of the antipodal
encounter against PX4 SITL (SIH), flown with commit 60aaa9d (the last before the autopilot
boundary, the Driver and the loop's stages): ``python -m tests.px4.flight --runs 1`` there,
obstacles on an obstacle link, ``fly --arm --takeoff-alt 5 --exit-after-goal 1`` (1.08 MB;
kept here without the autopilot telemetry the companion never reads, 501 KB: ATTITUDE,
HIGHRES_IMU, VFR_HUD and the like; it replays the same with and without it).

That companion armed at the first HEARTBEAT. Today's listens ``[offboard]
autopilot_listen_s`` (1.5 s) first unless it is told its vehicle (``--target-system``), so the
replay is given ``--target-system 1`` as a flight flown today with it would be. Two ticks
differ in what they announced, not in what they commanded: the old companion said
"obstacles: 3 rejected ..." for reports before its clock was mapped, which today's keeps as
early reports (commit 6a2d573). It handed back one second after its goal wherever the
vehicle was; today's waits for the vehicle to settle at the goal unless ``[offboard]
goal_settle_max_s = 0``, which the replay's scenario sets as that flight had it. Its clock
mapping is set the same way (``[companion] vehicle_clock = "timesync_line"``, the mapping of
companions before 8 December 2026): today's differs by 0.013 m/s at most in this flight's commands.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from companion.loop.config import read_scenario_toml
from companion.offline.campaign.toml_writer import to_toml

REPO = Path(__file__).resolve().parents[2]
LOG = REPO / "tests" / "data" / "px4_encounter_before_boundary.tlog"
FLAGS = ["--arm", "--takeoff-alt", "5", "--exit-after-goal", "1", "--json"]


def _scenario(tmp_path: Path) -> Path:
    """configs/antipodal_px4.toml with the hand-back rule and the clock mapping of the flight's day
    (``goal_settle_max_s = 0``, ``vehicle_clock = "timesync_line"``)."""
    data = read_scenario_toml(REPO / "configs" / "antipodal_px4.toml")
    data["offboard"] = {**data.get("offboard", {}), "goal_settle_max_s": 0.0}
    data["companion"] = {**data["companion"], "vehicle_clock": "timesync_line"}
    path = tmp_path / "antipodal_px4.toml"
    path.write_text(to_toml(data))
    return path


def _replay(tmp_path: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "companion.cli", "replay", str(LOG), "--scenario", str(_scenario(tmp_path)),
                           *FLAGS, *extra], capture_output=True, text=True, cwd=REPO, timeout=300)


def test_the_pre_boundary_px4_flight_replays_every_command_exactly_with_its_flags(tmp_path):
    out = _replay(tmp_path, "--target-system", "1")
    assert out.returncode == 0, out.stderr[-1000:]
    s = json.loads(out.stdout)
    assert s["commands_compared"] == s["commands_recorded"] == 384
    assert s["unmatched_commands"] == 0 and s["max_abs_diff_mps"] == 0.0
    assert s["replans"] == 50
    assert s["tick_mismatches"] == 2          # the two "obstacles: N rejected" announcements


def test_without_the_vehicle_named_the_replay_says_it_was_not_reproduced_and_which_flag_to_give(tmp_path):
    out = _replay(tmp_path)
    assert out.returncode == 1
    line = out.stderr.strip().splitlines()[-1]
    assert line.startswith("companion replay: compared 0 of 384") and "--target-system" in line, out.stderr[-500:]
