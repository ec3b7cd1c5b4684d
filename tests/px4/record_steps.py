"""Fly velocity steps against a live PX4 (SITL or vehicle) in OFFBOARD and record a tlog for identification.

Usage::

    python -m tests.px4.record_steps OUT.tlog [--connect udpin:127.0.0.1:14540] [--takeoff-alt 5]

Arms, requests HOME_POSITION (so the takeoff altitude is formed AMSL), takes off, streams
the step sequence of :func:`companion.offline.identify.step_sequence` as velocity
setpoints at 20 Hz in OFFBOARD, then switches to Hold (AUTO.LOITER) before it stops
streaming. Everything sent and received goes to the tlog.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import time

from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink import messages, px4
from companion.mavlink.link import open_link
from companion.offline.identify import step_sequence

logger = logging.getLogger(__name__)


class _Flyer:
    def __init__(self, url: str, tlog: str) -> None:
        self.link = open_link(url, tlog=tlog)
        self.t0 = time.monotonic()
        self.hb = None
        self.home_alt: float | None = None
        self.z: float | None = None
        self.texts: list[str] = []

    def pump(self, seconds: float, setpoint=None, until=None) -> bool:
        end = time.monotonic() + seconds
        next_sp = time.monotonic()
        next_hb = time.monotonic()
        while time.monotonic() < end:
            for rec in self.link.poll():
                msg = rec.msg
                kind = msg.get_type()
                if kind == "HEARTBEAT" and msg.get_srcComponent() == 1:
                    self.hb = messages.decode_heartbeat(msg)
                elif kind == "HOME_POSITION":
                    self.home_alt = msg.altitude * 1e-3
                elif kind == "LOCAL_POSITION_NED":
                    self.z = msg.z
                elif kind == "STATUSTEXT":
                    text = msg.text if isinstance(msg.text, str) else msg.text.decode(errors="replace")
                    self.texts.append(text)
                    logger.info("PX4: %s", text)
            now = time.monotonic()
            if now >= next_hb:
                self.link.send(messages.companion_heartbeat())
                next_hb = now + 1.0
            if setpoint is not None and now >= next_sp:
                self.link.send(messages.velocity_setpoint(int((now - self.t0) * 1000), setpoint))
                next_sp = now + 0.05
            if until is not None and until():
                return True
            time.sleep(0.005)
        return until is None

    def command(self, msg) -> None:
        self.link.send(msg)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("tlog")
    ap.add_argument("--connect", default="udpin:127.0.0.1:14540")
    ap.add_argument("--takeoff-alt", type=float, default=5.0)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(relativeCreated)8.0f %(message)s")
    f = _Flyer(args.connect, args.tlog)
    try:
        if not f.pump(30.0, until=lambda: f.hb is not None):
            print("no PX4 heartbeat", file=sys.stderr)
            return 1
        req = mavlink2.MAV_CMD_REQUEST_MESSAGE
        for _ in range(20):
            f.command(messages.command_long(req, (mavlink2.MAVLINK_MSG_ID_HOME_POSITION,)))
            if f.pump(1.0, until=lambda: f.home_alt is not None):
                break
        logger.info("home altitude %s m AMSL", f.home_alt)
        for _ in range(30):
            f.command(messages.arm_command(True))
            if f.pump(1.0, until=lambda: f.hb.armed):
                break
        alt = math.nan if f.home_alt is None else f.home_alt + args.takeoff_alt
        f.command(messages.takeoff_command(alt))
        f.pump(2.0)
        f.pump(25.0, until=lambda: f.hb.mode == "AUTO.LOITER" and f.z is not None and f.z < -args.takeoff_alt + 0.3)
        f.pump(2.0)
        logger.info("took off: z = %.2f m, mode %s", f.z, f.hb.mode)
        f.pump(1.0, setpoint=(0.0, 0.0, 0.0))
        for _ in range(10):
            f.command(messages.offboard_command(True))
            if f.pump(1.0, setpoint=(0.0, 0.0, 0.0), until=lambda: f.hb.offboard):
                break
        logger.info("mode %s; flying the steps", f.hb.mode)
        for duration, v in step_sequence():
            f.pump(duration, setpoint=v)
        for _ in range(10):
            f.command(messages.hold_command(True))
            if f.pump(1.0, setpoint=(0.0, 0.0, 0.0), until=lambda: f.hb.mode == "AUTO.LOITER"):
                break
        f.pump(3.0)
        logger.info("done, mode %s; failsafe texts: %s", f.hb.mode, [t for t in f.texts if "ailsafe" in t])
    finally:
        f.link.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
