"""A live flight keeps only its latest replan records; its report still sums every replan
(companion.loop.records.ReplanTally): the same figures as from every record."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from companion.loop.records import ReplanTally, status_counts
from companion.offline.harness import run_lockstep
from companion.offline.report import companion_report

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "configs" / "antipodal.toml"


def test_that_the_tally_is_what_every_record_says():
    companion = run_lockstep(SCENARIO, seed=0).companion
    records, tally = list(companion.records), companion.tally
    assert tally.count == len(records) > 20
    assert tally.status_counts() == status_counts(r.status for r in records)
    planned = [r.planned_min_contour for r in records if math.isfinite(r.planned_min_contour)]
    assert tally.min_planned_contour == min(planned)
    assert list(tally.solve_times_s) == [r.solve_time_s for r in records]
    assert tally.min_peer_contour is None                 # no fleet here


def test_that_a_flight_keeping_five_records_reports_as_one_keeping_all():
    full = run_lockstep(SCENARIO, seed=0).companion
    kept = run_lockstep(SCENARIO, seed=0, replan_history=5).companion
    assert len(kept.records) == 5 and kept.tally.count == len(full.records)
    assert [r.t_link_s for r in kept.records] == [r.t_link_s for r in list(full.records)[-5:]]
    a, b = companion_report(full), companion_report(kept)
    timing = {"solve_time_median_ms", "solve_time_p99_ms"}     # wall time of each solve: differs run to run
    assert {k: v for k, v in a.items() if k not in timing} == {k: v for k, v in b.items() if k not in timing}
    assert b["solve_time_p99_ms"] == float(np.percentile(np.array(kept.tally.solve_times_s), 99) * 1e3)


def test_that_only_fleet_peers_count_for_the_peer_contour():
    class Record:
        status, planned_min_contour, solve_time_s = "optimal", math.nan, 0.001

        def __init__(self, realised):
            self.realised_contour = realised

    tally = ReplanTally()
    peer = lambda key: isinstance(key, tuple) and key[-1] == "fleet"   # noqa: E731
    tally.add(Record({(2, 191, "fleet"): 0.97, (9, 1, "obstacles1"): 0.5}), is_peer=peer)
    tally.add(Record({(2, 191, "fleet"): 0.95}), is_peer=peer)
    assert tally.min_peer_contour == 0.95 and tally.min_planned_contour is None
    assert tally.count == 2 and tally.status_counts() == {"optimal": 2}
