"""Marks in the companion's own tlog: what a replay needs that the wire does not carry.

A tlog holds every packet the companion handled or sent, stamped with its link time.
What a replay needs beyond those packets is written beside them as *marks*, into the
tlog only, never onto a link:

- **Which link a message came in on.** The companion keys obstacle tracks by link and
  refuses other systems' positions on the autopilot link, so a message from an obstacle
  link must be replayed as from that link. Before the autopilot is known, for instance,
  no rule can tell an obstacle link's report from one on the autopilot link.
- **When the loop ticked without sending anything.** The loop's timers (its HEARTBEAT
  every second, the offboard sequence's retries) run on tick times; a tick that sent
  nothing leaves no packet behind, and a replay that guesses its time from the setpoint
  grid drifts from the real one by the real loop's jitter.
- **When each plan came back.** In real time the planning process answers some ticks
  after the request (or within the asking tick); the replay must apply each plan, and
  drop each job that came back without one, at the same tick.
- **How many packets the links rejected for their signature.** A rejected packet never
  reaches the tlog, and the count decides when the companion announces rejections.

Record format
-------------
Every mark is a MAVLink 2 NAMED_VALUE_INT packed as the companion's own (system,
component), written with :meth:`TlogWriter.write <companion.mavlink.tlog.TlogWriter.write>`
(the tlog's 8-byte big-endian microsecond stamp, then the packet); its ``time_boot_ms``
is the stamp in ms (modulo 2**32) and says nothing more. Other tools read marks as
ordinary telemetry. ``name`` and ``value``:

=================  ======================================  ==================================
name               value                                   stamp, place in the tlog
=================  ======================================  ==================================
``tick``           0                                       the tick's time; first record of the tick
``sig_reject``     the links' running count of packets     the tick's time; after its ``tick``
                   dropped for a bad or missing            mark, written only when the count
                   signature                               changed (none while it stays 0)
``plan_in``        the replan's number (ReplanJob.seq)     the tick's time; after its ``tick``
                   of a plan the tick collected            (and ``sig_reject``), before the
                                                           tick's packets
``plan_lost``      the replan's number of a job that       as ``plan_in``
                   came back without a plan (the
                   planner raised)
``rx_link``        the 1-based obstacle link index         the message's receive time; just
                   (:func:`link_index`)                    before an inbound record that came
                                                           on an obstacle link
``hand_back``      the reason's index in                   the tick's time; after the tick's
                   :data:`HAND_BACK_REASONS`               packets: something outside the loop
                                                           (a signal, the run's end) asked it
                                                           to hand the vehicle back after the
                                                           tick
=================  ======================================  ==================================

So a tick is: ``tick``, then its ``sig_reject``, ``plan_in`` and ``plan_lost`` marks, then the
packets it sent; the real-time edge (:func:`companion.realtime.stream.run_realtime`) records
them through its driver (:class:`companion.loop.driver.Driver`) with a :class:`TlogRecorder`
(:meth:`TlogMarks.tick`, :meth:`TlogMarks.plans`, :meth:`TlogMarks.received`), and
:mod:`companion.offline.replay` takes them out of the stream and uses them instead of
inference. A ``plan_in`` is written only for a planning service that solves beside the
loop (:attr:`~companion.loop.planning.PlanningService.asynchronous`); with inline planning a
plan applies at the tick that asked for it.

In logs recorded before the plan and signature marks, the companion *sent* the plan
bookkeeping on the autopilot link, as NAMED_VALUE_FLOAT ``plan_seq`` / ``plan_lost`` (value:
the replan's number) among the tick's packets, and a replay read the signature count from
the companion's STATUSTEXT (:data:`companion.loop.supervisor.SIGNATURE_TEXT`). The replay
still reads those logs (:data:`LEGACY_PLAN_ARRIVED`, :data:`LEGACY_PLAN_LOST`).
"""

from __future__ import annotations

import logging

from pymavlink.dialects.v20 import common as mavlink2

from companion.loop.plan_cycle import PlanArrival
from companion.loop.intake.traffic_config import AUTOPILOT_LINK, FLEET_LINK, OBSTACLE_LINK_PREFIX, obstacle_link_name
from companion.mavlink.link import Received
from companion.mavlink.tlog import TlogWriter

logger = logging.getLogger(__name__)

TICK = "tick"
RX_LINK = "rx_link"
PLAN_IN = "plan_in"
PLAN_LOST = "plan_lost"
SIGNATURES_REJECTED = "sig_reject"
HAND_BACK = "hand_back"
_NAMES = (TICK, RX_LINK, PLAN_IN, PLAN_LOST, SIGNATURES_REJECTED, HAND_BACK)
#: The reasons a :data:`HAND_BACK` mark's value stands for (the index); others are written as 0.
HAND_BACK_REASONS = ("stopped", "stopped (duration)", "stopped (SIGINT)", "stopped (SIGTERM)")

#: NAMED_VALUE_FLOAT names of the plan bookkeeping the companion sent on the wire before the
#: marks above (old logs only; the replay still reads them).
LEGACY_PLAN_ARRIVED = "plan_seq"
LEGACY_PLAN_LOST = "plan_lost"


