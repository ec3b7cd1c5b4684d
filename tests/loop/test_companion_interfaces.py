"""The Companion's seams: an injected sequencer, one decoder for every inbound message, typed records."""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink2

from companion.loop.app import Companion
from companion.loop.config import load_scenario
from companion.loop.records import LoopMode, PlanStatus, status_counts
from companion.mavlink.offboard import OffboardSequencer
from tests.support.inbound import px4_heartbeat, received


class _Recording(OffboardSequencer):
    def __init__(self):
        super().__init__()
        self.home: list[float] = []

    def on_home_altitude(self, alt_amsl_m: float) -> None:
        self.home.append(alt_amsl_m)


def _home(alt_mm: int):
    return mavlink2.MAVLink_home_position_message(0, 0, alt_mm, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0)


def test_that_the_injected_sequencer_gets_the_autopilots_home_altitude_and_no_one_elses():
    seq = _Recording()
    companion = Companion(load_scenario("configs/antipodal.toml"), sequencer=seq)
    companion.handle(received(_home(12_000)))  # before the autopilot is known: ignored
    companion.handle(received(px4_heartbeat()))
    companion.handle(received(_home(488_500)))
    companion.handle(received(_home(1_000), src=(7, 1)))  # another system's home
    assert companion.sequencer is seq and companion.autopilot == (1, 1)
    assert seq.home == [488.5]


def test_that_the_loop_starts_waiting_and_idles_without_a_stream():
    companion = Companion(load_scenario("configs/antipodal.toml"))
    assert companion.state.mode is LoopMode.WAITING
    out = companion.tick(0.0)
    assert [m.get_type() for m in out] == ["HEARTBEAT"]
    assert companion.state.mode is LoopMode.WAITING


def test_that_plan_statuses_are_counted_once_by_their_enum():
    counts = status_counts([PlanStatus.SLACK, "optimal", PlanStatus.OPTIMAL, PlanStatus.FAILED])
    assert counts == {"optimal": 2, "slack": 1, "failed": 1}
    assert list(counts) == ["optimal", "slack", "failed"]
    assert PlanStatus.FAILED == "failed"
