"""``companion fly --identify``: fly the identification steps against a live autopilot and record the tlog.

Waits for the autopilot's HEARTBEAT, arms with ``--arm`` (else waits for the pilot to
arm), requests HOME_POSITION and takes off to ``--takeoff-alt`` if given (so the altitude
is formed AMSL), streams the velocity steps of
:func:`companion.offline.identify.step_sequence` at 20 Hz in OFFBOARD (about 75 s, 45 m
north: fly it where that is free), switches to Hold (AUTO.LOITER) before the stream stops,
and writes everything sent and received to ``--tlog``. Then::

    companion identify steps.tlog --write-scenario table.toml

Against ArduPilot (``--autopilot ardupilot``, or auto from the HEARTBEAT) the steps of its
:class:`~companion.mavlink.autopilots.base.EngagementPlan` come first: its streams are
requested (MAV_CMD_SET_MESSAGE_INTERVAL), the EKF's absolute position is waited for
(EKF_STATUS_REPORT, about 42 s after SITL starts), GUIDED is requested before arming, the
takeoff's param7 is metres above home and it ends when LOCAL_POSITION_NED holds the height;
the steps are flown in GUIDED and the vehicle is handed back to LOITER.

Every wait is bounded; the run fails (exit 1) when the vehicle never arms, never takes
off or refuses OFFBOARD.
"""

from __future__ import annotations

import argparse
import logging
import math
import time
from collections.abc import Callable

from pymavlink.dialects.v20 import common as mavlink2

from companion.errors import ConfigError, LinkError
from companion.mavlink import messages
from companion.mavlink.autopilots import ModeRole, by_choice
from companion.mavlink.link import open_link
from companion.offline.identify import step_sequence

logger = logging.getLogger(__name__)

#: Setpoint period while streaming, seconds (20 Hz, as the companion streams).
SETPOINT_PERIOD_S = 0.05
#: Bounds of the waits, seconds.
HEARTBEAT_WAIT_S = 30.0
#: Bound of the wait for an autopilot that must first be ready (ArduCopter's EKF: about 42 s in SITL).
READY_WAIT_S = 120.0
ARM_WAIT_S = 60.0
TAKEOFF_WAIT_S = 40.0


class _StepFlyer:
    """One link, pumped in small steps: decodes what the flight needs, sends heartbeats and setpoints."""

    def __init__(self, url: str, tlog: str, autopilot: str = "auto") -> None:
        self.link = open_link(url, tlog=tlog)
        self.wanted = by_choice(autopilot)   # None: whichever registered autopilot is heard
        self.t0 = time.monotonic()
        self.hb: messages.VehicleHeartbeat | None = None
        self.home_alt_m: float | None = None
        self.z_m: float | None = None
        self.texts: list[str] = []
        self.ekf_flags: int | None = None

    def pump(self, seconds: float, setpoint: tuple[float, float, float] | None = None,
             until: Callable[[], bool] | None = None) -> bool:
        """Run ``seconds`` (streaming ``setpoint`` at 20 Hz if given); True once ``until()`` holds (or at the end without one)."""
        end = time.monotonic() + seconds
        next_sp = next_hb = time.monotonic()
        while time.monotonic() < end:
            for rec in self.link.poll():
                msg = rec.msg
                kind = msg.get_type()
                if kind == "HEARTBEAT" and msg.get_srcComponent() == 1:
                    hb = messages.decode_heartbeat(msg)
                    if hb.is_autopilot and hb.kind is not None and (self.wanted is None or hb.kind is self.wanted) \
                            and (self.hb is None or hb.key == self.hb.key):
                        self.hb = hb
                        if self.link.peer is None:  # a udpin link answers the autopilot only, once known
                            self.link.peer = (msg.get_srcSystem(), msg.get_srcComponent())
                elif kind == "HOME_POSITION":
                    self.home_alt_m = msg.altitude * 1e-3
                elif kind == "LOCAL_POSITION_NED":
                    self.z_m = msg.z
                elif kind == "EKF_STATUS_REPORT":
                    self.ekf_flags = int(msg.flags)
                elif kind == "STATUSTEXT":
                    text = msg.text if isinstance(msg.text, str) else msg.text.decode(errors="replace")
                    self.texts.append(text)
                    logger.info("autopilot: %s", text)
            now = time.monotonic()
            if now >= next_hb:
                self.link.send(messages.companion_heartbeat())
                next_hb = now + 1.0
            if setpoint is not None and now >= next_sp:
                self.link.send(messages.velocity_setpoint(int((now - self.t0) * 1000), setpoint, **self.target()))
                next_sp = now + SETPOINT_PERIOD_S
            if until is not None and until():
                return True
            time.sleep(0.005)
        return until is None

    def target(self) -> dict[str, int]:
        """The followed autopilot as a command's target (ArduPilot SITL instance N is system N + 1)."""
        return {"target_system": self.hb.sysid, "target_component": self.hb.compid}

    def request_streams(self) -> None:
        """Ask for the messages the autopilot does not send by itself (its ``streams``; none for PX4)."""
        for message_id, rate_hz in self.hb.kind.streams:
            self.link.send(messages.set_message_interval_command(message_id, rate_hz, **self.target()))