#: The :data:`RX_LINK` value of the fleet link.
FLEET_LINK_INDEX = 255


def link_index(link: str) -> int:
    """The 1-based index of an obstacle link from its name (``obstacles2`` -> 2); 0 for the autopilot
    link, :data:`FLEET_LINK_INDEX` for the fleet link."""
    if link == AUTOPILOT_LINK:
        return 0
    if link == FLEET_LINK:
        return FLEET_LINK_INDEX
    if link.startswith(OBSTACLE_LINK_PREFIX) and link[len(OBSTACLE_LINK_PREFIX):].isdigit():
        return int(link[len(OBSTACLE_LINK_PREFIX):])
    raise ValueError(f"not a link name the companion gives: {link!r}")


def link_name(index: int) -> str:
    """The link name of an :data:`RX_LINK` mark's value (inverse of :func:`link_index`)."""
    if index == FLEET_LINK_INDEX:
        return FLEET_LINK
    return AUTOPILOT_LINK if index <= 0 else obstacle_link_name(int(index) - 1)


def mark_of(msg) -> tuple[str, int] | None:
    """``(name, value)`` when ``msg`` (from the companion's own key) is a mark, else None."""
    if msg.get_type() != "NAMED_VALUE_INT":
        return None
    name = str(msg.name).rstrip("\x00")
    return (name, int(msg.value)) if name in _NAMES else None


class TlogMarks:
    """Writes marks into ``tlog`` as the companion ``key`` (system, component); never sends them.

    Parameters
    ----------
    tlog : the companion's tlog writer.
    key : the companion's (system id, component id), the source of its own packets.
    """

    def __init__(self, tlog: TlogWriter, key: tuple[int, int]) -> None:
        self.tlog = tlog
        self._mav = mavlink2.MAVLink(None, int(key[0]), int(key[1]))
        self._signatures = 0  # the count last marked

    def _write(self, t_s: float, name: str, value: int) -> None:
        msg = mavlink2.MAVLink_named_value_int_message(int(round(t_s * 1000.0)) % (1 << 32), name.encode(), int(value))
        self.tlog.write(t_s, bytes(msg.pack(self._mav)))

    def tick(self, t_s: float, signatures_rejected: int = 0) -> None:
        """The loop ticks at link time ``t_s`` (s); write before the tick's packets.

        ``signatures_rejected`` is the links' running count handed to the companion before
        this tick; it is marked when it changed since the last mark.
        """
        self._write(t_s, TICK, 0)
        if int(signatures_rejected) != self._signatures:
            self._signatures = int(signatures_rejected)
            self._write(t_s, SIGNATURES_REJECTED, self._signatures)

    def plans(self, t_s: float, arrivals) -> None:
        """The plans the tick at ``t_s`` collected (:attr:`companion.loop.app.Companion.plan_arrivals`);
        write after :meth:`tick` and before the tick's packets."""
        for arrival in arrivals:
            self._write(t_s, PLAN_LOST if arrival.lost else PLAN_IN, arrival.seq)

    def hand_back(self, t_s: float, reason: str) -> None:
        """After the tick at ``t_s`` (s), the loop was asked from outside to hand back, for ``reason``."""
        self._write(t_s, HAND_BACK, HAND_BACK_REASONS.index(reason) if reason in HAND_BACK_REASONS else 0)

    def received(self, t_s: float, link: str) -> None:
        """The next inbound record, received at ``t_s`` (s), came on ``link`` (written only for obstacle links)."""
        if link != AUTOPILOT_LINK:
            self._write(t_s, RX_LINK, link_index(link))


class TlogRecorder:
    """The :class:`~companion.loop.driver.Recorder` of the real-time edge: every message handled
    and packet sent, in the order the driver handled them, with the marks above; link time (s)
    is the tlog's stamp (a real link's clock is Unix time).

    Parameters
    ----------
    tlog : the companion's tlog writer (the caller's to close).
    key : the companion's (system id, component id).
    """

    def __init__(self, tlog: TlogWriter, key: tuple[int, int]) -> None:
        self.tlog = tlog
        self.marks = TlogMarks(tlog, key)

    def received(self, rx: Received) -> None:
        """An inbound message, after its link's mark (obstacle links only)."""
        self.marks.received(rx.t_s, rx.link)
        self.tlog.write(rx.t_s, rx.raw)

    def sent(self, t_s: float, packet: bytes | None) -> None:
        """A packet sent, stamped with the time it belongs to (the tick's, or the answered message's)."""
        if packet is not None:
            self.tlog.write(t_s, packet)

    def tick(self, t_s: float, signatures_rejected: int) -> None:
        self.marks.tick(t_s, signatures_rejected)

    def plans(self, t_s: float, arrivals: tuple[PlanArrival, ...]) -> None:
        self.marks.plans(t_s, arrivals)

    def hand_back(self, t_s: float, reason: str) -> None:
        self.marks.hand_back(t_s, reason)
