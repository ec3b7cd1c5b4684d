"""Plan arrivals, lost plans and signature counts are tlog marks, never packets (issue "One loop", item 3).

``run_realtime`` on a virtual clock against a scripted PX4 (:mod:`tests.support.scripted_realtime`):
a planning service that answers some ticks late and loses one job in four, a link that
rejects a signature every half second. What the companion sends on the autopilot link must
carry none of the replay's bookkeeping; the tlog must, as marks; and the replay must
reproduce every command and every announcement from the marks alone.
"""

from __future__ import annotations

from collections import Counter

from pymavlink.dialects.v20 import common as mavlink2

from companion.loop.plan_cycle import PlanArrival
from companion.loop.supervisor import SIGNATURE_TEXT
from companion.realtime.tlog_marks import PLAN_IN, PLAN_LOST, SIGNATURES_REJECTED, TICK, TlogMarks, mark_of
from companion.mavlink.tlog import TlogWriter, read_tlog
from companion.offline.replay import replay
from tests.support import scripted_realtime


def test_that_the_wire_carries_no_plan_bookkeeping_and_the_tlog_marks_it_for_an_exact_replay(tmp_path):
    path = tmp_path / "companion.tlog"
    companion, link = scripted_realtime.record(path)
    assert len(companion.records) >= 10 and companion.sequencer.phase.name == "ENGAGED"

    # the wire: no NAMED_VALUE_FLOAT plan_seq / plan_lost, no marks; the operator's STATUSTEXT stays
    sent = Counter(m.get_type() for _, m in link.sent)
    named = {m.name for _, m in link.sent if m.get_type() == "NAMED_VALUE_FLOAT"}
    assert not named & {"plan_seq", "plan_lost"} and sent["NAMED_VALUE_INT"] == 0, sent
    texts = [m.text for _, m in link.sent if m.get_type() == "STATUSTEXT" and m.text.startswith(SIGNATURE_TEXT)]
    assert texts == [f"{SIGNATURE_TEXT}1 rejected)", f"{SIGNATURE_TEXT}11 rejected)"]

    # the tlog: every arrival and loss, and the signature count each time it changed
    marks = [mark_of(m) for _, m in read_tlog(path) if m.get_srcComponent() == 191]
    marks = [m for m in marks if m is not None]
    arrived = [v for name, v in marks if name == PLAN_IN]
    lost = [v for name, v in marks if name == PLAN_LOST]
    counts = [v for name, v in marks if name == SIGNATURES_REJECTED]
    assert arrived and lost and sorted(arrived + lost) == list(range(len(arrived) + len(lost)))
    assert all(seq % 4 == 3 for seq in lost) and len(arrived) == len(companion.records)
    assert counts == list(range(1, link.stats.signature_rejected + 1))

    res = replay(path, scripted_realtime.SCENARIO)
    assert any("marked their arrival" in note for note in res.notes), res.notes
    assert res.commands_compared == res.commands_recorded == len([1 for _, m in link.sent if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"])
    assert res.unmatched_commands == 0 and res.tick_mismatches == 0 and res.max_abs_diff_mps == 0.0
    assert len(res.companion.records) == len(companion.records)
    assert res.companion.state.events == companion.state.events  # the signature announcements too, from the marks


def test_that_a_tick_is_marked_first_then_its_signature_count_when_changed_then_its_plans(tmp_path):
    path = tmp_path / "marks.tlog"
    with TlogWriter(path) as tlog:
        marks = TlogMarks(tlog, (1, 191))
        marks.tick(1.0, 0)
        marks.plans(1.0, ())
        marks.tick(1.05, 3)
        marks.plans(1.05, (PlanArrival(4), PlanArrival(5, lost=True)))
        marks.tick(1.1, 3)
    records = list(read_tlog(path))
    assert [(round(t, 2), mark_of(m)) for t, m in records] == [
        (1.0, (TICK, 0)), (1.05, (TICK, 0)), (1.05, (SIGNATURES_REJECTED, 3)), (1.05, (PLAN_IN, 4)),
        (1.05, (PLAN_LOST, 5)), (1.1, (TICK, 0))]
    assert all(m.get_type() == "NAMED_VALUE_INT" and (m.get_srcSystem(), m.get_srcComponent()) == (1, 191)
               for _, m in records)
    # a NAMED_VALUE_FLOAT of the same name (an old log's wire note) is not a mark
    assert mark_of(mavlink2.MAVLink_named_value_float_message(0, b"plan_lost", 5.0)) is None
