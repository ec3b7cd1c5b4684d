"""The offboard sequence an autopilot needs (PX4, ArduPilot), as a pure state machine (no clock, no I/O).

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
        unless ``reengage``, which goes back to PRESTREAM); ``left_by`` says whether it was
        the autopilot's own failsafe (HEARTBEAT system_status CRITICAL, or within 3 s of a
        HEARTBEAT gap over 1.5 s) or a pilot
    any but PILOT_TOOK_OVER/GAVE_UP --no autopilot HEARTBEAT > 3 s--> LINK_LOST
    ARMING / TAKEOFF / REQUEST_OFFBOARD --retries exhausted--> GAVE_UP
    WAIT_AUTOPILOT --found armed in a failsafe (CRITICAL), no ``reengage``--> GAVE_UP

With ``takeover = "watch"`` the companion never commands the vehicle: the autopilot flies its
own stored mission and the loop watches its path (:mod:`companion.loop.mission_watch`)::

    WAIT_AUTOPILOT -> [ARMING -> START_MISSION] -> WATCHING --disarmed after its mission--> WATCH_ENDED

START_MISSION (only with ``arm``, once a run) sends MAV_CMD_MISSION_START until the HEARTBEAT
shows the mission mode (retried as any command); without ``arm`` the operator arms and starts
the mission. Nothing is streamed while watching.

With ``takeover = "guard"`` the start is the same, and the loop may take the vehicle over
(:meth:`OffboardSequencer.take_over`, on a predicted conflict) and give it back to its mission
(:meth:`OffboardSequencer.resume_mission`, once its path is clear); setpoints stream all the
while, so OFFBOARD can be entered at once::

    WAIT_AUTOPILOT -> [ARMING -> START_MISSION] -> GUARDING --take_over()--> TAKING_OVER
        -> ENGAGED --resume_mission()--> RESUMING_MISSION -> GUARDING ...
        GUARDING --disarmed after its mission--> WATCH_ENDED

A takeover the autopilot does not confirm after the retries goes back to GUARDING (the loop
may ask again); a resumption it does not confirm goes back to ENGAGED. The companion commands
(``state.engaged``) from the takeover's request on: the plan's setpoints are already in force
when the vehicle enters OFFBOARD.

What differs between autopilots is the autopilot's
:class:`~companion.mavlink.autopilots.base.EngagementPlan`, never a branch on its name. ArduPilot's
(ArduCopter) adds WAIT_READY (nothing is commanded until its estimator status says it can fly,
EKF_STATUS_REPORT), requests its streams (MAV_CMD_SET_MESSAGE_INTERVAL, every
:data:`STREAM_REQUEST_PERIOD_S` until it is ready and its pose flows), asks for GUIDED (the offboard
role) in ARMING before arming, takes off in GUIDED with param7 above home and ends TAKEOFF when the
vehicle's own estimate holds the height; PRESTREAM then engages at once (the vehicle is in GUIDED)::

    WAIT_AUTOPILOT -> WAIT_READY -> ARMING (GUIDED, then arm) -> TAKEOFF (in GUIDED, by height)
        -> PRESTREAM -> ENGAGED --hand_back()--> HANDING_BACK (LOITER or BRAKE) -> HELD

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
told to. Even then a vehicle on the ground (EXTENDED_SYS_STATE: a failsafe's landing
ended) is not taken back: OFFBOARD on the ground would fly it off again, which no
operator asked for; the sequence ends in PILOT_TOOK_OVER.

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
from companion.errors import ConfigError
from companion.mavlink.autopilots import AUTOPILOT_CHOICES, Autopilot, ModeRole, by_choice
from companion import validation as check
from companion.mavlink.messages import CommandAck, VehicleHeartbeat

logger = logging.getLogger(__name__)


class Phase(enum.Enum):
    """Phases of the offboard sequence."""

    WAIT_AUTOPILOT = "WAIT_AUTOPILOT"
    WAIT_READY = "WAIT_READY"
    ARMING = "ARMING"
    TAKEOFF = "TAKEOFF"
    WAIT_ARMED = "WAIT_ARMED"
    PRESTREAM = "PRESTREAM"
    REQUEST_OFFBOARD = "REQUEST_OFFBOARD"
    START_MISSION = "START_MISSION"
    WATCHING = "WATCHING"
    GUARDING = "GUARDING"
    TAKING_OVER = "TAKING_OVER"
    RESUMING_MISSION = "RESUMING_MISSION"
    WATCH_ENDED = "WATCH_ENDED"
    ENGAGED = "ENGAGED"
    HANDING_BACK = "HANDING_BACK"
    HELD = "HELD"
    PILOT_TOOK_OVER = "PILOT_TOOK_OVER"
    LINK_LOST = "LINK_LOST"
    GAVE_UP = "GAVE_UP"


_STREAMING = frozenset({Phase.PRESTREAM, Phase.REQUEST_OFFBOARD, Phase.ENGAGED, Phase.HANDING_BACK, Phase.GUARDING,
                        Phase.TAKING_OVER, Phase.RESUMING_MISSION})
#: Phases in which the companion's setpoints are flown (or will be, the moment the vehicle enters OFFBOARD).
_COMMANDING = frozenset({Phase.ENGAGED, Phase.TAKING_OVER, Phase.RESUMING_MISSION})
#: Phases from which a hand-back may start: a vehicle in OFFBOARD, or about to be, and streamed to.
_HANDBACK_FROM = frozenset({Phase.PRESTREAM, Phase.REQUEST_OFFBOARD}) | _COMMANDING
#: Phases in which nothing more happens (no heartbeat watch, no commands).
_FINAL = frozenset({Phase.LINK_LOST, Phase.GAVE_UP, Phase.PILOT_TOOK_OVER, Phase.HELD, Phase.WATCH_ENDED})


#: Upper bound of every offboard duration setting (s): a day is already absurd.
MAX_OFFBOARD_SECONDS = 86_400.0

#: ``hand_back_mode`` values: the autopilot's hold (PX4 Hold, ArduCopter LOITER) or its brake
#: (ArduCopter BRAKE; PX4's Hold brakes too).
HAND_BACK_MODES = {"hold": ModeRole.HOLD, "brake": ModeRole.BRAKE}

#: ``takeover`` values: ``"always"`` flies the whole flight in the offboard mode; ``"watch"`` never
#: commands: the autopilot flies its own mission and the companion warns of predicted conflicts;
#: ``"guard"``: as watch, and the companion takes over on a predicted conflict and gives back.
TAKEOVER_CHOICES = ("always", "watch", "guard")
#: ``takeover`` values in which the autopilot flies its own mission
MISSION_TAKEOVERS = ("watch", "guard")

#: A takeoff that ends by height (:attr:`EngagementPlan.takeoff_ends_by_height`) is complete when
#: the vehicle's estimate is within this of the height asked (m) and climbs slower than
#: :data:`TAKEOFF_CLIMB_MPS`.
TAKEOFF_HEIGHT_TOLERANCE_M = 0.1
TAKEOFF_CLIMB_MPS = 0.1

#: A HEARTBEAT gap (s) after which a vehicle found out of the offboard mode counts as having left it
#: by the autopilot's own failsafe (the link was silent: PX4 leaves OFFBOARD COM_OF_LOSS_T, 1 s,
#: after the last setpoint it received), not by a pilot. Autopilots send HEARTBEAT at 1 Hz: a gap
#: over 1.5 s means at least one was lost.
FAILSAFE_SILENCE_S = 1.5
#: ... or a silence that ended at most this long before (s): the autopilot may show the mode it fell
#: back to a HEARTBEAT or two after the link came back (PX4 left OFFBOARD 1.3 to 1.8 s after the last
#: setpoint on SITL).
FAILSAFE_AFTER_SILENCE_S = 3.0

#: Seconds between repeats of the stream requests (MAV_CMD_SET_MESSAGE_INTERVAL) while the
#: autopilot is not yet ready or its pose has not arrived.
STREAM_REQUEST_PERIOD_S = 5.0


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
        Request OFFBOARD again after the vehicle left it while engaged; and take over a vehicle
        found armed in a failsafe at the start (a restarted companion), which otherwise gives up
        at once.
    hold_after_goal_s : float or None
        Seconds after :meth:`OffboardSequencer.on_goal_reached` to hand the
        vehicle back (Hold, see :meth:`OffboardSequencer.hand_back`), once the loop says it
        is settled at the goal (:meth:`OffboardSequencer.on_at_goal`), or
        ``goal_settle_max_s`` later whatever it says; None never.
    goal_settle_max_s : float
        The longest the goal's hand-back waits beyond ``hold_after_goal_s`` for the vehicle
        to settle at the goal (s): a goal it cannot settle at (traffic parked on it) still ends
        the run. 0: hand back at ``hold_after_goal_s`` wherever the vehicle is (the rule
        before 6 December 2026, for replaying logs flown then).
    heartbeat_timeout_s : float
        Autopilot heartbeat silence that counts as a lost link (MAVSDK: 3 s).
    target_system : int or None
        The MAVLink system id of the only vehicle the companion may command; None
        follows the first autopilot heard. Without it, ``arm`` first listens
        ``autopilot_listen_s`` and refuses to arm when more than one autopilot system
        is heard (GAVE_UP, naming them).
    autopilot_listen_s : float
        Seconds of listening for further autopilots before arming without a
        ``target_system`` (autopilots send HEARTBEAT at 1 Hz).
    autopilot : str
        ``"auto"`` follows the first registered autopilot heard; ``"px4"`` or ``"ardupilot"``
        only an autopilot of that kind (``companion fly --autopilot``).
    hand_back_mode : str
        Where the companion hands the vehicle back: ``"hold"`` (PX4 Hold, ArduCopter LOITER)
        or ``"brake"`` (ArduCopter BRAKE; PX4 Hold).
    brake_hand_back_s : float or None
        Hand the vehicle back after braking this long (stale estimate, no valid plan) once
        the braking command is zero; None: the autopilot's default (PX4 never, ArduPilot 2 s:
        ArduCopter stays in GUIDED whatever happens to the stream).
    takeover : str
        ``"always"`` (default): the companion flies the vehicle in the offboard mode.
        ``"watch"``: it never commands; the autopilot flies its stored mission (started by the
        companion with ``arm``, else by the operator) and the companion follows it and warns of
        predicted conflicts (WATCHING; ``companion fly --takeover watch``). ``"guard"``: as
        watch, streaming all the while; on a predicted conflict the loop takes the vehicle over
        in OFFBOARD and gives it back to its mission once the path is clear (GUARDING).
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
    goal_settle_max_s: float = 10.0
    target_system: int | None = None
    autopilot_listen_s: float = 1.5
    autopilot: str = "auto"
    hand_back_mode: str = "hold"
    brake_hand_back_s: float | None = None
    takeover: str = "always"

    def __post_init__(self) -> None:
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        for name in ("prestream_s", "takeoff_timeout_s", "takeoff_settle_s", "autopilot_listen_s", "goal_settle_max_s"):
            set_(name, check.number(name, getattr(self, name), lo=0.0, hi=MAX_OFFBOARD_SECONDS))
        for name in ("retry_period_s", "heartbeat_timeout_s"):
            set_(name, check.number(name, getattr(self, name), positive=True, hi=MAX_OFFBOARD_SECONDS))
        check.integer("max_retries", self.max_retries, lo=0, hi=1000)
        check.boolean("arm", self.arm)
        check.boolean("reengage", self.reengage)
        if self.takeoff_alt_m is not None:
            set_("takeoff_alt_m", check.number("takeoff_alt_m", self.takeoff_alt_m, positive=True, hi=10_000.0))
        if self.target_system is not None:
            check.integer("target_system", self.target_system, lo=1, hi=255)
        if self.autopilot not in AUTOPILOT_CHOICES:
            raise ConfigError(f"autopilot must be one of {', '.join(AUTOPILOT_CHOICES)}, got {self.autopilot!r}")
        if self.hand_back_mode not in HAND_BACK_MODES:
            raise ConfigError(f"hand_back_mode must be one of {', '.join(HAND_BACK_MODES)}, got {self.hand_back_mode!r}")
        if self.takeover not in TAKEOVER_CHOICES:
            raise ConfigError(f"takeover must be one of {', '.join(TAKEOVER_CHOICES)}, got {self.takeover!r}")
        if self.brake_hand_back_s is not None:
            set_("brake_hand_back_s", check.number("brake_hand_back_s", self.brake_hand_back_s, lo=0.0, hi=MAX_OFFBOARD_SECONDS))
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
        self._reason = "waiting for an autopilot HEARTBEAT"
        self._target: tuple[int, int] | None = None
        self._hb: VehicleHeartbeat | None = None
        self._hb_t: float | None = None
        self._hb_new = False
        self._silence_s = 0.0  # the longest recent HEARTBEAT gap (s), over FAILSAFE_SILENCE_S
        self._silence_end_s: float | None = None  # link time that gap ended
        #: Why the vehicle last left the offboard mode while engaged: ``"failsafe"`` (the autopilot's
        #: own, after link silence or shown by its HEARTBEAT's system_status CRITICAL) or ``"pilot"``;
        #: None while it has not.
        self.left_by: str | None = None
        self._pending: _Pending | None = None
        self._was_engaged = False
        self._hand_back_asked = False   # hand_back() was called: leaving OFFBOARD from here on is what we asked
        self._seen_takeoff_mode = False
        self._takeoff_done_s: float | None = None  # link time AUTO.LOITER was first seen after the takeoff
        self._home_alt_amsl_m: float | None = None
        self._home_requested_s: float | None = None
        self._goal_s: float | None = None
        self._settled_at_goal = False
        self._first_hb_s: float | None = None  # link time the followed autopilot was first heard
        self._other_systems: set[int] = set()  # autopilot systems heard besides the one followed
        self._other_kinds: set[tuple[int, int]] = set()  # autopilots of a kind not asked for (--autopilot)
        self._wanted_kind: Autopilot | None = by_choice(self.config.autopilot)
        self._ready = False  # the autopilot's estimator status says it can fly (EngagementPlan.wait_ready)
        self._on_ground = False  # the autopilot's EXTENDED_SYS_STATE says it is on the ground
        self._height_m: float | None = None  # the vehicle's own height above home (its estimate), m
        self._climb_mps: float | None = None
        self._home_local_z_m = 0.0
        self._streams_s: float | None = None  # link time the stream requests were last sent
        self._pose_seen = False  # a pose of the autopilot arrived since the streams were requested
        self._actions: list[Action] = []
        self.events: list[Event] = []
        self._start_held: str | None = None  # why the sequence may not leave WAIT_AUTOPILOT yet
        self._mission_started = False  # START_MISSION saw the mission mode (watch: started once a run)
        self._mission_seen = False     # the vehicle was seen in its mission mode while watching
        self._stream_since: float | None = None   # link time the setpoint stream began (None: not streaming)

    # ------------------------------------------------------------------ state

    @property
    def phase(self) -> Phase:
        return self._phase

    @property
    def state(self) -> SequencerState:
        return SequencerState(
            phase=self._phase,
            streaming=self._streaming(self._phase),
            engaged=self._phase in _COMMANDING,
            since_s=self._since,
            attempts=self._pending.attempts if self._pending else 0,
            reason=self._reason,
        )

    def _prestreamed(self, t_s: float) -> bool:
        """Whether setpoints have streamed ``prestream_s`` by link time ``t_s`` (OFFBOARD may be requested)."""
        return self._stream_since is not None and t_s - self._stream_since >= self.config.prestream_s - 1e-9

    def _streaming(self, phase: Phase) -> bool:
        """Whether setpoints stream in ``phase`` (a guard streams from its mission's start on)."""
        return phase in _STREAMING or (phase is Phase.START_MISSION and self.config.takeover == "guard")

    @property
    def target(self) -> tuple[int, int] | None:
        """(system, component) of the autopilot, once seen."""
        return self._target

    @property
    def kind(self) -> Autopilot | None:
        """The followed autopilot's kind, once heard."""
        return None if self._hb is None else self._hb.kind

    @property
    def vehicle_mode(self) -> str | None:
        """The followed autopilot's mode in its latest HEARTBEAT (its own name for it), once heard."""
        return None if self._hb is None else (self._hb.mode or "unknown mode")

    @property
    def vehicle_in_mission(self) -> bool:
        """Whether the followed autopilot's latest HEARTBEAT shows it armed in its mission mode."""
        return self._hb is not None and self._hb.armed and self._hb.role is ModeRole.MISSION

    # ------------------------------------------------------------------ inputs

    def on_heartbeat(self, t_s: float, hb: VehicleHeartbeat) -> None:
        """Feed any decoded HEARTBEAT; only the (first) autopilot's count (one of a registered kind)."""
        if not hb.is_autopilot:
            return
        if self._wanted_kind is not None and hb.kind is not self._wanted_kind:
            if hb.key not in self._other_kinds:
                self._other_kinds.add(hb.key)
                logger.info("autopilot %s is %s, not %s: not following it", hb.key,
                            hb.kind.name if hb.kind else "unknown", self._wanted_kind.name)
            return
        wanted = self.config.target_system
        if (wanted is not None and hb.key[0] != wanted) or (self._target is not None and hb.key != self._target):
            if hb.key[0] not in self._other_systems and (self._target is None or hb.key[0] != self._target[0]):
                self._other_systems.add(hb.key[0])
                logger.info("autopilot system %d heard; not following it (%s)", hb.key[0],
                            f"target system {wanted}" if wanted is not None else f"following {self._target}")
            return
        if self._target is None:
            self._target, self._first_hb_s = hb.key, t_s
        if self._hb_t is not None and t_s - self._hb_t > FAILSAFE_SILENCE_S:
            self._silence_s, self._silence_end_s = t_s - self._hb_t, t_s
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

    def on_home_local_z(self, local_z_m: float) -> None:
        """Home's down coordinate in the autopilot's local frame (HOME_POSITION ``z``, m): a takeoff
        that ends by height measures the height from it."""
        if math.isfinite(local_z_m):
            self._home_local_z_m = float(local_z_m)

    def on_estimator_status(self, t_s: float, flags: int) -> None:
        """The autopilot's estimator status (EKF_STATUS_REPORT ``flags``): whether it is ready to fly."""
        if self._hb is None or self._hb.kind is None:
            return
        ready = bool(self._hb.kind.ready(flags))
        if ready != self._ready:
            logger.info("autopilot %s ready to fly (estimator flags %d)", "now" if ready else "no longer", int(flags))
        self._ready = ready
        self._advance(t_s)

    def on_landed_state(self, t_s: float, on_ground: bool) -> None:
        """The autopilot's landed state (EXTENDED_SYS_STATE): on the ground or not. Only kept: a
        re-engagement after a failsafe stops at the next :meth:`step` when its landing has ended."""
        self._on_ground = bool(on_ground)

    def on_vehicle_position(self, t_s: float, z_ned_m: float, vz_ned_mps: float | None) -> None:
        """The autopilot's own position estimate's down coordinate (m, local NED) and down velocity
        (m/s), for a takeoff that ends by height."""
        if not math.isfinite(z_ned_m):
            return
        self._pose_seen = True
        self._height_m = -(float(z_ned_m) - self._home_local_z_m)
        self._climb_mps = None if vz_ned_mps is None or not math.isfinite(vz_ned_mps) else -float(vz_ned_mps)
        if self._phase is Phase.TAKEOFF and self._hb is not None and self._hb.kind is not None \
                and self._hb.kind.engagement.takeoff_ends_by_height:
            self._advance(t_s)

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
            if self._settled_at_goal:
                self.hand_back(t_s, "goal reached")
            elif t_s - self._goal_s >= hold_after + self.config.goal_settle_max_s - 1e-9:
                self.hand_back(t_s, "goal reached" if self.config.goal_settle_max_s == 0.0 else
                               f"goal reached; not settled at it {self.config.goal_settle_max_s:g} s later")
        self._advance(t_s)
        self._request_home(t_s)
        self._request_streams(t_s)
        self._retry(t_s)
        actions, self._actions = self._actions, []
        return actions

    def on_goal_reached(self, t_s: float) -> None:
        """The mission's goal was reached at ``t_s``: hand back after ``hold_after_goal_s``, if set,
        once the vehicle is settled at it (:meth:`on_at_goal`)."""
        if self._goal_s is None:
            self._goal_s = t_s

    def on_at_goal(self, t_s: float, settled: bool) -> None:
        """Whether the vehicle is settled at its goal now (inside its acceptance and nearly still):
        the goal's hand-back waits for it, so the autopilot's Hold keeps the vehicle at the goal
        rather than where an overshoot carried it."""
        self._settled_at_goal = bool(settled)

    def hand_back(self, t_s: float, reason: str = "mission complete") -> bool:
        """Ask for Hold (AUTO.LOITER) and keep streaming until the HEARTBEAT shows the vehicle out of OFFBOARD.

        Only from PRESTREAM, REQUEST_OFFBOARD or a commanding phase (``_HANDBACK_FROM``: a vehicle
        we may be streaming to); elsewhere nothing is done. Returns whether the hand-back started.
        """
        if self._phase not in _HANDBACK_FROM:
            return False
        self._pending = None
        self._hand_back_asked = True
        role = HAND_BACK_MODES[self.config.hand_back_mode]
        self._transition(t_s, Phase.HANDING_BACK, f"{reason}; requesting {'Hold' if role is ModeRole.HOLD else 'Brake'} "
                         f"({self._mode(role)})", mavlink2.MAV_SEVERITY_NOTICE)
        if self._target is not None:
            self._send(t_s, messages.set_mode_command(self._kind, role, bool(self._hb and self._hb.armed), **self._tgt()))
        self._advance(t_s)
        return True

    def take_over(self, t_s: float, reason: str) -> bool:
        """Guarding (``takeover = "guard"``), take the vehicle over: request OFFBOARD at link time ``t_s``
        (the stream runs already) and command from now on; whether it started (only from GUARDING,
        the vehicle armed in its mission mode)."""
        if self._phase is not Phase.GUARDING or not self.vehicle_in_mission:
            return False
        if not self._prestreamed(t_s):
            return False   # PX4 refuses OFFBOARD until the stream has run a while (prestream_s)
        self._transition(t_s, Phase.TAKING_OVER, f"{reason}; requesting {self._mode(ModeRole.OFFBOARD)}",
                         mavlink2.MAV_SEVERITY_WARNING)
        self._send(t_s, messages.set_mode_command(self._kind, ModeRole.OFFBOARD, True, **self._tgt()))
        return True

    def resume_mission(self, t_s: float, reason: str) -> bool:
        """Taken over while guarding, give the vehicle back to its mission (the mission mode requested
        at link time ``t_s``, streaming until the HEARTBEAT shows it); whether it started (only from
        ENGAGED in ``takeover = "guard"``; the loop has made the mission's current item the one to go on with)."""
        if self._phase is not Phase.ENGAGED or self.config.takeover != "guard":
            return False
        self._transition(t_s, Phase.RESUMING_MISSION, f"{reason}; requesting {self._mode(ModeRole.MISSION)}",
                         mavlink2.MAV_SEVERITY_NOTICE)
        self._send(t_s, messages.set_mode_command(self._kind, ModeRole.MISSION, True, **self._tgt()))
        return True

    def _request_streams(self, t_s: float) -> None:
        """Ask for the messages the autopilot does not send by itself (MAV_CMD_SET_MESSAGE_INTERVAL, one per
        message), as soon as it is heard, and again every :data:`STREAM_REQUEST_PERIOD_S` until it is ready
        and its pose arrives."""
        if self._target is None or self._hb is None or self._hb.kind is None or not self._hb.kind.streams:
            return
        if self._phase is Phase.LINK_LOST:
            self._streams_s, self._pose_seen = None, False  # asked again when it is back (it may have rebooted)
            return
        if self._streams_s is not None and (t_s - self._streams_s < STREAM_REQUEST_PERIOD_S
                                            or (self._pose_seen and self._ready_to_fly())):
            return
        self._streams_s = t_s
        for message_id, rate_hz in self._hb.kind.streams:
            self._actions.append(SendCommand(messages.set_message_interval_command(message_id, rate_hz, **self._tgt())))

    def _ready_to_fly(self) -> bool:
        return self._ready or not self._kind.engagement.wait_ready

    def hold_start(self, reason: str) -> None:
        """Stay in WAIT_AUTOPILOT (no arming, take-off or streaming) until :meth:`release_start`:
        the loop has something to settle first (a goal not placed yet); the autopilot is still
        followed (:attr:`target`) and its link watched."""
        self._start_held = reason

    def release_start(self, t_s: float) -> None:
        """End :meth:`hold_start`: the sequence goes on from the latest HEARTBEAT at link time ``t_s``."""
        if self._start_held is not None:
            self._start_held = None
            self._advance(t_s)

    def give_up(self, t_s: float, reason: str) -> bool:
        """Give up before anything of ours is in force (GAVE_UP, said with ``reason``); whether it did
        (not while streaming: :meth:`hand_back` ends that)."""
        if self._phase in _STREAMING or self._phase in _FINAL:
            return False
        self._pending = None
        self._transition(t_s, Phase.GAVE_UP, reason, mavlink2.MAV_SEVERITY_WARNING)
        return True

    def _request_home(self, t_s: float) -> None:
        """Request HOME_POSITION every retry period while a takeoff needs it."""
        if (self.config.takeoff_alt_m is None or self._home_alt_amsl_m is not None or self._target is None
                or self._kind.engagement.takeoff_above_home
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
            if self._start_held is not None or self._must_listen(t_s, hb):
                return
            if self._ambiguous(t_s, hb) or self._flown_by_another(t_s, hb):
                return
            found = f"autopilot {hb.key} found in {hb.mode or 'unknown mode'}"
            critical = hb.system_status == mavlink2.MAV_STATE_CRITICAL
            if hb.armed and (hb.role is ModeRole.HOLD or critical) and self.config.takeoff_alt_m is not None:
                # already armed and holding, or armed in a failsafe (reached here only with
                # ``reengage``: a restart finds PX4 in its offboard-loss RTL): flying. A vehicle
                # on the ground does not hold armed for long; a takeoff command is ignored by a
                # holding vehicle and would end PX4's RTL (measured on PX4 SITL: "Already higher
                # than takeoff altitude", RTL -> AUTO.LOITER, and no takeoff to wait for), so
                # it is skipped
                self._seen_takeoff_mode = True
                found += f", armed{' in a failsafe' if critical else ''}: already flying, no takeoff"
            self._transition(t_s, self._entry_phase(hb), found)
        elif phase is Phase.WAIT_READY:
            if self._ready and not self._ambiguous(t_s, hb):
                self._transition(t_s, self._entry_phase(hb), "autopilot ready to fly (its estimator status)")
        elif phase is Phase.LINK_LOST:
            if not fresh:
                return
            if self._was_engaged:
                if self._hand_back_asked and (not hb.offboard or not hb.armed):
                    # the link went while handing back, and the vehicle is out of OFFBOARD: the hand-back
                    # it was asked for (not a failsafe; had the request been lost, PX4 is in its own)
                    self._transition(t_s, Phase.HELD, f"link back; vehicle in {hb.mode or 'unknown mode'}"
                                     + ("" if hb.armed else ", disarmed") + " after the hand-back; stopped streaming",
                                     mavlink2.MAV_SEVERITY_NOTICE)
                elif hb.offboard and hb.armed:
                    self._transition(t_s, Phase.ENGAGED, f"link back; vehicle still in {self._mode(ModeRole.OFFBOARD)}, resuming")
                elif self.config.takeover == "guard" and hb.role is ModeRole.MISSION and hb.armed:
                    self._transition(t_s, Phase.GUARDING, f"link back; vehicle in {hb.mode}, guarding")
                else:
                    self._left_offboard(t_s, f"link back; vehicle left {self._mode(ModeRole.OFFBOARD)} for {hb.mode}")
            else:
                self._transition(t_s, self._entry_phase(hb), "link back; resuming the sequence")
        elif phase is Phase.ARMING:
            if hb.armed:
                self._pending = None
                self._transition(t_s, self._after_armed(), "armed")
            elif self._kind.engagement.mode_before_arming and not hb.offboard:
                if self._pending is None or self._pending.command != mavlink2.MAV_CMD_DO_SET_MODE:
                    self._send(t_s, messages.set_mode_command(self._kind, ModeRole.OFFBOARD, False, **self._tgt()))
            elif self._pending is None or self._pending.command != mavlink2.MAV_CMD_COMPONENT_ARM_DISARM:
                self._send(t_s, messages.arm_command(True, **self._tgt()))
        elif phase is Phase.TAKEOFF and self._kind.engagement.takeoff_ends_by_height:
            self._takeoff_by_height(t_s, hb)
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
        elif phase in (Phase.PRESTREAM, Phase.REQUEST_OFFBOARD) and self._was_engaged and self._on_ground \
                and not hb.offboard:
            # re-engaging (``reengage``) a vehicle the autopilot has put down: not flown off again
            self._pending = None
            self._transition(t_s, Phase.PILOT_TOOK_OVER, f"vehicle on the ground in {hb.mode or 'unknown mode'}"
                             + ("" if hb.armed else ", disarmed") + "; not re-engaging, stopped commanding",
                             mavlink2.MAV_SEVERITY_WARNING)
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
        elif phase is Phase.START_MISSION:
            if hb.role is ModeRole.MISSION:
                self._pending = None
                self._mission_started = True
                self._transition(t_s, self._watching, f"mission started ({hb.mode}); "
                                 + ("guarding" if self._watching is Phase.GUARDING else "watching, not commanding"))
            elif not hb.armed:
                self._pending = None
                self._transition(t_s, self._entry_phase(hb), "vehicle disarmed before its mission started")
            elif self._pending is None and (not self._streaming(phase) or self._prestreamed(t_s)):
                # a guard starts the mission once OFFBOARD may be entered: a conflict on the first metres
                # of the mission (a building beside the start) is taken over at the first evaluation
                self._send(t_s, messages.mission_start_command(**self._tgt()))
        elif phase in (Phase.WATCHING, Phase.GUARDING):
            if hb.role is ModeRole.MISSION and hb.armed:
                self._mission_seen = True
            elif self._mission_seen and not hb.armed:
                self._transition(t_s, Phase.WATCH_ENDED, f"vehicle disarmed in {hb.mode or 'unknown mode'} after its "
                                 "mission; watch ended", mavlink2.MAV_SEVERITY_NOTICE)
        elif phase is Phase.TAKING_OVER:
            if hb.offboard and hb.armed:
                self._engage(t_s, f"{self._mode(ModeRole.OFFBOARD)} confirmed by HEARTBEAT; taken over")
            elif not hb.armed or hb.role is not ModeRole.MISSION:
                self._pending = None
                self._transition(t_s, Phase.GUARDING, f"vehicle in {hb.mode or 'unknown mode'}"
                                 + ("" if hb.armed else ", disarmed") + "; takeover dropped", mavlink2.MAV_SEVERITY_WARNING)
        elif phase is Phase.RESUMING_MISSION:
            if hb.role is ModeRole.MISSION and hb.armed:
                self._pending = None
                self._transition(t_s, Phase.GUARDING, f"vehicle back in {hb.mode}; guarding", mavlink2.MAV_SEVERITY_NOTICE)
            elif not hb.offboard or not hb.armed:
                self._left_offboard(t_s, f"vehicle left {self._mode(ModeRole.OFFBOARD)} for {hb.mode}"
                                    if hb.armed else "vehicle disarmed")
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

    def _takeoff_by_height(self, t_s: float, hb: VehicleHeartbeat) -> None:
        """TAKEOFF of an autopilot that takes off in its offboard mode (ArduCopter in GUIDED): the mode
        first, then MAV_CMD_NAV_TAKEOFF (param7 from the autopilot), complete when the vehicle's own
        estimate holds the height (within :data:`TAKEOFF_HEIGHT_TOLERANCE_M`, climbing slower than
        :data:`TAKEOFF_CLIMB_MPS`), then ``takeoff_settle_s``; nothing is streamed until then."""
        cfg, pending = self.config, self._pending
        target = cfg.takeoff_alt_m
        if self._kind.engagement.mode_before_arming and not hb.offboard:
            if pending is None or pending.command != mavlink2.MAV_CMD_DO_SET_MODE:
                self._send(t_s, messages.set_mode_command(self._kind, ModeRole.OFFBOARD, hb.armed, **self._tgt()))
            return
        if self._takeoff_done_s is None:
            if pending is None or pending.command != mavlink2.MAV_CMD_NAV_TAKEOFF:
                self._send(t_s, messages.takeoff_command(self._takeoff_param7(), **self._tgt()))
                return
            height, climb = self._height_m, self._climb_mps
            if (height is not None and target is not None and abs(height - target) <= TAKEOFF_HEIGHT_TOLERANCE_M
                    and climb is not None and abs(climb) <= TAKEOFF_CLIMB_MPS):
                self._pending = None
                self._takeoff_done_s = t_s
                self._event(t_s, f"takeoff height reached: {height:.2f} m above home (asked {target:.2f} m)")
            elif t_s - pending.first_s > cfg.takeoff_timeout_s:
                self._pending = None
                self._transition(t_s, Phase.GAVE_UP, f"takeoff not complete after {cfg.takeoff_timeout_s:.0f} s "
                                 f"(height {height if height is None else round(height, 2)} m)",
                                 mavlink2.MAV_SEVERITY_WARNING)
                return
        if self._takeoff_done_s is not None and t_s - self._takeoff_done_s >= cfg.takeoff_settle_s - 1e-9:
            self._seen_takeoff_mode = True  # done: never again
            self._transition(t_s, Phase.PRESTREAM, f"takeoff complete ({hb.mode})"
                             + (f", settled {cfg.takeoff_settle_s:.1f} s" if cfg.takeoff_settle_s else ""))

    def _ambiguous(self, t_s: float, hb: VehicleHeartbeat) -> bool:
        """Whether arming must be refused because several autopilots were heard and none is named
        (goes to GAVE_UP, naming them)."""
        if not (self._other_systems and self._would_arm(hb) and self.config.target_system is None):
            return False
        systems = ", ".join(str(k) for k in sorted({self._target[0], *self._other_systems}))
        self._transition(t_s, Phase.GAVE_UP, f"autopilots of systems {systems} heard: not arming; "
                         "name the vehicle with --target-system", mavlink2.MAV_SEVERITY_WARNING)
        return True

    def _flown_by_another(self, t_s: float, hb: VehicleHeartbeat) -> bool:
        """Whether to give up at once because the vehicle is found armed in a failsafe (system_status
        CRITICAL: its autopilot took it from a companion, this one before a restart perhaps, or
        fell back for a reason of its own). Taking it over would fight the failsafe; ``reengage``
        allows it (GAVE_UP otherwise, saying why). A vehicle found in the offboard mode itself is
        engaged as before (tests and scripted flights start there)."""
        if self.config.reengage or not hb.armed or hb.offboard or hb.system_status != mavlink2.MAV_STATE_CRITICAL:
            return False
        why = f"in a failsafe ({hb.mode})"
        self._transition(t_s, Phase.GAVE_UP, f"vehicle found armed {why} (a restart?); not taking over "
                         "(--reengage to)", mavlink2.MAV_SEVERITY_WARNING)
        return True

    def _would_arm(self, hb: VehicleHeartbeat) -> bool:
        return not hb.armed and self.config.arm

    def _must_listen(self, t_s: float, hb: VehicleHeartbeat) -> bool:
        """Whether to wait longer before leaving WAIT_AUTOPILOT: only to arm without a named
        target system, for ``autopilot_listen_s`` after the first autopilot HEARTBEAT."""
        if self.config.target_system is not None or not self._would_arm(hb):
            return False
        return self._first_hb_s is not None and t_s - self._first_hb_s < self.config.autopilot_listen_s - 1e-9

    def _entry_phase(self, hb: VehicleHeartbeat) -> Phase:
        if self._kind.engagement.wait_ready and not self._ready:
            return Phase.WAIT_READY
        if hb.armed:
            return self._after_armed()
        if self.config.takeover in MISSION_TAKEOVERS and (self._mission_started or not self.config.arm):
            return self._watching
        return Phase.ARMING if self.config.arm else Phase.WAIT_ARMED

    @property
    def _watching(self) -> Phase:
        """Where a mission-flying takeover waits: WATCHING, or GUARDING (streaming)."""
        return Phase.GUARDING if self.config.takeover == "guard" else Phase.WATCHING

    def _after_armed(self) -> Phase:
        if self.config.takeover in MISSION_TAKEOVERS:   # the autopilot takes off with its mission
            return Phase.START_MISSION if self.config.arm and not self._mission_started else self._watching
        if self.config.takeoff_alt_m is not None and not self._seen_takeoff_mode:
            return Phase.TAKEOFF
        return Phase.PRESTREAM

    def _engage(self, t_s: float, reason: str) -> None:
        self._pending = None
        self._was_engaged = True
        self.left_by = None
        self._transition(t_s, Phase.ENGAGED, reason, mavlink2.MAV_SEVERITY_NOTICE)

    def _left_offboard(self, t_s: float, reason: str) -> None:
        self._pending = None
        hb = self._hb
        critical = hb is not None and hb.system_status == mavlink2.MAV_STATE_CRITICAL
        silent = self._silence_end_s is not None and t_s - self._silence_end_s <= FAILSAFE_AFTER_SILENCE_S
        if critical or silent:
            self.left_by = "failsafe"
            reason += (f" (autopilot failsafe after {self._silence_s:.1f} s of link silence)" if silent
                       else " (autopilot failsafe)")
        else:
            self.left_by = "pilot"
        if self.config.reengage:
            self._transition(t_s, Phase.PRESTREAM, reason + "; re-engaging", mavlink2.MAV_SEVERITY_WARNING)
        else:
            self._transition(t_s, Phase.PILOT_TOOK_OVER, reason + "; stopped commanding",
                             mavlink2.MAV_SEVERITY_WARNING)

    def _retry(self, t_s: float) -> None:
        pending, cfg = self._pending, self.config
        if pending is None or t_s - pending.last_s < cfg.retry_period_s:
            return
        if self._phase is Phase.TAKEOFF and pending.command == mavlink2.MAV_CMD_NAV_TAKEOFF:
            if self._seen_takeoff_mode or mavlink2.MAV_RESULT_ACCEPTED in pending.acks:
                return  # accepted or climbing; the takeoff timeout decides
        if pending.attempts > cfg.max_retries and self._phase in (Phase.TAKING_OVER, Phase.RESUMING_MISSION):
            self._pending = None
            back = Phase.GUARDING if self._phase is Phase.TAKING_OVER else Phase.ENGAGED
            self._transition(t_s, back, f"{self._phase.value}: no confirmation after {pending.attempts} attempts",
                             mavlink2.MAV_SEVERITY_WARNING)
            return
        if pending.attempts > cfg.max_retries:
            self._pending = None
            self._transition(t_s, Phase.GAVE_UP,
                             f"{self._phase.value}: no confirmation after {pending.attempts} attempts",
                             mavlink2.MAV_SEVERITY_WARNING)
            return
        armed = bool(self._hb and self._hb.armed)
        if self._phase in (Phase.ARMING, Phase.TAKEOFF) and pending.command == mavlink2.MAV_CMD_DO_SET_MODE:
            msg = messages.set_mode_command(self._kind, ModeRole.OFFBOARD, armed, confirmation=pending.attempts, **self._tgt())
        elif self._phase is Phase.ARMING:
            msg = messages.arm_command(True, confirmation=pending.attempts, **self._tgt())
        elif self._phase is Phase.TAKEOFF:
            msg = messages.takeoff_command(self._takeoff_param7(), confirmation=pending.attempts, **self._tgt())
        elif self._phase in (Phase.REQUEST_OFFBOARD, Phase.TAKING_OVER):
            msg = messages.set_mode_command(self._kind, ModeRole.OFFBOARD, armed, confirmation=pending.attempts, **self._tgt())
        elif self._phase is Phase.RESUMING_MISSION:
            msg = messages.set_mode_command(self._kind, ModeRole.MISSION, armed, confirmation=pending.attempts, **self._tgt())
        elif self._phase is Phase.START_MISSION:
            msg = messages.mission_start_command(confirmation=pending.attempts, **self._tgt())
        elif self._phase is Phase.HANDING_BACK:
            msg = messages.set_mode_command(self._kind, HAND_BACK_MODES[self.config.hand_back_mode], armed,
                                            confirmation=pending.attempts, **self._tgt())
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
        if alt is None:
            return math.nan
        return self._kind.takeoff_param7(alt, self._home_alt_amsl_m)

    def _transition(self, t_s: float, phase: Phase, reason: str, severity: int = mavlink2.MAV_SEVERITY_INFO) -> None:
        if phase is self._phase:
            return
        old = self._phase
        if phase is Phase.TAKEOFF and self._home_alt_amsl_m is None and not self._kind.engagement.takeoff_above_home:
            reason += " (waiting for HOME_POSITION)"
        if self._streaming(phase) and not self._streaming(old):
            self._stream_since = t_s
        elif not self._streaming(phase):
            self._stream_since = None
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
