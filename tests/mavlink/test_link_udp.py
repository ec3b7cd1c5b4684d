"""MavutilLink over loopback UDP (free ports, bounded waits, closed afterwards)."""

import time

import pytest

from companion.mavlink import messages as M
from companion.errors import LinkError
from companion.mavlink.link import MavutilLink, open_link
from tests.support.ports import free_udp_port


def poll_until(link, predicate, timeout_s=3.0):
    deadline = time.monotonic() + timeout_s
    got = []
    while time.monotonic() < deadline:
        got.extend(link.poll())
        if predicate(got):
            return got
        time.sleep(0.005)
    return got


@pytest.fixture
def pair(tmp_path):
    port = free_udp_port()
    companion = MavutilLink(f"udpin:127.0.0.1:{port}", tlog=tmp_path / "companion.tlog")
    vehicle = MavutilLink(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1)
    yield companion, vehicle
    companion.close()
    vehicle.close()


def test_that_companion_receives_vehicle_traffic_and_answers_the_sender(pair):
    companion, vehicle = pair
    hb = vehicle.send(M.companion_heartbeat())  # any packet will do to open the path
    got = poll_until(companion, lambda g: len(g) >= 1)
    assert [r.raw for r in got] == [hb]
    assert got[0].msg.get_srcComponent() == 1
    assert abs(got[0].t_s - time.time()) < 5.0

    companion.peer = (got[0].msg.get_srcSystem(), got[0].msg.get_srcComponent())  # the loop names its autopilot
    sent = companion.send(M.velocity_setpoint(10, [1.0, 0.0, 0.0]))
    back = poll_until(vehicle, lambda g: len(g) >= 1)
    assert [r.raw for r in back] == [sent]
    assert back[0].msg.type_mask == 3527


def test_that_udp_garbage_does_not_break_the_link(pair):
    companion, vehicle = pair
    vehicle._conn.write(b"\x00not mavlink\xfd\x09")
    good = vehicle.send(M.statustext(6, "hello"))
    got = poll_until(companion, lambda g: any(r.raw == good for r in g))
    assert good in [r.raw for r in got]


def test_that_poll_without_traffic_returns_immediately(pair):
    companion, _ = pair
    t0 = time.monotonic()
    assert companion.poll() == []
    assert time.monotonic() - t0 < 0.5


def test_that_a_bad_connection_string_raises_link_error_naming_it(tmp_path):
    with pytest.raises(LinkError, match="tcp:127.0.0.1:1"):
        open_link("tcp:127.0.0.1:1", tcp_retries=0)
    log = tmp_path / "x.tlog"
    log.write_bytes(b"\x00" * 20)
    with pytest.raises(LinkError, match="is a file"):
        open_link(str(log))


def test_that_closing_twice_is_harmless_and_poll_after_close_raises(pair):
    companion, _ = pair
    companion.close()
    companion.close()
    with pytest.raises(LinkError):
        companion.poll()
