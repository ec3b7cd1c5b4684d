"""Serial connection strings: DEVICE, DEVICE,BAUD and serial:DEVICE:BAUD; a missing device is named.

There is no serial port here: a path that does not exist, and a pseudo-terminal
(``os.openpty``), a real tty that pyserial opens and sets the baud rate of.
"""

from __future__ import annotations

import argparse
import os

import pytest

from companion.commands._argtypes import connection_string
from companion.errors import LinkError
from companion.mavlink.connection import DEFAULT_BAUD, serial_device
from companion.mavlink.link import open_link
from tests.commands.test_bad_input import ROOT, assert_one_line, run_companion

MISSING = "/dev/ttyOGCC_NO_SUCH0"


@pytest.fixture
def tty():
    master, slave = os.openpty()
    yield os.ttyname(slave)
    os.close(slave)
    os.close(master)


@pytest.mark.parametrize(("form", "baud"), [("{}", DEFAULT_BAUD), ("{},115200", 115200), ("serial:{}:921600", 921600),
                                            ("serial:{}", DEFAULT_BAUD), ("serial://{}:230400", 230400)])
def test_that_a_serial_device_opens_at_its_baud_rate(tty, form, baud):
    url = form.format(tty)
    assert serial_device(url) == (tty, baud)
    link = open_link(url)
    try:
        assert (link._conn.port.port, link._conn.port.baudrate) == (tty, baud)
    finally:
        link.close()


@pytest.mark.parametrize("url", [MISSING, f"{MISSING},57600", f"serial:{MISSING}:57600"])
def test_that_a_missing_serial_device_is_named(url):
    with pytest.raises(LinkError) as info:
        open_link(url)
    assert str(info.value) == (f"serial device {MISSING} does not exist (connection {url!r}); is the autopilot "
                               "plugged in? ls /dev/serial/by-id/ lists the serial devices there are")


@pytest.mark.parametrize(("url", "message"), [
    ("/dev/ttyACM0,fast", "connection '/dev/ttyACM0,fast': baud rate 'fast' must be an integer from 50 to 20000000"),
    ("serial:/dev/ttyACM0:0", "connection 'serial:/dev/ttyACM0:0': baud rate '0' must be an integer from 50 to 20000000"),
    ("serial:ttyACM0", "connection 'serial:ttyACM0': serial:DEVICE:BAUD needs a device path such as /dev/ttyACM0 "
                       "(or COM3), got 'ttyACM0'"),
])
def test_that_a_bad_serial_string_is_one_clear_error(url, message):
    with pytest.raises(LinkError) as info:
        serial_device(url)
    assert str(info.value) == message


@pytest.mark.parametrize("url", ["udpin:0.0.0.0:14540", "udpout:127.0.0.1:14580", "tcp:127.0.0.1:5760", "127.0.0.1:14550"])
def test_that_network_strings_are_not_serial(url):
    assert serial_device(url) is None
    assert connection_string(url) == url


def test_that_the_argument_type_refuses_a_missing_device_at_once():
    with pytest.raises(argparse.ArgumentTypeError, match=f"serial device {MISSING} does not exist"):
        connection_string(f"serial:{MISSING}:57600")


def test_that_fly_on_a_missing_serial_device_is_one_line_from_the_parser(capsys):
    """Checked by the parser, before the planning process starts (it took 17 s to be told otherwise)."""
    url = f"serial:{MISSING}:57600"
    code, err = run_companion(capsys, ["fly", "--scenario", str(ROOT / "configs" / "antipodal.toml"), "--connect", url])
    assert_one_line(code, err)
    assert err == (f"companion fly: error: argument --connect: serial device {MISSING} does not exist (connection "
                   f"{url!r}); is the autopilot plugged in? ls /dev/serial/by-id/ lists the serial devices there are "
                   "(see --help)\n")
