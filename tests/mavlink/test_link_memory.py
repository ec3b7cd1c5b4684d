"""MemoryLink: packing identity, chunked delivery, garbage handling, tlog recording."""

import logging

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink import messages as M
from companion.errors import LinkError
from companion.mavlink.link import MemoryLink
from companion.mavlink.tlog import TlogWriter, read_tlog
from companion.offline.harness import LOCKSTEP_EPOCH_S


class SimClock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def vehicle_packet(msg, sysid=1, compid=1, seq=0):
    mav = mavlink2.MAVLink(None, sysid, compid)
    mav.seq = seq
    return bytes(msg.pack(mav))


HB = mavlink2.MAVLink_heartbeat_message(2, 12, 145, 393216, 4, 3)


def test_that_sent_packets_carry_companion_identity_and_increasing_sequence():
    link = MemoryLink(clock=SimClock())
    link.send(M.companion_heartbeat())
    link.send(M.velocity_setpoint(0, [0, 0, 0]))
    packets = link.take_outbound()
    assert link.take_outbound() == []
    parser = mavlink2.MAVLink(None, 255, 0)
    msgs = [parser.parse_buffer(p)[0] for p in packets]
    assert [(m.get_srcSystem(), m.get_srcComponent()) for m in msgs] == [(1, 191), (1, 191)]
    assert [m.get_seq() for m in msgs] == [0, 1]


def test_that_identity_is_configurable():
    link = MemoryLink(clock=SimClock(), source_system=42, source_component=196)
    pkt = link.send(M.companion_heartbeat())
    assert (pkt[5], pkt[6]) == (42, 196)
    with pytest.raises(LinkError):
        MemoryLink(clock=SimClock(), source_system=0)


def test_that_delivered_bytes_are_parsed_in_any_chunking_and_stamped_with_completion_time():
    link = MemoryLink(clock=SimClock())
    pkt = vehicle_packet(HB)
    link.deliver(1.0, pkt[:3])
    link.deliver(1.1, pkt[3:] + pkt[:4])
    link.deliver(1.2, pkt[4:])
    got = link.poll()
    assert [r.t_s for r in got] == [1.1, 1.2]
    assert all(r.raw == pkt and r.msg.get_type() == "HEARTBEAT" for r in got)
    assert link.poll() == []


def test_that_garbage_and_bad_crc_are_dropped_and_logged_never_raised(caplog):
    link = MemoryLink(clock=SimClock())
    good = vehicle_packet(HB)
    corrupt = bytearray(vehicle_packet(HB, seq=1))
    corrupt[-1] ^= 0xFF
    with caplog.at_level(logging.DEBUG, logger="companion.mavlink.link"):
        link.deliver(0.0, b"\x00\x01garbage" + bytes(corrupt) + good + b"\xfd\xff\xff")
        got = link.poll()
    assert [r.raw for r in got] == [good]
    assert link.stats.bad >= 2
    assert "bad MAVLink data" in caplog.text


def test_that_our_own_looped_back_traffic_is_dropped():
    link = MemoryLink(clock=SimClock())
    pkt = link.send(M.companion_heartbeat())
    link.deliver(0.0, pkt)
    assert link.poll() == [] and link.stats.own_echo == 1


def test_that_sent_and_received_packets_are_recorded_in_the_tlog_with_lockstep_epoch(tmp_path):
    clock = SimClock()
    path = tmp_path / "run.tlog"
    link = MemoryLink(clock=clock, tlog=path, tlog_offset_s=LOCKSTEP_EPOCH_S)
    clock.t = 0.5
    sent = link.send(M.velocity_setpoint(500, [1, 0, 0]))
    link.deliver(0.75, vehicle_packet(HB))
    link.poll()
    link.close()
    records = list(read_tlog(path))
    assert [m.get_type() for _, m in records] == ["SET_POSITION_TARGET_LOCAL_NED", "HEARTBEAT"]
    assert records[0][0] == pytest.approx(LOCKSTEP_EPOCH_S + 0.5, abs=1e-6)
    assert records[1][0] == pytest.approx(LOCKSTEP_EPOCH_S + 0.75, abs=1e-6)
    assert bytes(records[0][1].get_msgbuf()) == sent


def test_that_a_caller_owned_tlog_writer_stays_open_after_the_link_closes(tmp_path):
    writer = TlogWriter(tmp_path / "shared.tlog")
    link = MemoryLink(clock=SimClock(), tlog=writer)
    link.send(M.companion_heartbeat())
    link.close()
    assert not writer.closed
    writer.close()
    assert len(list(read_tlog(tmp_path / "shared.tlog"))) == 1


def test_that_a_closed_link_refuses_to_send():
    link = MemoryLink(clock=SimClock())
    link.close()
    link.close()
    with pytest.raises(LinkError, match="closed"):
        link.send(M.companion_heartbeat())


def test_that_signed_links_talk_to_each_other_and_drop_unsigned_traffic():
    key = bytes(range(32))
    clock = SimClock()
    a = MemoryLink(clock=clock, signing_key=key)
    b = MemoryLink(clock=clock, source_system=1, source_component=1, signing_key=key)
    pkt = a.send(M.companion_heartbeat())
    assert pkt[2] & 0x01  # incompat flag: signed
    b.deliver(0.0, pkt)
    assert [r.msg.get_type() for r in b.poll()] == ["HEARTBEAT"]
    b.deliver(0.0, vehicle_packet(HB, sysid=9))
    assert b.poll() == []
    with pytest.raises(LinkError, match="32 bytes"):
        MemoryLink(clock=clock, signing_key=b"short")


def test_that_a_signed_link_told_to_accept_unsigned_traffic_takes_it():
    """``accept_unsigned`` once raised NameError (an undefined ``signing``) instead of taking it."""
    clock = SimClock()
    b = MemoryLink(clock=clock, source_system=1, source_component=1, signing_key=bytes(range(32)), accept_unsigned=True)
    b.deliver(0.0, vehicle_packet(HB, sysid=9))
    assert [r.msg.get_type() for r in b.poll()] == ["HEARTBEAT"]
