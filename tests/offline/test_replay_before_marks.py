"""Logs recorded before the plan and signature marks still replay exactly (issue "One loop", item 3).

Until the plan arrivals, lost plans and signature counts became tlog marks
(:mod:`companion.realtime.tlog_marks`), the companion sent them on the autopilot link:
NAMED_VALUE_FLOAT ``plan_seq`` / ``plan_lost`` in the tick that collected a plan, and the
signature count only in its STATUSTEXT. Today's companion sends neither NAMED_VALUE_FLOAT,
so the replay takes them out of the recorded ticks, applies each plan where they say, and
reads the count from the STATUSTEXT. Two logs recorded with the code from before the
change (commit dba2e14):

- ``tests/data/realtime_before_marks.tlog``: ``companion demo tests/data/short_hop.toml
  --realtime --out ...`` (mavsim and ``companion fly`` over loopback UDP, the planner in its
  own process; the companion's tlog, 130 KB), replayed with the clock mapping of its day
  (``[companion] vehicle_clock = "timesync_line"``: today's maps mavsim's clock a fraction of a
  millisecond differently, and the flight's plans differ from the first that does);
- ``tests/data/scripted_before_marks.tlog``: :func:`tests.support.scripted_realtime.record`
  (run_realtime on a virtual clock against a scripted PX4, one job in four lost, a
  signature rejected every half second; 19 KB).
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from pathlib import Path

from companion.loop.config import load_scenario
from companion.loop.supervisor import SIGNATURE_TEXT
from companion.mavlink.tlog import read_tlog
from companion.offline.replay import replay
from tests.support import scripted_realtime

DATA = Path(__file__).resolve().parents[1] / "data"
SHORT_HOP = DATA / "short_hop.toml"


def short_hop_of_its_day(tmp_path: Path) -> Path:
    """SHORT_HOP with the autopilot's clock mapped as companions before 8 December 2026 did
    (``[companion] vehicle_clock = "timesync_line"``): the clock mapping of the day these logs were flown."""
    path = tmp_path / "short_hop_timesync_line.toml"
    path.write_text(SHORT_HOP.read_text() + '\n[companion]\nvehicle_clock = "timesync_line"\n')
    return path


def _bookkeeping(path: Path) -> Counter:
    """The companion's NAMED_VALUE_FLOAT / NAMED_VALUE_INT in a tlog, by (type, name)."""
    return Counter((m.get_type(), m.name) for _, m in read_tlog(path)
                   if m.get_type() in ("NAMED_VALUE_FLOAT", "NAMED_VALUE_INT") and m.get_srcComponent() == 191)


def test_that_a_realtime_log_from_before_the_marks_replays_every_command_exactly(tmp_path):
    path = DATA / "realtime_before_marks.tlog"
    kinds = _bookkeeping(path)
    assert kinds[("NAMED_VALUE_FLOAT", "plan_seq")] == 15 and kinds[("NAMED_VALUE_INT", "plan_in")] == 0  # the old format
    offboard = dataclasses.replace(load_scenario(SHORT_HOP).offboard, hold_after_goal_s=1.0)  # demo --realtime: fly --exit-after-goal 1
    res = replay(path, short_hop_of_its_day(tmp_path), offboard=offboard)
    assert res.mode == "compare"
    assert any("before the plan marks" in note for note in res.notes), res.notes
    assert res.commands_compared == res.commands_recorded == 140
    assert res.unmatched_commands == 0 and res.tick_mismatches == 0  # the plan_seq notes are not compared
    assert res.max_abs_diff_mps == 0.0
    assert len(res.companion.records) == 14  # every announced plan applied but the last (back after the hand-back to Hold)


def test_that_an_old_log_with_lost_plans_and_signature_rejections_replays_exactly():
    path = DATA / "scripted_before_marks.tlog"
    kinds = _bookkeeping(path)
    assert kinds[("NAMED_VALUE_FLOAT", "plan_seq")] == 15 and kinds[("NAMED_VALUE_FLOAT", "plan_lost")] == 5
    assert kinds[("NAMED_VALUE_INT", "sig_reject")] == 0
    res = replay(path, scripted_realtime.SCENARIO)
    assert res.commands_compared == res.commands_recorded == 120
    assert res.unmatched_commands == 0 and res.tick_mismatches == 0 and res.max_abs_diff_mps == 0.0
    assert len(res.companion.records) == 15  # lost jobs dropped at their tick, the rest applied
    # the count came from the recorded STATUSTEXT: announced again at the same ticks with the same count
    said = [(round(t, 3), text) for t, text in res.companion.state.events if text.startswith(SIGNATURE_TEXT)]
    assert said == [(0.35, f"{SIGNATURE_TEXT}1 rejected)"), (5.35, f"{SIGNATURE_TEXT}11 rejected)")]
