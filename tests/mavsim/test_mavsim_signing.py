"""mavsim with MAVLink 2 signing on: signed out, unsigned or badly signed in changes nothing."""

from __future__ import annotations

import time

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from mavsim.signing import SigningKeyError, enable_signing, load_signing_key
from mavsim.core import Simulator
from mavsim.scenario import scenario_from_dict

KEY = bytes(range(32))
OTHER_KEY = bytes(range(1, 33))
AIRBORNE = {"vehicle": {"start_ned_m": [0.0, 0.0, -5.0]}}
MAV_CMD_DO_SET_MODE = 176
AUTO_LAND = (1 | 128, 4, 6)  # base mode custom|safety-armed, PX4 main AUTO, sub LAND


def simulator() -> Simulator:
    sim = Simulator(scenario_from_dict(AIRBORNE), seed=0, signing=(KEY, time.time()))
    sim.advance_to(200_000)
    return sim


def encoder(key: bytes | None, link_id: int = 0) -> mavlink2.MAVLink:
    enc = mavlink2.MAVLink(None, srcSystem=245, srcComponent=190)
    if key is not None:
        enable_signing(enc, key, link_id=link_id, now_s=time.time())
    return enc


def set_mode_land(enc: mavlink2.MAVLink) -> bytes:
    base, main, sub = AUTO_LAND
    msg = mavlink2.MAVLink_command_long_message(1, 1, MAV_CMD_DO_SET_MODE, 0, base, main, sub, 0, 0, 0, 0)
    return bytes(msg.pack(enc))


def decoded(packets: list, key: bytes = KEY) -> list:
    """Messages of ``(t_us, link, bytes)`` packets as a client holding ``key`` reads them."""
    dec = mavlink2.MAVLink(None)
    dec.robust_parsing = True
    enable_signing(dec, key, link_id=1, now_s=time.time())
    return [m for _, _, data in packets for m in dec.parse_buffer(data) or []]


@pytest.mark.parametrize("key", [None, OTHER_KEY], ids=["unsigned", "badly-signed"])
def test_that_an_unsigned_or_badly_signed_set_mode_land_changes_nothing(key):
    sim = simulator()
    before = (sim.commander.mode, sim.commander.armed, sim.vehicle.position_ned_m.copy())
    sim.receive(set_mode_land(encoder(key)), datagram=True)
    replies = decoded(sim.advance_to(sim.now_us + 500_000))
    assert sim.commander.mode == before[0] == "AUTO.LOITER"
    assert sim.commander.armed == before[1]
    assert sim.stats["signature_rejected"] == 1
    assert not any(m.get_type() == "COMMAND_ACK" for m in replies)
    texts = [m.text for m in replies if m.get_type() == "STATUSTEXT"]
    assert any("Rejected bad or no signature (1 so far)" in t for t in texts)


def test_that_the_same_command_correctly_signed_is_obeyed():
    sim = simulator()
    sim.receive(set_mode_land(encoder(KEY)), datagram=True)
    sim.advance_to(sim.now_us + 100_000)
    assert sim.commander.mode == "AUTO.LAND"
    assert sim.stats["signature_rejected"] == 0


def test_that_the_rejection_statustext_is_rate_limited_and_the_counter_is_not():
    sim = simulator()
    bad = encoder(OTHER_KEY)
    packets = []
    for _ in range(50):
        sim.receive(set_mode_land(bad), datagram=True)
        packets += sim.advance_to(sim.now_us + 20_000)  # 1 s in all
    texts = [m.text for m in decoded(packets) if m.get_type() == "STATUSTEXT" and "Rejected" in m.text]
    assert sim.stats["signature_rejected"] == 50
    assert len(texts) == 1


def test_that_a_forged_packet_stamped_in_the_future_does_not_lock_out_the_genuine_sender():
    sim = simulator()
    forged = encoder(OTHER_KEY)
    forged.signing.timestamp = 2**47  # far ahead of any genuine stamp, same stream (link 0, 245, 190)
    sim.receive(set_mode_land(forged), datagram=True)
    sim.receive(set_mode_land(encoder(KEY)), datagram=True)
    sim.advance_to(sim.now_us + 100_000)
    assert sim.stats["signature_rejected"] == 1
    assert sim.commander.mode == "AUTO.LAND"


