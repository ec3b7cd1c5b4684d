"""Stand-ins for the live edge in a replay: the offboard sequence, the planning service and the port.

A replay drives a fresh :class:`~companion.loop.app.Companion` through the same
:class:`~companion.loop.driver.Driver` as the live edges, feeding it the logged messages at
the logged ticks; what it cannot replay from the log it is given through the Companion's
and the driver's seams: :class:`AssumeEngaged` (the sequencer of a what-if replay, where no
companion asked for OFFBOARD), :class:`RecordedArrivals` (the planning service of a replay
of a real-time log, where plans arrived some ticks after their requests) and
:class:`CollectingPort` (the driver's port: what would be sent, kept to compare with the log).
"""

from __future__ import annotations

import logging

from companion.core.planner import Planner
from companion.loop.planning import PlanResult
from companion.loop.supervisor import SIGNATURE_TEXT
from companion.realtime.tlog_marks import LEGACY_PLAN_ARRIVED, LEGACY_PLAN_LOST
from companion.loop.request_builder import ReplanJob
from companion.mavlink import messages
from companion.mavlink.offboard import OffboardConfig, Phase, SequencerState

logger = logging.getLogger(__name__)


class AssumeEngaged:
    """The :class:`~companion.loop.engagement.OffboardSequence` of a what-if replay.

    Streams and counts as engaged from the first PX4 autopilot HEARTBEAT on; sends no
    commands. Used only for logs in which no companion ever asked for OFFBOARD.
    """

    def __init__(self) -> None:
        self._target: tuple[int, int] | None = None
        self._since: float | None = None
        self.events: list = []

    def on_heartbeat(self, t_s: float, hb: messages.VehicleHeartbeat) -> None:
        if hb.is_autopilot and self._target is None:
            self._target, self._since = hb.key, t_s

    def on_ack(self, t_s: float, ack: messages.CommandAck) -> None:
        """Ignored: nothing was asked."""

    def on_statustext(self, t_s: float, text: str) -> None:
        """Ignored."""

    def on_home_altitude(self, alt_amsl_m: float) -> None:
        """Ignored."""

    def on_home_local_z(self, local_z_m: float) -> None:
        """Ignored."""

    def on_estimator_status(self, t_s: float, flags: int) -> None:
        """Ignored."""

    def on_vehicle_position(self, t_s: float, z_ned_m: float, vz_ned_mps) -> None:
        """Ignored."""

    @property
    def kind(self):
        """None: a what-if never hands back."""
        return None

    @property
    def config(self) -> OffboardConfig:
        return OffboardConfig()

    def on_goal_reached(self, t_s: float) -> None:
        """Ignored."""

    def on_at_goal(self, t_s: float, settled: bool) -> None:
        """Ignored."""

    def hand_back(self, t_s: float, reason: str) -> bool:
        """Nothing to hand back: a what-if never commands the vehicle (False)."""
        return False

    def step(self, t_s: float) -> list:
        return []

    @property
    def target(self) -> tuple[int, int] | None:
        return self._target

    @property
    def phase(self) -> Phase:
        return Phase.ENGAGED if self._target is not None else Phase.WAIT_AUTOPILOT

    @property
    def state(self) -> SequencerState:
        engaged = self._target is not None
        return SequencerState(
            phase=self.phase, streaming=engaged, engaged=engaged, since_s=self._since, attempts=0,
            reason="replay what-if: assumed engaged from the first autopilot HEARTBEAT",
        )


