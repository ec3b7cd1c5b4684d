"""The fault campaign (tests/support/fault_campaign.py): every lockstep fault of docs/FAULTS.md on
20 seeds. Not in the default suite (marker ``faults``, about 3 minutes): ``make fault-campaign``."""

from __future__ import annotations

import logging

import pytest

from tests.support.fault_campaign import FAULTS, run_campaign, summarise

pytestmark = pytest.mark.faults

RUNS = 20


def test_that_every_fault_on_twenty_seeds_keeps_the_defined_behaviour():
    logging.disable(logging.WARNING)
    try:
        rows = run_campaign(RUNS)
    finally:
        logging.disable(logging.NOTSET)
    table = {line["fault"]: line for line in summarise(rows)}
    assert sorted(table) == sorted(case.name for case in FAULTS)
    retakes = {case.name for case in FAULTS if case.reengage}     # --reengage: asks for OFFBOARD again, by design
    for name, line in table.items():
        assert line["runs"] == RUNS
        assert line["collisions_in_control"] == 0, line
        assert line["outcome_as_documented"] == RUNS, line
        if name not in retakes:
            assert line["setpoints_after_seen"] == 0 and line["mode_requests_after_left"] == 0, line
        else:
            assert line["collisions"] == 0, line
        assert line["stale_frame_ticks"] == 0, line
