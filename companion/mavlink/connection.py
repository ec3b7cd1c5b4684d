"""Connection strings, read without pymavlink: which ones name a serial device, and its baud rate.

Light on purpose (``os`` only): the command line checks ``--connect`` with it while it
parses, before anything heavy is imported (:func:`companion.commands._argtypes.connection_string`),
and :class:`companion.mavlink.link.MavutilLink` opens what it finds.

Serial devices: ``DEVICE`` or ``DEVICE,BAUD`` (pymavlink's form: ``/dev/ttyACM0``,
``/dev/ttyUSB0,921600``, ``COM3``), also written ``serial:DEVICE[:BAUD]``; without a baud
rate :data:`DEFAULT_BAUD`. pymavlink itself took ``serial:/dev/ttyACM0:57600`` for a UDP
address ("UDP ports must be specified as host:port").
"""

from __future__ import annotations

import os

from companion.errors import LinkError

#: Prefixes of the network connection strings pymavlink opens.
NETWORK_PREFIXES = ("udpin:", "udpout:", "udp:", "udpbcast:", "tcp:", "tcpin:")
#: Baud rate of a serial device named without one.
DEFAULT_BAUD = 57600
#: Accepted baud rates: any integer in this range (the UART decides what it can do).
BAUD_RANGE = (50, 20_000_000)
SERIAL_PREFIX = "serial:"


def _is_device_name(text: str) -> bool:
    """A path (``/dev/ttyACM0``) or a Windows port (``COM3``)."""
    return text.startswith("/") or (text[:3].upper() == "COM" and text[3:].isdigit())


def _baud(text: str, url: str) -> int:
    lo, hi = BAUD_RANGE
    if not text.isdigit() or not lo <= int(text) <= hi:
        raise LinkError(f"connection {url!r}: baud rate {text!r} must be an integer from {lo} to {hi}")
    return int(text)


def serial_device(url: str) -> tuple[str, int] | None:
    """``(device, baud)`` of a serial connection string, or None for any other.

    Accepted: ``DEVICE``, ``DEVICE,BAUD`` (pymavlink's) and ``serial:DEVICE[:BAUD]`` (also
    ``serial:///dev/...``), where DEVICE is a path (``/dev/ttyACM0``) or ``COMn``; the
    baud rate defaults to :data:`DEFAULT_BAUD`.

    Raises
    ------
    LinkError
        A bad baud rate, a ``serial:`` string without a device, or a device path that does
        not exist (each named).
    """
    if url.startswith(NETWORK_PREFIXES):
        return None
    if url.startswith(SERIAL_PREFIX):
        rest = url[len(SERIAL_PREFIX):]
        if rest.startswith("///"):
            rest = rest[2:]
        device, baud = rest, str(DEFAULT_BAUD)
        head, sep, tail = rest.rpartition(":")
        if sep and _is_device_name(head):
            device, baud = head, tail
        elif "," in rest:
            device, _, baud = rest.rpartition(",")
        if not _is_device_name(device):
            raise LinkError(f"connection {url!r}: serial:DEVICE:BAUD needs a device path such as /dev/ttyACM0 "
                            f"(or COM3), got {device!r}")
    elif _is_device_name(url.split(",")[0]):
        device, _, baud = url.partition(",")
        baud = baud or str(DEFAULT_BAUD)
        if os.path.exists(url):                                # a device whose name has a comma
            device, baud = url, str(DEFAULT_BAUD)
    else:
        return None
    rate = _baud(baud, url)
    if device.startswith("/"):
        if not os.path.exists(device):
            raise LinkError(f"serial device {device} does not exist (connection {url!r}); is the autopilot "
                            f"plugged in? ls /dev/serial/by-id/ lists the serial devices there are")
        if os.path.isdir(device):
            raise LinkError(f"serial device {device} is a directory, not a serial port")
    return device, rate
