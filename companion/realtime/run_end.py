"""How a live flight ends: stop requests, the hand-back they start, and the exit code that says why.

A live run (``companion fly``) must never just stop streaming while the vehicle is in the
companion's control mode: PX4 takes a stream that stops in OFFBOARD as a failsafe (seen on
PX4 SITL: "Failsafe activated", RTL through the traffic). So a stop request (SIGINT,
SIGTERM, the end of ``--duration``) while setpoints stream starts the sequencer's
hand-back: Hold is requested while the stream goes on (zero velocity), and the run ends
once the HEARTBEAT shows the vehicle out of the control mode, or after
``hand_back_timeout_s`` without that. A second signal ends the run at once. After a pilot
takes over (or the autopilot's failsafe does), the run ends ``linger_s`` later (the tlog keeps what the pilot did first).

:class:`RunEnd` is the decision, checked after every tick with the link time; it reads no
clock and installs no handler (``companion fly`` turns signals into :meth:`RunEnd.request_stop`).
:class:`Outcome` is how the run ended, and its value is ``fly``'s exit code:

====  ==================  ==========================================================
code  outcome             meaning
====  ==================  ==========================================================
0     goal reached        the goal was reached and the run ended without trouble;
                          watching (``--takeover watch``): the vehicle flew its
                          mission and disarmed
1     error               the sequence gave up (arming, take-off or the mode refused,
                          or the planning process did not start)
2     (bad input)         a bad flag, file or key; nothing was flown
3     stopped             a signal or ``--duration`` ended the run; the vehicle was
                          handed back (Hold confirmed) or was never in our control;
                          or the companion handed back itself after braking on a
                          stale estimate or without a valid plan (``[offboard]
                          brake_hand_back_s``; ArduPilot by default)
4     stopped, not held   stopped, but Hold was not confirmed in time (a second
                          signal, or no HEARTBEAT showing it): check the vehicle
5     pilot took over     the vehicle left the control mode; the companion stopped
6     link lost           the autopilot's HEARTBEAT was missing when the run ended
                          (or no autopilot was ever heard)
7     autopilot failsafe  the vehicle left the control mode by the autopilot's own
                          failsafe (its HEARTBEAT showed system_status CRITICAL, or
                          the link had been silent: PX4's offboard-loss failsafe);
                          the companion stopped and did not fight it
====  ==================  ==========================================================
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from companion import validation as check
from companion.loop.engagement import OffboardSequence
from companion.mavlink.offboard import Phase

#: Phases after which nothing more will happen without the operator.
_OVER = frozenset({Phase.HELD, Phase.GAVE_UP, Phase.WATCH_ENDED})


class Outcome(enum.Enum):
    """How a live run ended; the value is ``companion fly``'s exit code (see the module docstring)."""

    GOAL_REACHED = 0
    ERROR = 1
    STOPPED = 3
    STOPPED_NOT_HELD = 4
    PILOT_TOOK_OVER = 5
    LINK_LOST = 6
    AUTOPILOT_FAILSAFE = 7

    @property
    def code(self) -> int:
        return self.value

    @property
    def text(self) -> str:
        return self.name.lower().replace("_", " ")


@dataclass(frozen=True)
class RunEndConfig:
    """When a live run ends.

    Attributes
    ----------
    duration_s : float or None
        Seconds of link time after the first tick after which the run is asked to stop
        (as by a signal: handed back first); None runs until a signal or the mission ends.
    hand_back_timeout_s : float
        Seconds a stop request waits for the HEARTBEAT to show the vehicle out of the
        control mode while the stream goes on; then the run ends unconfirmed.
    linger_s : float
        Seconds the run goes on (recording, not commanding) after a pilot took over.
    """

    duration_s: float | None = None
    hand_back_timeout_s: float = 5.0
    linger_s: float = 3.0

    def __post_init__(self) -> None:
        check.number("hand_back_timeout_s", self.hand_back_timeout_s, lo=0.0)
        check.number("linger_s", self.linger_s, lo=0.0)
        if self.duration_s is not None:
            check.number("duration_s", self.duration_s, positive=True)


class RunEnd:
    """Whether a live run is over, decided after every tick (``stop(companion, t_s)`` of the edge).

    Parameters
    ----------
    config : RunEndConfig
    """

    def __init__(self, config: RunEndConfig | None = None) -> None:
        self.config = config or RunEndConfig()
        self.requests: list[str] = []      #: every stop request, as said (``"SIGINT"``, ``"duration"``)
        self.forced = False                #: a second request ended the run without waiting
        self.stop_requested_s: float | None = None  #: link time the first request was acted on
        self.handed_back = False           #: a stop request started the sequencer's hand-back
        self._first_t: float | None = None
        self._took_over_s: float | None = None

    def request_stop(self, why: str) -> None:
        """Ask the run to stop (safe to call from a signal handler: it only records)."""
        self.requests.append(why)

    @property
    def stop_reason(self) -> str | None:
        """What asked the run to stop first (None if nothing did)."""
        return self.requests[0] if self.requests else None

    def __call__(self, companion, t_s: float) -> bool:
        """Whether the run ends now, at link time ``t_s`` (s); starts the hand-back on a stop request."""
        seq: OffboardSequence = companion.sequencer
        if self._first_t is None:
            self._first_t = t_s
        duration = self.config.duration_s
        if duration is not None and t_s - self._first_t >= duration - 1e-9 and "duration" not in self.requests:
            self.request_stop("duration")
        if len(self.requests) > 1 and self.stop_requested_s is not None:
            self.forced = True
            return True
        if self.requests and self.stop_requested_s is None:
            self.stop_requested_s = t_s
            self.handed_back = companion.hand_back(t_s, f"stopped ({self.requests[0]})")
            if not self.handed_back:
                return True  # nothing of ours is in force: end at once
        if seq.phase in _OVER:
            return True
        if seq.phase is Phase.PILOT_TOOK_OVER:
            if self._took_over_s is None:
                self._took_over_s = t_s
            if t_s - self._took_over_s >= self.config.linger_s - 1e-9:
                return True
        else:
            self._took_over_s = None  # re-engaged (``--reengage``)
        if self.stop_requested_s is not None and t_s - self.stop_requested_s >= self.config.hand_back_timeout_s - 1e-9:
            return True
        return False

    def outcome(self, companion) -> Outcome:
        """How the run ended (call when it has)."""
        phase = companion.sequencer.phase
        if phase is Phase.GAVE_UP:
            return Outcome.ERROR
        if phase is Phase.PILOT_TOOK_OVER:
            if getattr(companion.sequencer, "left_by", None) == "failsafe":
                return Outcome.AUTOPILOT_FAILSAFE
            return Outcome.PILOT_TOOK_OVER
        if phase in (Phase.LINK_LOST, Phase.WAIT_AUTOPILOT):  # lost, or never heard
            return Outcome.LINK_LOST
        if self.handed_back and phase is not Phase.HELD:
            return Outcome.STOPPED_NOT_HELD
        if self.requests:
            return Outcome.STOPPED
        if phase is Phase.WATCH_ENDED:
            return Outcome.GOAL_REACHED
        if companion.state.goal_reached_t_s is not None:
            return Outcome.GOAL_REACHED
        return Outcome.STOPPED
