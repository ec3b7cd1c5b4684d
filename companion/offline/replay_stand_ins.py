"""Stand-ins for the live edge in a replay: the offboard sequence and the planning service.

A replay feeds a fresh :class:`~companion.loop.app.Companion` the logged messages at the
logged ticks; what it cannot replay from the log it is given through the Companion's
seams: :class:`AssumeEngaged` (the sequencer of a what-if replay, where no companion
asked for OFFBOARD) and :class:`RecordedArrivals` (the planning service of a replay of
a real-time log, where plans arrived some ticks after their requests).
"""

from __future__ import annotations

import logging

from companion.core.planner import Planner
from companion.loop.app import PLAN_ARRIVED, PLAN_LOST, SIGNATURE_TEXT
from companion.loop.planning import PlanResult
from companion.loop.request_builder import ReplanJob
from companion.mavlink import messages
from companion.mavlink.offboard import Phase, SequencerState

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

    def on_goal_reached(self, t_s: float) -> None:
        """Ignored."""

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
    stream, in the tick of its request), and ``companion fly`` announces every arrival
    (NAMED_VALUE_FLOAT :data:`~companion.loop.app.PLAN_ARRIVED`, the replan's number). The
    replay sets :attr:`arrivals` from the recorded tick before each tick; a job is solved
    when its arrival comes, so the replayed planner solves the same jobs in the same order
    as the recorded one (its warm starts match) and its plan is applied at the same tick.
    Jobs the recording never solved (superseded, in logs from before requests waited for a
    free planner) are dropped; a job the recorded planner raised on (NAMED_VALUE_FLOAT
    :data:`~companion.loop.app.PLAN_LOST`, set in :attr:`lost`) is handed back without a plan
    at its recorded tick. The service is :attr:`busy` from a request until its recorded
    arrival or loss, as the recorded planning process was, so the replayed loop builds its
    requests at the recorded ticks.
    """

    asynchronous = True  #: announces its arrivals as the recorded planning service did

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


def signatures_rejected(recorded: list) -> int | None:
    """The links' count of rejected signatures announced among a recorded tick's messages, if any.

    A packet dropped for its signature never reaches the tlog, so the replay learns the
    count from the companion's own announcement (:data:`companion.loop.app.SIGNATURE_TEXT`).
    """
    for m in recorded:
        if m.get_type() == "STATUSTEXT":
            text = bytes(m.text).decode("ascii", "replace") if not isinstance(m.text, str) else m.text
            if text.startswith(SIGNATURE_TEXT):
                digits = text[len(SIGNATURE_TEXT):].split(" ", 1)[0]
                if digits.isdigit():
                    return int(digits)
    return None


def arrivals(recorded: list, name: str = PLAN_ARRIVED) -> list[int]:
    """Replan numbers announced as arrived (or, with ``name=PLAN_LOST``, lost) among a recorded tick's messages."""
    return [
        int(m.value) for m in recorded
        if m.get_type() == "NAMED_VALUE_FLOAT" and str(m.name).rstrip("\x00") == name
    ]
