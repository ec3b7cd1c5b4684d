"""A real-time run on a virtual clock, in a second or two: ``run_realtime`` against a scripted PX4.

The stream (:func:`companion.realtime.stream.run_realtime`) runs on an injected clock against
:class:`ScriptedLink`, a PX4 armed in OFFBOARD hovering at the start (HEARTBEAT at 4 Hz,
LOCAL_POSITION_NED at 20 Hz) whose link counts a rejected signature now and then. The
planning service, :class:`DelayedPlanning`, hands each plan back some ticks after its
request and loses one job in four (as a planning process that raised). So the tlog holds
everything a replay must take from the recording: ticks, plan arrivals, lost plans and
signature counts. ``record(path)`` writes it; nothing here reads a wall clock.

This module also ran against the code from before the plan and signature marks, to make
``tests/data/scripted_before_marks.tlog`` (the same run, its bookkeeping sent as
NAMED_VALUE_FLOAT and read back from STATUSTEXT): keep it free of newer imports.
"""

from __future__ import annotations

from types import SimpleNamespace

from pymavlink.dialects.v20 import common as mavlink2

from companion.core.planner import Planner
from companion.loop.app import Companion
from companion.loop.config import load_scenario
from companion.loop.planning import PlanResult
from companion.realtime.stream import run_realtime
from companion.mavlink.link import Received
from companion.mavlink.tlog import TlogWriter

SCENARIO = "tests/data/short_hop.toml"
DURATION_S = 6.0
COMPANION_KEY = (1, 191)


def _offboard_heartbeat() -> mavlink2.MAVLink_heartbeat_message:
    return mavlink2.MAVLink_heartbeat_message(2, 12, 157 | 128, 6 << 16, 4, 3)


class ScriptedLink:
    """The autopilot link: a scripted PX4 that hovers; every packet the companion sends is kept in :attr:`sent`.

    Every 10th position report comes with a rejected signature (counted in ``stats``, as
    a signed link counts a stranger's unsigned packets).
    """

    def __init__(self, clock) -> None:
        self.clock = clock
        self.key = COMPANION_KEY
        self.peer = None
        self.stats = SimpleNamespace(signature_rejected=0)
        self.sent: list[tuple[float, object]] = []   # (t_s, message) as the companion sent them
        self._autopilot = mavlink2.MAVLink(None, 1, 1)
        self._own = mavlink2.MAVLink(None, *COMPANION_KEY)
        self._next = 0.0
        self._i = 0

    def _rx(self, msg, t_s: float) -> Received:
        raw = bytes(msg.pack(self._autopilot))
        return Received(t_s, self._autopilot.parse_buffer(raw)[0], raw)

    def poll(self) -> list[Received]:
        out, now = [], self.clock()
        while self._next <= now + 1e-9:
            if self._i % 5 == 0:
                out.append(self._rx(_offboard_heartbeat(), now))
            out.append(self._rx(mavlink2.MAVLink_local_position_ned_message(
                int(round(self._next * 1000)), 0.0, 0.0, -5.0, 0.0, 0.0, 0.0), now))
            if self._i % 10 == 7:
                self.stats.signature_rejected += 1
            self._i += 1
            self._next = round(self._next + 0.05, 6)
        return out

    def send(self, msg, t_s: float | None = None) -> bytes:
        packet = bytes(msg.pack(self._own))
        self.sent.append((t_s, self._own.parse_buffer(packet)[0]))
        return packet


class DelayedPlanning:
    """A planning process under script: a job comes back ``delay`` collects after it was sent;
    every ``lose_every``-th job comes back without a plan (its solver raised)."""

    asynchronous = True

    def __init__(self, planner: Planner, delay: int = 2, lose_every: int = 4) -> None:
        self.planner = planner
        self.delay, self.lose_every = delay, lose_every
        self._jobs: list = []   # [job, collects left]

    @property
    def busy(self) -> bool:
        return bool(self._jobs)

    def submit(self, job) -> None:
        self._jobs.append([job, self.delay])

    def collect(self) -> list[PlanResult]:
        done = []
        for entry in list(self._jobs):
            entry[1] -= 1
            if entry[1] < 0:
                self._jobs.remove(entry)
                job = entry[0]
                lost = job.seq % self.lose_every == self.lose_every - 1
                plan = None if lost else self.planner.solve(job.request, warm_start=job.warm_start)
                done.append(PlanResult(job, plan))
        return done


def record(tlog_path, *, duration_s: float = DURATION_S) -> tuple[Companion, ScriptedLink]:
    """Run the scripted flight for ``duration_s`` virtual seconds, writing the companion's tlog to ``tlog_path``."""
    scenario = load_scenario(SCENARIO)
    now_us = [0]   # a microsecond clock, as the tlog's stamps: a replay ticks at exactly the recorded times
    companion = Companion(scenario, planning=DelayedPlanning(Planner(scenario.planner)))

    def clock() -> float:
        return now_us[0] * 1e-6

    def sleep(dt: float) -> None:
        now_us[0] += max(int(round(dt * 1e6)), 1000)

    link = ScriptedLink(clock)
    tlog = TlogWriter(tlog_path)
    try:
        run_realtime(companion, link, duration_s=duration_s, clock=clock, sleep=sleep, tlog=tlog)
    finally:
        tlog.close()
    return companion, link