class RecordedArrivals:
    """The :class:`~companion.loop.planning.PlanningService` of a replay of a real-time log.

    In real time a plan arrives some ticks after its request (or, when the solve beats the
    stream, in the tick of its request), and ``companion fly`` marks every arrival in its
    tlog (:data:`~companion.realtime.tlog_marks.PLAN_IN`, the replan's number; logs from before
    the marks carry a NAMED_VALUE_FLOAT :data:`~companion.realtime.tlog_marks.LEGACY_PLAN_ARRIVED`
    instead). The replay sets :attr:`arrivals` from the recorded tick before each tick; a job
    is solved when its arrival comes, so the replayed planner solves the same jobs in the
    same order as the recorded one (its warm starts match) and its plan is applied at the
    same tick. Jobs the recording never solved (superseded, in logs from before requests
    waited for a free planner) are dropped; a job the recorded planner raised on
    (:data:`~companion.realtime.tlog_marks.PLAN_LOST`, set in :attr:`lost`) is handed back without
    a plan at its recorded tick. The service is :attr:`busy` from a request until its recorded
    arrival or loss, as the recorded planning process was, so the replayed loop builds its
    requests at the recorded ticks.
    """

    asynchronous = True  #: keeps its arrivals as the recorded planning service did

    def __init__(self, planner: Planner) -> None:
        self.planner = planner
        self.arrivals: list[int] = []
        self.lost: list[int] = []
        self.missing = 0
        self._jobs: dict[int, ReplanJob] = {}

    @property
    def busy(self) -> bool:
        """A replayed request whose recorded arrival (or loss) has not come yet."""
        return bool(self._jobs)

    def submit(self, job: ReplanJob) -> None:
        self._jobs[job.seq] = job

    def collect(self) -> list[PlanResult]:
        done = []
        for seq in self.lost:  # the recorded planner raised on these: handed back without a plan
            job = self._jobs.pop(seq, None)
            if job is None:
                self.missing += 1
            else:
                done.append(PlanResult(job, None))
        self.lost = []
        for seq in self.arrivals:
            job = self._jobs.pop(seq, None)
            if job is None:
                self.missing += 1
                continue
            for older in [s for s in self._jobs if s < seq]:
                del self._jobs[older]
            done.append(PlanResult(job, self.planner.solve(job.request, warm_start=job.warm_start)))
        self.arrivals = []
        return done


class CollectingPort:
    """The :class:`~companion.loop.driver.Port` of a replay: keeps what would be sent, sends nothing.

    :attr:`sent` holds the messages since the last :meth:`take`, in send order (the TIMESYNC
    answers of handled messages too); a replay takes a tick's messages as those sent during it.
    """

    def __init__(self) -> None:
        self.sent: list = []

    def take(self) -> list:
        """The messages kept since the last call, in send order."""
        out, self.sent = self.sent, []
        return out

    def send(self, msg, t_s: float) -> None:
        """Keep ``msg`` (link time ``t_s``, s, is the tick's or the answered message's; not needed). Nothing is packed."""
        self.sent.append(msg)


def signatures_rejected(recorded: list) -> int | None:
    """The links' count of rejected signatures announced among a recorded tick's messages, if any.

    For logs from before the signature-count mark (:data:`companion.realtime.tlog_marks.SIGNATURES_REJECTED`):
    a packet dropped for its signature never reaches the tlog, so the replay learns the count
    from the companion's own announcement (:data:`companion.loop.supervisor.SIGNATURE_TEXT`).
    """
    for m in recorded:
        if m.get_type() == "STATUSTEXT":
            text = bytes(m.text).decode("ascii", "replace") if not isinstance(m.text, str) else m.text
            if text.startswith(SIGNATURE_TEXT):
                digits = text[len(SIGNATURE_TEXT):].split(" ", 1)[0]
                if digits.isdigit():
                    return int(digits)
    return None


def is_legacy_plan_note(msg) -> bool:
    """Whether ``msg`` is an old log's plan bookkeeping sent on the wire (NAMED_VALUE_FLOAT
    :data:`~companion.realtime.tlog_marks.LEGACY_PLAN_ARRIVED` or ``LEGACY_PLAN_LOST``)."""
    return msg.get_type() == "NAMED_VALUE_FLOAT" and str(msg.name).rstrip("\x00") in (LEGACY_PLAN_ARRIVED, LEGACY_PLAN_LOST)


def arrivals(recorded: list, name: str = LEGACY_PLAN_ARRIVED) -> list[int]:
    """Replan numbers an old log's tick announced as arrived (or, with ``name=LEGACY_PLAN_LOST``,
    lost) among its recorded messages (NAMED_VALUE_FLOAT)."""
    return [
        int(m.value) for m in recorded
        if m.get_type() == "NAMED_VALUE_FLOAT" and str(m.name).rstrip("\x00") == name
    ]
