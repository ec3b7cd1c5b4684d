"""The offboard sequence PX4 needs, as a pure state machine (no clock, no I/O).

(Over 400 lines: one state machine, its configuration and its phases; a split would
separate transitions that must be read together: arm, take off, engage, hand back.)

PX4's offboard contract (``docs/PX4_FACTS.md``, section 3): setpoints must already be
streaming when OFFBOARD is requested; MAV_CMD_DO_SET_MODE with main mode 6 asks
for it; the only proof that the switch happened is the autopilot's HEARTBEAT
showing main mode 6. A COMMAND_ACK 0 proves nothing: current PX4 answers 0 and
stays in its mode ("Switching to Offboard is currently not available"), and
ACKs can arrive twice.

Phases::

    WAIT_AUTOPILOT -> [ARMING] -> [TAKEOFF] -> WAIT_ARMED -> PRESTREAM
        -> REQUEST_OFFBOARD -> ENGAGED --hand_back()--> HANDING_BACK -> HELD
    ENGAGED --heartbeat leaves OFFBOARD or disarms--> PILOT_TOOK_OVER (terminal
        unless ``reengage``, which goes back to PRESTREAM)
    any but PILOT_TOOK_OVER/GAVE_UP --no autopilot HEARTBEAT > 3 s--> LINK_LOST
    ARMING / TAKEOFF / REQUEST_OFFBOARD --retries exhausted--> GAVE_UP

ARMING and TAKEOFF run only when configured (``arm``, ``takeoff_alt_m``);
otherwise WAIT_ARMED waits for the pilot to arm. A takeoff waits for the home
altitude (HOME_POSITION, which PX4 streams only every 2 s; requested with
MAV_CMD_REQUEST_MESSAGE every ``retry_period_s`` from the moment the autopilot is
seen): PX4 takes param7 as AMSL, and without it climbs to MIS_TAKEOFF_ALT (seen in 7
of 10 takeoffs on PX4 SITL). No home within ``takeoff_timeout_s``: GAVE_UP.

At the end of a mission :meth:`OffboardSequencer.hand_back` asks for Hold
(AUTO.LOITER) while the setpoints still stream (zero velocity), and the stream
stops only once the HEARTBEAT shows the vehicle out of OFFBOARD (HELD): stopping
the stream in OFFBOARD is a failsafe for PX4 ("Failsafe activated", RTL). Setpoints may be streamed in
PRESTREAM, REQUEST_OFFBOARD and ENGAGED (``state.streaming``); the companion
commands the vehicle only in ENGAGED (``state.engaged``).

After a link loss the sequencer resumes when heartbeats return: in ENGAGED if
the vehicle is still in OFFBOARD (it never left our control), in the phase that
fits the vehicle if we had not engaged yet, and otherwise as after a pilot
takeover. Leaving OFFBOARD while engaged re-enters PRESTREAM only with
``reengage``; PX4 never re-enters OFFBOARD by itself, and neither do we unless
told to.

Usage (the control loop)::

    seq = OffboardSequencer(OffboardConfig(arm=True))
    seq.on_heartbeat(t, hb)              # every decoded VehicleHeartbeat
    seq.on_ack(t, ack)                   # every CommandAck
    seq.on_statustext(t, text)           # autopilot STATUSTEXT
    for action in seq.step(t):           # at the loop rate
        SendCommand -> link.send(action.msg); Notify -> STATUSTEXT / log
    if seq.state.streaming: send a setpoint (zero velocity unless engaged)
"""

from __future__ import annotations

import enum
import logging
import math
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink import messages
from companion.mavlink.autopilots import Autopilot, ModeRole
from companion import validation as check
from companion.mavlink.messages import CommandAck, VehicleHeartbeat

logger = logging.getLogger(__name__)


class Phase(enum.Enum):
    """Phases of the offboard sequence."""

    WAIT_AUTOPILOT = "WAIT_AUTOPILOT"
    ARMING = "ARMING"
    TAKEOFF = "TAKEOFF"
    WAIT_ARMED = "WAIT_ARMED"
    PRESTREAM = "PRESTREAM"
    REQUEST_OFFBOARD = "REQUEST_OFFBOARD"
    ENGAGED = "ENGAGED"
    HANDING_BACK = "HANDING_BACK"
    HELD = "HELD"
    PILOT_TOOK_OVER = "PILOT_TOOK_OVER"
    LINK_LOST = "LINK_LOST"
    GAVE_UP = "GAVE_UP"


