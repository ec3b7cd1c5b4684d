"""The one driver (:mod:`companion.loop.driver`): what each receive, tick and hand-back sends and records, in order."""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink2

from companion.loop.app import Companion
from companion.loop.config import load_scenario
from companion.loop.driver import Driver
from companion.mavlink.link import Received

SCENARIO = "tests/data/short_hop.toml"
_PX4 = mavlink2.MAVLink(None, 1, 1)


def _rx(msg, t_s: float) -> Received:
    raw = bytes(msg.pack(_PX4))
    return Received(t_s, _PX4.parse_buffer(raw)[0], raw)


def _heartbeat(t_s: float) -> Received:
    return _rx(mavlink2.MAVLink_heartbeat_message(2, 12, 157 | 128, 6 << 16, 4, 3), t_s)


def _position(t_s: float) -> Received:
    return _rx(mavlink2.MAVLink_local_position_ned_message(int(round(t_s * 1000)), 0.0, 0.0, -5.0, 0.0, 0.0, 0.0), t_s)


class _Port:
    def __init__(self) -> None:
        self.sent: list = []

    def send(self, msg, t_s: float) -> bytes:
        self.sent.append((t_s, msg.get_type()))
        return msg.get_type().encode()


class _Recorder:
    def __init__(self) -> None:
        self.events: list = []

    def received(self, rx) -> None:
        self.events.append(("rx", rx.t_s, rx.msg.get_type()))

    def sent(self, t_s, packet) -> None:
        self.events.append(("sent", t_s, packet))

    def tick(self, t_s, signatures_rejected) -> None:
        self.events.append(("tick", t_s, signatures_rejected))

    def plans(self, t_s, arrivals) -> None:
        self.events.append(("plans", t_s, tuple(arrivals)))

    def hand_back(self, t_s, reason) -> None:
        self.events.append(("hand_back", t_s, reason))


def _driver(recorder=None):
    companion = Companion(load_scenario(SCENARIO))
    port = _Port()
    return Driver(companion, port, recorder), port, companion


def test_that_an_autopilot_timesync_request_is_answered_at_its_receive_time_and_recorded_after_it():
    recorder = _Recorder()
    driver, port, _ = _driver(recorder)
    driver.receive(_heartbeat(1.0))
    answers = driver.receive(_rx(mavlink2.MAVLink_timesync_message(0, 123_000_000), 1.25))
    assert [m.get_type() for m in answers] == ["TIMESYNC"]
    assert port.sent == [(1.25, "TIMESYNC")]
    assert recorder.events == [("rx", 1.0, "HEARTBEAT"), ("rx", 1.25, "TIMESYNC"), ("sent", 1.25, b"TIMESYNC")]


def test_that_a_tick_records_its_mark_and_plans_before_its_packets_and_counts_setpoints():
    recorder = _Recorder()
    driver, port, _ = _driver(recorder)
    driver.receive(_heartbeat(0.0))
    for k in range(40):
        t = 0.05 * k
        driver.receive(_position(t))
        n_sent = len(port.sent)
        outbox = driver.tick(t, signatures_rejected=3)
        assert port.sent[n_sent:] == [(t, m.get_type()) for m in outbox]  # stamped with the tick time
        assert driver.streamed == (bool(outbox) and outbox[-1].get_type() == "SET_POSITION_TARGET_LOCAL_NED")
    assert driver.ticks == 40 and 0 < driver.setpoints <= 40
    ticks = [i for i, ev in enumerate(recorder.events) if ev[0] == "tick"]
    for i in ticks:  # tick, plans, then that tick's packets
        assert recorder.events[i][2] == 3 and recorder.events[i + 1][0] == "plans"


class _StubCompanion:
    """What the driver calls, counted: a hand-back always starts; ticks send nothing."""

    def __init__(self) -> None:
        self.hand_backs: list = []
        self.signatures: list = []
        self.plan_arrivals = ()

    def hand_back(self, t_s, reason) -> bool:
        self.hand_backs.append((t_s, reason))
        return True

    def on_signatures_rejected(self, total) -> None:
        self.signatures.append(total)

    def tick(self, t_s) -> list:
        return []


def test_that_hand_backs_from_outside_are_recorded_once_after_the_tick():
    recorder, companion = _Recorder(), _StubCompanion()
    driver = Driver(companion, _Port(), recorder)
    driver.tick(1.0)
    companion.hand_back(1.0, "stopped (SIGINT)")  # as a stop callback (RunEnd) does, without the driver
    driver.mark_hand_backs()
    driver.mark_hand_backs()
    assert driver.hand_back(1.05, "stopped") is True
    assert [ev for ev in recorder.events if ev[0] == "hand_back"] == [("hand_back", 1.0, "stopped (SIGINT)"),
                                                                     ("hand_back", 1.05, "stopped")]
    assert not driver.streamed and driver.setpoints == 0


def test_that_a_signature_count_is_handed_in_only_when_reported():
    companion = _StubCompanion()
    driver = Driver(companion, _Port())
    driver.tick(0.0)                          # lockstep: nothing reported
    driver.tick(0.05, signatures_rejected=0)  # real time and marked replays: always
    driver.tick(0.1, signatures_rejected=2)
    assert companion.signatures == [0, 2] and driver.ticks == 3