def test_that_everything_mavsim_sends_is_signed_with_the_key():
    sim = Simulator(scenario_from_dict(AIRBORNE), seed=0, signing=(KEY, time.time()))
    packets = sim.drain() + sim.advance_to(1_000_000)  # from boot on
    assert len(packets) > 20
    assert all(data[0] == 0xFD and data[2] & mavlink2.MAVLINK_IFLAG_SIGNED for _, _, data in packets)
    assert all(m.get_type() != "BAD_DATA" for m in decoded(packets, KEY))
    assert all(m.get_type() == "BAD_DATA" for m in decoded(packets, OTHER_KEY))


def test_that_a_two_byte_datagram_does_not_swallow_the_next_command():
    sim = Simulator(scenario_from_dict(AIRBORNE), seed=0)
    sim.advance_to(200_000)
    enc = encoder(None)
    sim.receive(b"\xfd\xff", datagram=True)
    sim.receive(set_mode_land(enc), datagram=True)
    sim.advance_to(sim.now_us + 100_000)
    assert sim.commander.mode == "AUTO.LAND"


def test_that_without_datagram_framing_a_stream_still_reassembles_split_packets():
    sim = Simulator(scenario_from_dict(AIRBORNE), seed=0)
    sim.advance_to(200_000)
    packet = set_mode_land(encoder(None))
    sim.receive(packet[:7])
    sim.receive(packet[7:])
    sim.advance_to(sim.now_us + 100_000)
    assert sim.commander.mode == "AUTO.LAND"


def test_that_signing_keys_come_from_a_file_or_the_environment_as_64_hex_digits(tmp_path, monkeypatch):
    path = tmp_path / "key"
    path.write_text(KEY.hex() + "\n")
    path.chmod(0o600)
    assert load_signing_key(path) == KEY
    monkeypatch.setenv("TEST_MAVLINK_KEY", KEY.hex().upper())
    assert load_signing_key(key_env="TEST_MAVLINK_KEY") == KEY
    assert load_signing_key() is None
    path.write_text("abc")
    with pytest.raises(SigningKeyError, match=rf"{path}: a signing key must be 64 hexadecimal digits"):
        load_signing_key(path)
    with pytest.raises(SigningKeyError, match="not both"):
        load_signing_key(path, "TEST_MAVLINK_KEY")


def test_that_over_udp_a_badly_signed_set_mode_land_changes_nothing_and_a_signed_one_lands():
    import socket
    import threading

    from mavsim.udp import LinkAddress, UdpServer

    client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    client.bind(("127.0.0.1", 0))
    sim = Simulator(scenario_from_dict(AIRBORNE), seed=0, signing=(KEY, time.time()))
    server = UdpServer(sim, [LinkAddress("api", 0, client.getsockname()[1])], speed=1.0)
    thread = threading.Thread(target=server.run, args=(30.0,), daemon=True)
    thread.start()
    addr = ("127.0.0.1", server.local_ports["api"])
    try:
        client.sendto(set_mode_land(encoder(OTHER_KEY)), addr)
        client.sendto(set_mode_land(encoder(None)), addr)
        end = time.monotonic() + 3.0
        while sim.stats["signature_rejected"] < 2 and time.monotonic() < end:
            time.sleep(0.02)
        time.sleep(0.2)
        assert sim.stats["signature_rejected"] == 2 and sim.commander.mode == "AUTO.LOITER"
        client.sendto(set_mode_land(encoder(KEY)), addr)
        while sim.commander.mode != "AUTO.LAND" and time.monotonic() < end + 3.0:
            time.sleep(0.02)
        assert sim.commander.mode == "AUTO.LAND"
    finally:
        server.stop()
        thread.join(timeout=5)
        server.close()
        client.close()