_STREAMING = frozenset({Phase.PRESTREAM, Phase.REQUEST_OFFBOARD, Phase.ENGAGED, Phase.HANDING_BACK})
#: Phases in which nothing more happens (no heartbeat watch, no commands).
_FINAL = frozenset({Phase.LINK_LOST, Phase.GAVE_UP, Phase.PILOT_TOOK_OVER, Phase.HELD})


#: Upper bound of every offboard duration setting (s): a day is already absurd.
MAX_OFFBOARD_SECONDS = 86_400.0


@dataclass(frozen=True)
class OffboardConfig:
    """Settings of the offboard sequence (the scenario file's ``[offboard]`` table).

    Attributes
    ----------
    prestream_s : float
        Seconds of setpoint streaming before OFFBOARD is requested (PX4 wants
        a stream above 2 Hz first).
    retry_period_s : float
        Seconds between attempts of a command (arm, takeoff, DO_SET_MODE)
        while the HEARTBEAT does not confirm it.
    max_retries : int
        Retransmissions after the first attempt (so ``1 + max_retries``
        attempts); one ``retry_period_s`` after the last one, GAVE_UP.
    arm : bool
        Arm the vehicle ourselves (otherwise wait for the pilot to arm).
    takeoff_alt_m : float or None
        Take off (MAV_CMD_NAV_TAKEOFF) to this height above home, metres,
        before requesting OFFBOARD, once the home altitude is known (see
        :meth:`OffboardSequencer.on_home_altitude`).
    takeoff_timeout_s : float
        Seconds allowed for the home altitude to arrive, and again from the
        takeoff request to AUTO.LOITER.
    takeoff_settle_s : float
        Seconds to leave the vehicle in Hold after the takeoff completes, before
        streaming: PX4 ends AUTO.TAKEOFF within its altitude acceptance of the
        target (NAV_MC_ALT_RAD, 0.8 m by default) and closes the rest in Hold
        (measured on PX4 SITL: 4.67 m at the switch, still climbing toward 5 m).
    reengage : bool
        Request OFFBOARD again after the vehicle left it while engaged.
    hold_after_goal_s : float or None
        Seconds after :meth:`OffboardSequencer.on_goal_reached` to hand the
        vehicle back (Hold, see :meth:`OffboardSequencer.hand_back`); None never.
    heartbeat_timeout_s : float
        Autopilot heartbeat silence that counts as a lost link (MAVSDK: 3 s).
    """

    prestream_s: float = 1.0
    retry_period_s: float = 1.0
    max_retries: int = 5
    arm: bool = False
    takeoff_alt_m: float | None = None
    takeoff_timeout_s: float = 30.0
    takeoff_settle_s: float = 0.0
    reengage: bool = False
    heartbeat_timeout_s: float = 3.0
    hold_after_goal_s: float | None = None

    def __post_init__(self) -> None:
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        for name in ("prestream_s", "takeoff_timeout_s", "takeoff_settle_s"):
            set_(name, check.number(name, getattr(self, name), lo=0.0, hi=MAX_OFFBOARD_SECONDS))
        for name in ("retry_period_s", "heartbeat_timeout_s"):
            set_(name, check.number(name, getattr(self, name), positive=True, hi=MAX_OFFBOARD_SECONDS))
        check.integer("max_retries", self.max_retries, lo=0, hi=1000)
        check.boolean("arm", self.arm)
        check.boolean("reengage", self.reengage)
        if self.takeoff_alt_m is not None:
            set_("takeoff_alt_m", check.number("takeoff_alt_m", self.takeoff_alt_m, positive=True, hi=10_000.0))
        if self.hold_after_goal_s is not None:
            set_("hold_after_goal_s", check.number("hold_after_goal_s", self.hold_after_goal_s, lo=0.0, hi=MAX_OFFBOARD_SECONDS))


@dataclass(frozen=True)
class SequencerState:
    """Snapshot of the sequence: phase, whether to stream, whether in control."""

    phase: Phase
    streaming: bool
    engaged: bool
    since_s: float | None
    attempts: int
    reason: str


@dataclass(frozen=True)
class Event:
    """A transition or notable happening, for the log and a STATUSTEXT.

    ``severity`` is MAV_SEVERITY (4 warning, 5 notice, 6 info).
    """

    t_s: float
    phase: Phase
    text: str
    severity: int = mavlink2.MAV_SEVERITY_INFO


