"""The mission protocol's download and upload machines against a scripted vehicle: order, retries, failures."""

from __future__ import annotations

import io

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink.mission_protocol import MissionDownload, MissionItem, MissionUpload, RETRIES, TIMEOUT_S

AP = (1, 1)


def _wire(msg, src=AP):
    """``msg`` as it arrives from system ``src`` (packed and parsed, so it carries its sender)."""
    mav = mavlink2.MAVLink(io.BytesIO(), srcSystem=src[0], srcComponent=src[1])
    return mav.parse_char(msg.pack(mav))


class Vehicle:
    """Keeps a mission and answers the protocol as PX4 does; ``drop(msg)`` loses what it would receive."""

    def __init__(self, items=(), drop=None, refuse=None):
        self.items = list(items)
        self.drop = drop or (lambda m: False)
        self.refuse = refuse
        self.incoming: list = []
        self.count = None

    def receive(self, msgs) -> list:
        out = []
        for msg in msgs:
            if self.drop(msg):
                continue
            t = msg.get_type()
            if t == "MISSION_REQUEST_LIST":
                out.append(mavlink2.MAVLink_mission_count_message(255, 190, len(self.items), msg.mission_type))
            elif t == "MISSION_REQUEST_INT":
                out.append(self.items[msg.seq].to_message(255, 190))
            elif t == "MISSION_COUNT":
                if self.refuse is not None:
                    out.append(mavlink2.MAVLink_mission_ack_message(255, 190, self.refuse, msg.mission_type))
                    continue
                self.count, self.incoming = msg.count, []
                out.append(mavlink2.MAVLink_mission_request_int_message(255, 190, 0, msg.mission_type))
            elif t == "MISSION_ITEM_INT" and msg.seq == len(self.incoming):
                self.incoming.append(MissionItem.from_message(msg))
                nxt = len(self.incoming)
                out.append(mavlink2.MAVLink_mission_request_int_message(255, 190, nxt, msg.mission_type)
                           if nxt < self.count else mavlink2.MAVLink_mission_ack_message(255, 190, 0, msg.mission_type))
        return [_wire(m) for m in out]


def _items(n):
    return [MissionItem(seq=i, frame=3, command=16, params=(0.0, 1.0, 0.0, 0.0), x=47.39 + i * 1e-4, y=8.54, z=5.0 + i)
            for i in range(n)]


def test_that_a_download_reads_every_item_then_acknowledges():
    veh = Vehicle(_items(4))
    dl = MissionDownload(AP)
    sent = [dl.start(0.0)[0]]
    t = 0.0
    while not dl.over:
        for answer in veh.receive(sent):
            sent = dl.on_message(t, answer)
        t += 0.05
    assert dl.done and [(i.seq, round(i.x, 7), i.z) for i in dl.items] == [(i.seq, round(i.x, 7), i.z) for i in _items(4)]
    assert sent[-1].get_type() == "MISSION_ACK" and sent[-1].type == mavlink2.MAV_MISSION_ACCEPTED


def test_that_a_lost_request_is_repeated_after_the_timeout():
    lost = {"n": 0}

    def drop(msg):   # the first request for item 2 is lost
        if msg.get_type() == "MISSION_REQUEST_INT" and msg.seq == 2 and lost["n"] == 0:
            lost["n"] += 1
            return True
        return False

    veh = Vehicle(_items(4), drop=drop)
    dl = MissionDownload(AP)
    t, sent = 0.0, dl.start(0.0)
    while not dl.over and t < 10:
        nxt = []
        for answer in veh.receive(sent):
            nxt += dl.on_message(t, answer)
        t += 0.05
        sent = nxt + dl.step(t)
    assert dl.done and len(dl.items) == 4 and dl.resent == 1
    assert TIMEOUT_S < t < TIMEOUT_S + 0.3   # one timeout, not more


def test_that_a_vehicle_that_never_answers_fails_the_download_naming_the_step():
    dl = MissionDownload(AP)
    dl.start(0.0)
    t, sent = 0.0, 0
    while not dl.over:
        t += 0.05
        sent += len(dl.step(t))
    assert sent == RETRIES and "no MISSION_COUNT after 6 tries of 1.5 s" in dl.failed
    assert t == pytest.approx((RETRIES + 1) * TIMEOUT_S, abs=0.06)


def test_that_an_upload_sends_each_item_asked_for_and_ends_on_the_vehicles_ack():
    veh = Vehicle()
    up = MissionUpload(AP, _items(3))
    t, sent = 0.0, up.start(0.0)
    while not up.over and t < 10:
        nxt = []
        for answer in veh.receive(sent):
            nxt += up.on_message(t, answer)
        t += 0.05
        sent = nxt + up.step(t)
    assert up.done and [(i.seq, i.z) for i in veh.incoming] == [(0, 5.0), (1, 6.0), (2, 7.0)]


def test_that_a_refused_upload_fails_with_the_vehicles_reason():
    veh = Vehicle(refuse=mavlink2.MAV_MISSION_UNSUPPORTED)
    up = MissionUpload(AP, _items(2))
    for answer in veh.receive(up.start(0.0)):
        up.on_message(0.0, answer)
    assert up.failed == "mission upload failed: the vehicle answered MAV_MISSION_UNSUPPORTED"


def test_that_messages_of_another_system_or_mission_type_are_ignored():
    dl = MissionDownload(AP)
    dl.start(0.0)
    assert dl.on_message(0.0, _wire(mavlink2.MAVLink_mission_count_message(255, 190, 3, 0), src=(2, 1))) == []
    assert dl.on_message(0.0, _wire(mavlink2.MAVLink_mission_count_message(255, 190, 3, 1))) == []
    assert dl.count is None
