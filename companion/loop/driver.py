"""One driver of the pure :class:`Companion`: route a message, tick, send, record, for every edge.

The three edges that run the loop differ only in *when* they call it: the lockstep
harness (:func:`companion.offline.harness.run_lockstep`) from mavsim's clock, the
real-time stream (:func:`companion.realtime.stream.run_realtime`) from the wall clock and
its obstacle budget, and replay (:func:`companion.offline.replay.replay`) from the log's
schedule. *What* happens at each call is here, once:

- :meth:`Driver.receive`: one inbound message to :meth:`Companion.handle`, recorded (with
  its link, for a replay), and what answers it (the autopilot's TIMESYNC request) sent at
  once, stamped with the message's receive time;
- :meth:`Driver.tick`: the links' signature-rejection count handed in, the tick recorded,
  :meth:`Companion.tick`, the plans it collected recorded, its outbox sent and recorded,
  and whether it streamed a setpoint;
- :meth:`Driver.hand_back` and :meth:`Driver.mark_hand_backs`: a hand-back asked from
  outside the loop (a signal, the run's end), recorded after the tick it follows.

The driver is as pure as the loop: no socket, thread, clock or sleep. Time (link time, s)
comes from the caller; bytes leave through a :class:`Port`, and a :class:`Recorder` (the
real-time edge's tlog and marks, :class:`companion.realtime.tlog_marks.TlogRecorder`) is
told what happened. Without a recorder nothing is recorded here: a lockstep link records
what crosses it itself, and replay records nothing. Planning is not the driver's concern:
the planning service is injected into the :class:`Companion` (inline, the real-time
planning process, a replay's recorded arrivals).
"""

from __future__ import annotations

from typing import Protocol

from pymavlink.dialects.v20 import common as mavlink2

from companion.loop.app import Companion, Outbox
from companion.loop.plan_cycle import PlanArrival
from companion.mavlink.link import Received

_SETPOINT = "SET_POSITION_TARGET_LOCAL_NED"


class Port(Protocol):
    """Where the driver's outbound messages go: the autopilot link, or a replay's collection."""

    def send(self, msg: mavlink2.MAVLink_message, t_s: float) -> bytes | None:
        """Send ``msg``, which belongs to link time ``t_s`` (s); the packet as sent (None: not packed)."""


class Recorder(Protocol):
    """What the driver tells a recording (a tlog with the marks a replay needs); times are link time (s)."""

    def received(self, rx: Received) -> None:
        """``rx`` was handled (before any answer to it is recorded)."""

    def sent(self, t_s: float, packet: bytes | None) -> None:
        """``packet`` went out, belonging to ``t_s``."""

    def tick(self, t_s: float, signatures_rejected: int) -> None:
        """The loop ticks at ``t_s``, the links having rejected ``signatures_rejected`` packets so far."""

    def plans(self, t_s: float, arrivals: tuple[PlanArrival, ...]) -> None:
        """The tick at ``t_s`` collected these plans (before its packets)."""

    def hand_back(self, t_s: float, reason: str) -> None:
        """After the tick at ``t_s`` the loop was asked from outside to hand the vehicle back."""


class Driver:
    """Feeds one :class:`Companion` and carries its answers out: the same steps for every edge.

    Parameters
    ----------
    companion : Companion
        The loop, with its planning service already injected.
    port : Port
        ``port.send(msg, t_s)`` for everything the companion sends: the TIMESYNC answers of
        :meth:`receive` (``t_s`` the receive time) and each tick's outbox (``t_s`` the tick time).
    recorder : Recorder, optional
        Told every message handled, packet sent, tick, plan arrival and hand-back (None: nothing recorded).
    fleet_port : Port, optional
        Where each tick's :attr:`Companion.fleet_outbox` goes (the fleet link); not recorded
        (what a replay needs of the fleet is what was heard). None: nothing sent.
    """

    def __init__(self, companion: Companion, port: Port, recorder: Recorder | None = None,
                 fleet_port: Port | None = None) -> None:
        self.companion = companion
        self.port = port
        self.recorder = recorder
        self.fleet_port = fleet_port
        self.ticks = 0              #: ticks driven
        self.setpoints = 0          #: ticks whose outbox ended with a setpoint
        self.streamed = False       #: the last tick sent a setpoint (its outbox's last message)
        self._hand_backs_marked = len(companion.hand_backs)

    def receive(self, rx: Received) -> Outbox:
        """Route one inbound message (received at link time ``rx.t_s``, s); answer it at once. Returns the answers."""
        answers = self.companion.handle(rx)
        rec = self.recorder
        if rec is not None:
            rec.received(rx)
        for msg in answers:  # TIMESYNC answers: at once, to the autopilot only
            packet = self.port.send(msg, rx.t_s)
            if rec is not None:
                rec.sent(rx.t_s, packet)
        return answers

    def tick(self, t_s: float, signatures_rejected: int | None = None) -> Outbox:
        """Tick the loop at link time ``t_s`` (s) and send its outbox, stamped ``t_s``; returns the outbox.

        ``signatures_rejected`` is the links' running count of packets dropped for their
        signature, handed to the companion before the tick (None: not reported, as in lockstep).
        """
        companion, rec = self.companion, self.recorder
        if signatures_rejected is not None:
            companion.on_signatures_rejected(signatures_rejected)
        if rec is not None:
            rec.tick(t_s, signatures_rejected or 0)
        outbox = companion.tick(t_s)
        if rec is not None:
            rec.plans(t_s, companion.plan_arrivals)
        send = self.port.send
        for msg in outbox:
            packet = send(msg, t_s)  # stamped with the tick time: a replay ticks at the same times
            if rec is not None:
                rec.sent(t_s, packet)
        if self.fleet_port is not None:
            for msg in companion.fleet_outbox:
                self.fleet_port.send(msg, t_s)
        self.ticks += 1
        self.streamed = bool(outbox) and outbox[-1].get_type() == _SETPOINT
        self.setpoints += self.streamed
        return outbox

    def hand_back(self, t_s: float, reason: str) -> bool:
        """Hand the vehicle back on an outside request at link time ``t_s`` (s), after that tick;
        whether it started (:meth:`Companion.hand_back`). A started one is recorded."""
        started = self.companion.hand_back(t_s, reason)
        self.mark_hand_backs()
        return started

    def mark_hand_backs(self) -> None:
        """Record the hand-backs the companion started since the last call (a stop callback that
        calls :meth:`Companion.hand_back` itself, as :class:`~companion.realtime.run_end.RunEnd` does)."""
        hand_backs = self.companion.hand_backs
        if len(hand_backs) == self._hand_backs_marked:  # the usual case: nothing new (no slice)
            return
        if self.recorder is not None:
            for t_hb, reason in hand_backs[self._hand_backs_marked:]:
                self.recorder.hand_back(t_hb, reason)
        self._hand_backs_marked = len(hand_backs)