@dataclass(frozen=True)
class SendCommand:
    """Send this message to the autopilot."""

    msg: mavlink2.MAVLink_message


@dataclass(frozen=True)
class Notify:
    """Report this event (the app turns it into a STATUSTEXT)."""

    event: Event


Action = SendCommand | Notify


@dataclass
class _Pending:
    """A command being retried until the HEARTBEAT confirms its effect."""

    command: int
    first_s: float
    last_s: float
    attempts: int = 1
    acks: list[int] = field(default_factory=list)


class OffboardSequencer:
    """Pure state machine of the offboard sequence; see the module docstring.

    Parameters
    ----------
    config : OffboardConfig
    """

    def __init__(self, config: OffboardConfig | None = None) -> None:
        self.config = config or OffboardConfig()
        self._phase = Phase.WAIT_AUTOPILOT
        self._since: float | None = None
        self._reason = "waiting for a PX4 autopilot HEARTBEAT"
        self._target: tuple[int, int] | None = None
        self._hb: VehicleHeartbeat | None = None
        self._hb_t: float | None = None
        self._hb_new = False
        self._pending: _Pending | None = None
        self._was_engaged = False
        self._seen_takeoff_mode = False
        self._takeoff_done_s: float | None = None  # link time AUTO.LOITER was first seen after the takeoff
        self._home_alt_amsl_m: float | None = None
        self._home_requested_s: float | None = None
        self._goal_s: float | None = None
        self._actions: list[Action] = []
        self.events: list[Event] = []

    # ------------------------------------------------------------------ state

    @property
    def phase(self) -> Phase:
        return self._phase

    @property
    def state(self) -> SequencerState:
        return SequencerState(
            phase=self._phase,
            streaming=self._phase in _STREAMING,
            engaged=self._phase is Phase.ENGAGED,
            since_s=self._since,
            attempts=self._pending.attempts if self._pending else 0,
            reason=self._reason,
        )

    @property
    def target(self) -> tuple[int, int] | None:
        """(system, component) of the autopilot, once seen."""
        return self._target

    # ------------------------------------------------------------------ inputs

    def on_heartbeat(self, t_s: float, hb: VehicleHeartbeat) -> None:
        """Feed any decoded HEARTBEAT; only the (first) autopilot's count (one of a registered kind)."""
        if not hb.is_autopilot:
            return
        if self._target is None:
            self._target = hb.key
        elif hb.key != self._target:
            logger.debug("ignoring HEARTBEAT of a second autopilot %s (following %s)", hb.key, self._target)
            return
        self._hb, self._hb_t, self._hb_new = hb, t_s, True
        if hb.role is ModeRole.TAKEOFF:
            self._seen_takeoff_mode = True
        self._advance(t_s)

    def on_ack(self, t_s: float, ack: CommandAck) -> None:
        """Feed a COMMAND_ACK. Never a confirmation by itself; refusals are reported."""
        if self._target is None or ack.key != self._target:
            return
        pending = self._pending
        if pending is None or ack.command != pending.command:
            logger.debug("COMMAND_ACK %s for command %d not pending", ack.result_name, ack.command)
            return
        duplicate = len(pending.acks) >= pending.attempts
        pending.acks.append(ack.result)
        if duplicate:
            logger.debug("duplicate COMMAND_ACK %s for command %d", ack.result_name, ack.command)
            return
        if ack.result == mavlink2.MAV_RESULT_ACCEPTED:
            self._event(t_s, f"command {ack.command} acknowledged; waiting for the HEARTBEAT to confirm")
        elif ack.result == mavlink2.MAV_RESULT_IN_PROGRESS:
            pass
        elif ack.result == mavlink2.MAV_RESULT_UNSUPPORTED:
            self._pending = None
            self._transition(t_s, Phase.GAVE_UP, f"autopilot does not support command {ack.command}",
                             mavlink2.MAV_SEVERITY_WARNING)
        else:
            self._event(t_s, f"command {ack.command} refused ({ack.result_name}); will retry",
                        mavlink2.MAV_SEVERITY_WARNING)

    def on_statustext(self, t_s: float, text: str) -> None:
        """Feed an autopilot STATUSTEXT (reported as an event while a command is pending)."""
        if self._pending is not None:
            self._event(t_s, f"autopilot: {text}", mavlink2.MAV_SEVERITY_NOTICE)
        else:
            logger.info("autopilot: %s", text)

    def on_home_altitude(self, alt_amsl_m: float) -> None:
        """Home altitude AMSL in metres (HOME_POSITION), to make the takeoff target AMSL."""
        if math.isfinite(alt_amsl_m):
            self._home_alt_amsl_m = float(alt_amsl_m)

    def step(self, t_s: float) -> list[Action]:
        """Advance time to ``t_s`` (seconds, the loop's clock); return the actions to take."""
        if self._since is None:
            self._since = t_s
        if self._hb_t is not None and self._phase not in _FINAL:
            if t_s - self._hb_t > self.config.heartbeat_timeout_s:
                self._pending = None
                self._transition(t_s, Phase.LINK_LOST,
                                 f"no autopilot HEARTBEAT for {t_s - self._hb_t:.1f} s; stopped commanding",
                                 mavlink2.MAV_SEVERITY_WARNING)
        hold_after = self.config.hold_after_goal_s
        if hold_after is not None and self._goal_s is not None and t_s - self._goal_s >= hold_after - 1e-9:
            self.hand_back(t_s, "goal reached")
        self._advance(t_s)
        self._request_home(t_s)
        self._retry(t_s)
        actions, self._actions = self._actions, []
        return actions

    def on_goal_reached(self, t_s: float) -> None:
        """The mission's goal was reached at ``t_s``: hand back after ``hold_after_goal_s``, if set."""
        if self._goal_s is None:
            self._goal_s = t_s

    def hand_back(self, t_s: float, reason: str = "mission complete") -> None:
        """Ask for Hold (AUTO.LOITER) and keep streaming until the HEARTBEAT shows the vehicle out of OFFBOARD.

        Only from PRESTREAM, REQUEST_OFFBOARD or ENGAGED (a vehicle we may be
        streaming to); elsewhere nothing is streaming and nothing is done.
        """
        if self._phase not in (Phase.PRESTREAM, Phase.REQUEST_OFFBOARD, Phase.ENGAGED):
            return
        self._pending = None
        self._transition(t_s, Phase.HANDING_BACK, f"{reason}; requesting Hold ({self._mode(ModeRole.HOLD)})",
                         mavlink2.MAV_SEVERITY_NOTICE)
        if self._target is not None:
            self._send(t_s, messages.set_mode_command(self._kind, ModeRole.HOLD, bool(self._hb and self._hb.armed), **self._tgt()))
        self._advance(t_s)

    def _request_home(self, t_s: float) -> None:
        """Request HOME_POSITION every retry period while a takeoff needs it."""
        if (self.config.takeoff_alt_m is None or self._home_alt_amsl_m is not None or self._target is None
                or self._seen_takeoff_mode or self._phase not in (Phase.ARMING, Phase.TAKEOFF, Phase.WAIT_ARMED)):
            return
        if self._home_requested_s is None or t_s - self._home_requested_s >= self.config.retry_period_s:
            self._home_requested_s = t_s
            self._actions.append(SendCommand(messages.request_message_command(
                mavlink2.MAVLINK_MSG_ID_HOME_POSITION, **self._tgt())))

    # ------------------------------------------------------------------ machinery

    def _advance(self, t_s: float) -> None:
        """Move through phases as the latest HEARTBEAT allows (loops until stable)."""
        for _ in range(len(Phase) + 1):
            before = self._phase
            self._advance_once(t_s)
            if self._phase is before:
                return

    def _advance_once(self, t_s: float) -> None:
        hb, cfg, phase = self._hb, self.config, self._phase
        if hb is None or phase is Phase.GAVE_UP:
            return
        fresh, self._hb_new = self._hb_new, False
        if phase is Phase.WAIT_AUTOPILOT:
            self._transition(t_s, self._entry_phase(hb), f"autopilot {hb.key} found in {hb.mode or 'unknown mode'}")
        elif phase is Phase.LINK_LOST:
            if not fresh:
                return
            if self._was_engaged:
                if hb.offboard and hb.armed:
                    self._transition(t_s, Phase.ENGAGED, f"link back; vehicle still in {self._mode(ModeRole.OFFBOARD)}, resuming")
                else:
                    self._left_offboard(t_s, f"link back; vehicle left {self._mode(ModeRole.OFFBOARD)} for {hb.mode}")
            else:
                self._transition(t_s, self._entry_phase(hb), "link back; resuming the sequence")
        elif phase is Phase.ARMING:
            if hb.armed:
                self._pending = None
                self._transition(t_s, self._after_armed(), "armed")
            elif self._pending is None:
                self._send(t_s, messages.arm_command(True, **self._tgt()))
        elif phase is Phase.TAKEOFF:
            if self._home_alt_amsl_m is None and not self._seen_takeoff_mode:
                if self._since is not None and t_s - self._since > cfg.takeoff_timeout_s:
                    self._transition(t_s, Phase.GAVE_UP, f"no HOME_POSITION after {cfg.takeoff_timeout_s:.0f} s: "
                                     "the takeoff altitude cannot be formed", mavlink2.MAV_SEVERITY_WARNING)
                return
            if self._pending is None and not self._seen_takeoff_mode:
                self._send(t_s, messages.takeoff_command(self._takeoff_param7(), **self._tgt()))
            if self._seen_takeoff_mode and hb.role is ModeRole.HOLD:
                self._pending = None
                if self._takeoff_done_s is None:
                    self._takeoff_done_s = t_s
                if t_s - self._takeoff_done_s >= cfg.takeoff_settle_s - 1e-9:
                    self._transition(t_s, Phase.PRESTREAM, f"takeoff complete ({self._mode(ModeRole.HOLD)})"
                                     + (f", settled {cfg.takeoff_settle_s:.1f} s" if cfg.takeoff_settle_s else ""))
            elif self._pending is not None and t_s - self._pending.first_s > cfg.takeoff_timeout_s:
                self._pending = None
                self._transition(t_s, Phase.GAVE_UP, f"takeoff not complete after {cfg.takeoff_timeout_s:.0f} s",
                                 mavlink2.MAV_SEVERITY_WARNING)
        elif phase is Phase.WAIT_ARMED:
            if hb.armed:
                self._transition(t_s, Phase.PRESTREAM, "vehicle armed; streaming setpoints")
        elif phase is Phase.PRESTREAM:
            if not hb.armed:
                self._transition(t_s, self._entry_phase(hb), f"vehicle disarmed before {self._mode(ModeRole.OFFBOARD)}")
            elif hb.offboard:
                self._engage(t_s, f"vehicle switched to {self._mode(ModeRole.OFFBOARD)}")
            elif self._since is not None and t_s - self._since >= cfg.prestream_s:
                self._transition(t_s, Phase.REQUEST_OFFBOARD, f"streamed {cfg.prestream_s:.1f} s; requesting {self._mode(ModeRole.OFFBOARD)}")
                self._send(t_s, messages.set_mode_command(self._kind, ModeRole.OFFBOARD, True, **self._tgt()))
        elif phase is Phase.REQUEST_OFFBOARD:
            if not hb.armed:
                self._pending = None
                self._transition(t_s, self._entry_phase(hb), f"vehicle disarmed before {self._mode(ModeRole.OFFBOARD)}")
            elif hb.offboard:
                self._engage(t_s, f"{self._mode(ModeRole.OFFBOARD)} confirmed by HEARTBEAT")
        elif phase is Phase.HANDING_BACK:
            if not hb.offboard or not hb.armed:
                self._pending = None
                self._transition(t_s, Phase.HELD, f"vehicle in {hb.mode or 'unknown mode'}"
                                 + ("" if hb.armed else ", disarmed") + "; stopped streaming",
                                 mavlink2.MAV_SEVERITY_NOTICE)
        elif phase is Phase.ENGAGED:
            if not hb.offboard:
                self._left_offboard(t_s, f"vehicle left {self._mode(ModeRole.OFFBOARD)} for {hb.mode}")
            elif not hb.armed:
                self._left_offboard(t_s, "vehicle disarmed")

    def _entry_phase(self, hb: VehicleHeartbeat) -> Phase:
        if hb.armed:
            return self._after_armed()
        return Phase.ARMING if self.config.arm else Phase.WAIT_ARMED

    def _after_armed(self) -> Phase:
        if self.config.takeoff_alt_m is not None and not self._seen_takeoff_mode:
            return Phase.TAKEOFF
        return Phase.PRESTREAM

    def _engage(self, t_s: float, reason: str) -> None:
        self._pending = None
        self._was_engaged = True
        self._transition(t_s, Phase.ENGAGED, reason, mavlink2.MAV_SEVERITY_NOTICE)

    def _left_offboard(self, t_s: float, reason: str) -> None:
        self._pending = None
        if self.config.reengage:
            self._transition(t_s, Phase.PRESTREAM, reason + "; re-engaging", mavlink2.MAV_SEVERITY_WARNING)
        else:
            self._transition(t_s, Phase.PILOT_TOOK_OVER, reason + "; stopped commanding",
                             mavlink2.MAV_SEVERITY_WARNING)

    def _retry(self, t_s: float) -> None:
        pending, cfg = self._pending, self.config
        if pending is None or t_s - pending.last_s < cfg.retry_period_s:
            return
        if self._phase is Phase.TAKEOFF:
            if self._seen_takeoff_mode or mavlink2.MAV_RESULT_ACCEPTED in pending.acks:
                return  # accepted or climbing; the takeoff timeout decides
        if pending.attempts > cfg.max_retries:
            self._pending = None
            self._transition(t_s, Phase.GAVE_UP,
                             f"{self._phase.value}: no confirmation after {pending.attempts} attempts",
                             mavlink2.MAV_SEVERITY_WARNING)
            return
        armed = bool(self._hb and self._hb.armed)
        if self._phase is Phase.ARMING:
            msg = messages.arm_command(True, confirmation=pending.attempts, **self._tgt())
        elif self._phase is Phase.TAKEOFF:
            msg = messages.takeoff_command(self._takeoff_param7(), confirmation=pending.attempts, **self._tgt())
        elif self._phase is Phase.REQUEST_OFFBOARD:
            msg = messages.set_mode_command(self._kind, ModeRole.OFFBOARD, armed, confirmation=pending.attempts, **self._tgt())
        elif self._phase is Phase.HANDING_BACK:
            msg = messages.set_mode_command(self._kind, ModeRole.HOLD, armed, confirmation=pending.attempts, **self._tgt())
        else:
            self._pending = None
            return
        pending.attempts += 1
        pending.last_s = t_s
        self._event(t_s, f"{self._phase.value}: attempt {pending.attempts} of {cfg.max_retries + 1}")
        self._actions.append(SendCommand(msg))

    def _send(self, t_s: float, msg: mavlink2.MAVLink_command_long_message) -> None:
        self._pending = _Pending(command=int(msg.command), first_s=t_s, last_s=t_s)
        self._actions.append(SendCommand(msg))

    @property
    def _kind(self) -> Autopilot:
        """The followed autopilot's kind (known from its first HEARTBEAT, before any command)."""
        assert self._hb is not None and self._hb.kind is not None
        return self._hb.kind

    def _mode(self, role: ModeRole) -> str:
        """The followed autopilot's name of the mode the companion requests for ``role``."""
        return self._kind.mode_name(self._kind.custom_mode_of(role))

    def _tgt(self) -> dict[str, int]:
        assert self._target is not None  # only called once the autopilot is known
        return {"target_system": self._target[0], "target_component": self._target[1]}

    def _takeoff_param7(self) -> float:
        alt = self.config.takeoff_alt_m
        if alt is None or self._home_alt_amsl_m is None:
            return math.nan
        return self._home_alt_amsl_m + alt

    def _transition(self, t_s: float, phase: Phase, reason: str, severity: int = mavlink2.MAV_SEVERITY_INFO) -> None:
        if phase is self._phase:
            return
        old = self._phase
        if phase is Phase.TAKEOFF and self._home_alt_amsl_m is None:
            reason += " (waiting for HOME_POSITION)"
        self._phase, self._since, self._reason = phase, t_s, reason
        logger.log(logging.WARNING if severity <= mavlink2.MAV_SEVERITY_WARNING else logging.INFO,
                   "offboard %s -> %s: %s", old.value, phase.value, reason)
        self._emit(Event(t_s, phase, f"{phase.value}: {reason}", severity))

    def _event(self, t_s: float, text: str, severity: int = mavlink2.MAV_SEVERITY_INFO) -> None:
        logger.info("offboard %s: %s", self._phase.value, text)
        self._emit(Event(t_s, self._phase, text, severity))

    def _emit(self, event: Event) -> None:
        self.events.append(event)
        self._actions.append(Notify(event))
