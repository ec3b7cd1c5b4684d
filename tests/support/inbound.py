"""Inbound messages as a link hands them to ``Companion.handle``, for tests that feed the loop by hand."""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink.link import Received


def received(msg, src: tuple[int, int] = (1, 1), t_s: float = 1.0, link: str = "autopilot") -> Received:
    """``msg`` packed as system/component ``src`` and parsed back, received at link time ``t_s`` (s) on ``link``."""
    mav = mavlink2.MAVLink(None, *src)
    raw = bytes(msg.pack(mav))
    return Received(t_s, mav.parse_buffer(raw)[0], raw, link)


def px4_heartbeat() -> mavlink2.MAVLink_heartbeat_message:
    """A PX4 quadrotor's HEARTBEAT: armed, in AUTO.LOITER."""
    return mavlink2.MAVLink_heartbeat_message(2, 12, 157, 50593792, 4, 3)


def px4_offboard_heartbeat() -> mavlink2.MAVLink_heartbeat_message:
    """A PX4 quadrotor's HEARTBEAT: armed, in OFFBOARD (the loop streams plans)."""
    return mavlink2.MAVLink_heartbeat_message(2, 12, 157 | 128, 6 << 16, 4, 3)