def fly_identification(url: str, tlog: str, *, arm: bool, takeoff_alt_m: float | None, autopilot: str = "auto") -> dict:
    """Fly the step sequence over ``url`` recording ``tlog``; returns a small report (mode, failsafe texts).

    ``autopilot``: ``"auto"`` (the first registered autopilot heard), ``"px4"`` or ``"ardupilot"``.
    """
    f = _StepFlyer(url, tlog, autopilot)
    try:
        if not f.pump(HEARTBEAT_WAIT_S, until=lambda: f.hb is not None):
            raise LinkError(f"no {'autopilot' if f.wanted is None else f.wanted.name} HEARTBEAT on {url} "
                            f"within {HEARTBEAT_WAIT_S:.0f} s")
        plan = f.hb.kind.engagement
        logger.info("%s autopilot (system %d): mode %s", f.hb.kind.name, f.hb.sysid, f.hb.mode)
        if f.hb.kind.streams:
            f.request_streams()
            f.pump(1.0)
        if plan.wait_ready:
            deadline = time.monotonic() + READY_WAIT_S
            while not (f.ekf_flags is not None and f.hb.kind.ready(f.ekf_flags)) and time.monotonic() < deadline:
                f.pump(5.0, until=lambda: f.ekf_flags is not None and f.hb.kind.ready(f.ekf_flags))
                f.request_streams()   # repeated: a request can be lost, and some streams start only once ready
            if not (f.ekf_flags is not None and f.hb.kind.ready(f.ekf_flags)):
                raise LinkError(f"the {f.hb.kind.name} autopilot was not ready (EKF_STATUS_REPORT flags "
                                f"{f.ekf_flags}) within {READY_WAIT_S:.0f} s")
            logger.info("ready: EKF_STATUS_REPORT flags %d", f.ekf_flags)
            f.request_streams()
            f.pump(1.0)
        if plan.mode_before_arming and not f.hb.armed:
            for _ in range(10):
                f.link.send(messages.set_mode_command(f.hb.kind, ModeRole.OFFBOARD, False, **f.target()))
                if f.pump(1.0, until=lambda: f.hb.offboard):
                    break
            if not f.hb.offboard:
                raise LinkError(f"the vehicle did not enter {f.hb.kind.mode_name(f.hb.kind.custom_mode_of(ModeRole.OFFBOARD))} "
                                f"(mode {f.hb.mode})")
        if takeoff_alt_m is not None and not plan.takeoff_above_home:
            for _ in range(20):
                f.link.send(messages.command_long(mavlink2.MAV_CMD_REQUEST_MESSAGE, (mavlink2.MAVLINK_MSG_ID_HOME_POSITION,), **f.target()))
                if f.pump(1.0, until=lambda: f.home_alt_m is not None):
                    break
        deadline = time.monotonic() + ARM_WAIT_S
        while not f.hb.armed and time.monotonic() < deadline:
            if arm:
                f.link.send(messages.arm_command(True, **f.target()))
            f.pump(1.0, until=lambda: f.hb.armed)
        if not f.hb.armed:
            raise LinkError(f"the vehicle did not arm within {ARM_WAIT_S:.0f} s" + ("" if arm else " (no --arm)"))
        if takeoff_alt_m is not None:
            if plan.takeoff_above_home:
                param7 = f.hb.kind.takeoff_param7(takeoff_alt_m, f.home_alt_m)
            else:
                param7 = math.nan if f.home_alt_m is None else f.home_alt_m + takeoff_alt_m
            f.link.send(messages.takeoff_command(param7, **f.target()))
            f.pump(2.0)
            done_role = ModeRole.OFFBOARD if plan.takeoff_ends_by_height else ModeRole.HOLD
            if not f.pump(TAKEOFF_WAIT_S, until=lambda: f.hb.role is done_role and f.z_m is not None
                          and f.z_m < -takeoff_alt_m + 0.3):
                raise LinkError(f"the vehicle did not reach {takeoff_alt_m} m within {TAKEOFF_WAIT_S:.0f} s")
            f.pump(2.0)
        hold = (0.0, 0.0, 0.0)
        f.pump(1.0, setpoint=hold)
        for _ in range(10):
            f.link.send(messages.set_mode_command(f.hb.kind, ModeRole.OFFBOARD, True, **f.target()))
            if f.pump(1.0, setpoint=hold, until=lambda: f.hb.offboard):
                break
        if not f.hb.offboard:
            raise LinkError(f"the vehicle did not enter OFFBOARD (mode {f.hb.mode})")
        logger.info("%s: flying the identification steps", f.hb.mode)
        for duration, v in step_sequence():
            f.pump(duration, setpoint=v)
        for _ in range(10):
            f.link.send(messages.set_mode_command(f.hb.kind, ModeRole.HOLD, True, **f.target()))
            if f.pump(1.0, setpoint=hold, until=lambda: f.hb.role is ModeRole.HOLD):
                break
        f.pump(2.0)
        return {"final_mode": f.hb.mode, "held": f.hb.role is ModeRole.HOLD, "failsafe_texts": [t for t in f.texts if "ailsafe" in t], "tlog": tlog}
    finally:
        f.link.close()


def run(args: argparse.Namespace) -> int:
    """``companion fly --identify``: needs ``--tlog``; prints where the log went and the next command."""
    if not args.tlog:
        raise ConfigError("--identify needs --tlog FILE (the log to identify)")
    report = fly_identification(args.connect, args.tlog, arm=args.arm, takeoff_alt_m=args.takeoff_alt,
                                autopilot=getattr(args, "autopilot", None) or "auto")
    print(f"identification steps flown; final mode {report['final_mode']}; failsafe texts: {report['failsafe_texts'] or 'none'}")
    print(f"tlog: {args.tlog}\nnext: companion identify {args.tlog} --write-scenario vehicle_response.toml")
    return 0 if report["held"] and not report["failsafe_texts"] else 1
