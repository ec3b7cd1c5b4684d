"""The real-time edge: wall clock, sleeping, a real link and the planning worker around the pure :class:`Companion`.

Two processes. The *stream* (the caller of :func:`run_realtime`, one thread) polls the
link often (inbound messages are stamped by the link's clock when they arrive) and ticks
the companion at its setpoint rate; a tick builds a replan's request when one is due,
hands it to the :class:`PlanWorker` and sends the newest plan's command for the current
time. It never waits for the planner: a tick costs the request building and the
bookkeeping, not the solve. The *planning process* (:class:`PlanWorker`) solves one job
at a time; a job submitted while another is being solved waits in a one-slot mailbox,
and a newer one replaces it (counted as superseded), so the planner always works on the
freshest state. A plan that comes back is applied at the next tick; the executor brakes
within the acceleration bound once the plan in force is older than ``[companion]
max_plan_age_s`` (see :mod:`companion.loop.executor`).

If the stream thread falls behind, ticks are not bunched up: the schedule restarts from
now, as a late setpoint is better than a burst of stale ones. Every setpoint's send time
is measured (:class:`StreamStats`: rate and the largest gap).
"""

from __future__ import annotations

import logging
import math
import multiprocessing
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from typing import Callable

from companion.core.planner import Planner, PlannerConfig
from companion.loop.app import Companion
from companion.loop.planning import PlanResult
from companion.loop.request_builder import ReplanJob
from companion.loop.tlog_marks import TlogMarks
from companion.mavlink.link import Link
from companion.mavlink.tlog import TlogWriter

logger = logging.getLogger(__name__)

_SETPOINT = "SET_POSITION_TARGET_LOCAL_NED"
_WORKER_JOIN_S = 2.0
_MAX_BACKLOG = 2000            # obstacle messages waiting; beyond, the oldest are dropped
_MIN_OBSTACLE_MESSAGES = 5     # obstacle messages handled per loop even when a tick is due


@dataclass
class WorkerStats:
    """What the planning process did (counted by the stream side)."""

    submitted: int = 0
    solved: int = 0
    superseded: int = 0
    errors: int = 0
    max_solve_s: float = 0.0


def _serve(conn: Connection, config: PlannerConfig, make_planner: Callable[[PlannerConfig], Planner]) -> None:
    """The planning process: solve each ``(seq, request, warm_start)`` received, send ``(seq, plan, error)``."""
    planner = make_planner(config)
    conn.send("ready")
    while True:
        try:
            job = conn.recv()
        except (EOFError, OSError):
            return
        if job is None:
            return
        seq, request, warm_start = job
        try:
            conn.send((seq, planner.solve(request, warm_start=warm_start), None))
        except Exception as exc:  # a planner bug must not end the process: the stream brakes on plan age
            conn.send((seq, None, f"{type(exc).__name__}: {exc}"))


class PlanWorker:
    """A planning process behind the :class:`~companion.loop.planning.PlanningService` protocol.

    The solve runs in its own process (``spawn``), not a thread: measured on a loaded
    2-core machine, a planning *thread* starved the stream thread of the GIL (ticks up to
    365 ms, gaps up to 442 ms, 15 Hz; see ``docs/REALTIME.md``). One job is in flight at a
    time; a job submitted meanwhile waits in a one-slot mailbox and a newer one replaces it.
    A job is sent only when the process is idle (blocked in ``recv``), so sending never
    waits on a solve. The process is forked where the platform allows (it starts at once,
    with everything imported); it says when its planner is built (:meth:`wait_ready`),
    and jobs wait in the mailbox until then.

    Parameters
    ----------
    config : PlannerConfig
        The planner's settings (the process builds its own planner from them).
    make_planner : callable, optional
        ``make_planner(config)`` builds the process's planner (default
        :class:`~companion.core.planner.Planner`); a module-level callable (it is pickled).
    """

    def __init__(self, config: PlannerConfig, *, make_planner: Callable[[PlannerConfig], Planner] = Planner) -> None:
        self.planner = Planner(config)  # the stream side's copy: only its vehicle model (``lag``) is read
        self.stats = WorkerStats()
        # fork (where there is one) starts at once with everything imported; spawn re-imports (seconds under load)
        methods = multiprocessing.get_all_start_methods()
        ctx = multiprocessing.get_context("fork" if "fork" in methods else "spawn")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_serve, args=(child, config, make_planner), name="companion-planner", daemon=True)
        self._proc.start()
        child.close()
        self._in_flight: ReplanJob | None = None
        self._pending: ReplanJob | None = None
        self._dead = False
        self._ready = False

    def wait_ready(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` for the process to have built its planner; True when it has."""
        if not self._ready and not self._dead and self._poll(timeout_s):
            try:
                self._ready = self._conn.recv() == "ready"
            except (EOFError, OSError) as exc:
                self._die(f"planner process failed to start: {exc}")
        return self._ready

    @property
    def busy(self) -> bool:
        """A job is being solved or waiting."""
        return self._in_flight is not None or self._pending is not None

    def submit(self, job: ReplanJob) -> None:
        """Send ``job`` if the process is idle, else keep it (replacing a waiting one)."""
        self.stats.submitted += 1
        if self._in_flight is None and self.wait_ready(0.0):
            self._send(job)
            return
        if self._pending is not None:
            self.stats.superseded += 1
            logger.debug("replan %d superseded by %d before the planner took it", self._pending.seq, job.seq)
        self._pending = job

    def collect(self) -> list[PlanResult]:
        """Plans finished since the last call (never blocks)."""
        done: list[PlanResult] = []
        if not self._start(0.0):
            return done
        while self._in_flight is not None and not self._dead and self._poll(0.0):
            try:
                seq, plan, error = self._conn.recv()
            except (EOFError, OSError) as exc:
                self._die(f"planner process gone: {exc}")
                break
            job, self._in_flight = self._in_flight, None
            if plan is None:
                self.stats.errors += 1
                logger.error("planner failed on replan %d: %s", seq, error)
            else:
                self.stats.solved += 1
                self.stats.max_solve_s = max(self.stats.max_solve_s, float(plan.solve_time_s))
                done.append(PlanResult(job, plan))
            if self._pending is not None:
                job, self._pending = self._pending, None
                self._send(job)
        return done

    def wait_for_result(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` for the job in flight to finish (for tests; the loop never calls it)."""
        return self._start(timeout_s) and self._in_flight is not None and self._poll(timeout_s)

    def _start(self, timeout_s: float) -> bool:
        """Once the process is ready, send the job that waited for it; whether it is ready."""
        if self._ready:
            return True
        if not self.wait_ready(timeout_s):
            return False
        if self._pending is not None and self._in_flight is None:
            job, self._pending = self._pending, None
            self._send(job)
        return True

    def close(self, timeout_s: float = _WORKER_JOIN_S) -> None:
        """Stop the process: ask it to end, wait up to ``timeout_s``, then terminate it."""
        if not self._dead and self._in_flight is None:
            try:
                self._conn.send(None)
            except OSError:
                pass
        self._proc.join(timeout_s if self._in_flight is None else 0.0)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(timeout_s)
        self._conn.close()
        self._dead = True

    def __enter__(self) -> "PlanWorker":
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    def _send(self, job: ReplanJob) -> None:
        if self._dead:
            return
        try:
            self._conn.send((job.seq, job.request, job.warm_start))
        except OSError as exc:
            self._die(f"cannot send to the planner process: {exc}")
            return
        self._in_flight = job

    def _poll(self, timeout_s: float) -> bool:
        try:
            return self._conn.poll(timeout_s)
        except (EOFError, OSError):
            return True  # recv() reports it

    def _die(self, why: str) -> None:
        logger.error("%s; no more plans (the stream brakes)", why)
        self.stats.errors += 1
        self._dead = True
        self._in_flight = self._pending = None


@dataclass
class StreamStats:
    """What the stream thread did, measured on its clock (s).

    ``setpoint_gaps_s`` holds every gap between consecutive setpoints while streaming
    (bounded by the run's length at the setpoint rate).
    """

    ticks: int = 0
    late_ticks: int = 0
    wall_s: float = 0.0
    setpoints: int = 0
    first_setpoint_s: float | None = None
    last_setpoint_s: float | None = None
    setpoint_gaps_s: list = field(default_factory=list)
    max_tick_s: float = 0.0
    inbound_dropped: int = 0
    inbound_superseded: int = 0
    inbound_backlog_at_end: int = 0

    def note_setpoint(self, t_s: float) -> None:
        if self.last_setpoint_s is not None:
            self.setpoint_gaps_s.append(t_s - self.last_setpoint_s)
        if self.first_setpoint_s is None:
            self.first_setpoint_s = t_s
        self.last_setpoint_s = t_s
        self.setpoints += 1

    def summary(self, gap_limit_s: float = 0.15) -> dict:
        """Rate (Hz), largest gap (ms), gaps over ``gap_limit_s``, the longest tick (ms)."""
        span = (self.last_setpoint_s or 0.0) - (self.first_setpoint_s or 0.0)
        gaps = self.setpoint_gaps_s
        return {
            "ticks": self.ticks,
            "late_ticks": self.late_ticks,
            "setpoints": self.setpoints,
            "setpoint_rate_hz": round((self.setpoints - 1) / span, 2) if span > 0 else None,
            "setpoint_gap_max_ms": round(max(gaps) * 1e3, 1) if gaps else None,
            "setpoint_gaps_over_150ms": sum(g > gap_limit_s for g in gaps),
            "tick_max_ms": round(self.max_tick_s * 1e3, 1),
            "inbound_dropped": self.inbound_dropped,
            "inbound_superseded": self.inbound_superseded,
        }


def _keep_newest_per_source(queue: deque) -> int:
    """Drop every waiting message that a newer one of the same kind from the same source supersedes.

    A source is (link, system, component) and a kind the message type; the survivors keep
    their order. Returns how many were dropped. Run when the obstacle queue backs up: a
    loop slowed by load (measured on PX4 SITL on a loaded 2-core machine: five obstacle
    messages handled per loop, 30 arriving per second) would otherwise fall further and
    further behind, and the tracks would be seconds old (the backlog reached 3 s).
    """
    seen: set = set()
    keep: list = []
    for rx in reversed(queue):
        key = (rx.link, rx.msg.get_srcSystem(), rx.msg.get_srcComponent(), rx.msg.get_type())
        if key not in seen:
            seen.add(key)
            keep.append(rx)
    dropped = len(queue) - len(keep)
    if dropped:
        queue.clear()
        queue.extend(reversed(keep))
    return dropped


def run_realtime(
    companion: Companion,
    link: Link,
    *,
    duration_s: float | None = None,
    stop: Callable[[Companion], bool] | None = None,
    clock: Callable[[], float] = time.time,
    sleep: Callable[[float], None] = time.sleep,
    poll_period_s: float = 0.002,
    tlog: TlogWriter | None = None,
    obstacle_links: Sequence[Link] = (),
) -> StreamStats:
    """Run the companion against a live link until ``duration_s`` passes or ``stop(companion)``.

    The companion should plan through a :class:`PlanWorker` (``Companion(...,
    planning=worker)``); with inline planning a tick lasts as long as a solve.

    Inbound messages wait in two queues: the autopilot's (and every HEARTBEAT) and the
    rest (obstacle traffic). Each loop handles all of the first and as many of the rest as
    fit before the next tick is due (at least ``_MIN_OBSTACLE_MESSAGES``), so a flood of
    obstacle reports delays neither the setpoints nor the drone's own estimate. When more
    than that wait, only the newest message of each kind from each source is kept (the
    others counted in ``StreamStats.inbound_superseded``), so the tracks never lag behind
    a loop slowed by load; past ``_MAX_BACKLOG`` waiting obstacle messages the oldest are
    dropped and counted (``StreamStats.inbound_dropped``). The tlog is written here, in the order the
    companion handled the messages (each stamped with its arrival), so a replay feeds
    them in that order and reproduces the commands; open the link without a tlog.

    Parameters
    ----------
    companion : the control loop.
    link : an open link (its clock should be ``clock`` so receive stamps and ticks agree).
    duration_s : wall seconds to run; None runs until ``stop`` or KeyboardInterrupt.
        The loop ends at the first poll after it (a tick never waits for the planner).
    stop : checked after every tick.
    clock, sleep : injectable for tests.
    tlog : record every message handled and every packet sent.
    obstacle_links : receive-only links carrying traffic (their messages reach the companion
        tagged with the link's name, in the obstacle queue; nothing is ever sent on them).

    The tlog also gets the marks a replay needs (:mod:`companion.loop.tlog_marks`): each
    tick's time, and the link of each message from an obstacle link.
    """
    if duration_s is not None and not (math.isfinite(duration_s) and duration_s >= 0.0):
        raise ValueError(f"duration_s must be finite seconds >= 0, got {duration_s!r}")
    period = 1.0 / companion.loop.setpoint_rate_hz
    stats = StreamStats()
    vehicle: deque = deque()
    others: deque = deque()

    marks = TlogMarks(tlog, link.key) if tlog is not None else None

    def handle(rx) -> None:
        companion.handle(rx)
        if tlog is not None:
            marks.received(rx.t_s, rx.link)
            tlog.write(rx.t_s, rx.raw)

    start = clock()
    next_tick = start
    while True:
        now = clock()
        if duration_s is not None and now - start >= duration_s:
            break
        autopilot = companion.autopilot
        for rx in link.poll():
            first = rx.msg.get_type() == "HEARTBEAT" or (autopilot is not None and rx.msg.get_srcSystem() == autopilot[0])
            (vehicle if first else others).append(rx)
        for obstacle_link in obstacle_links:  # obstacle traffic only: never ahead of the autopilot
            others.extend(obstacle_link.poll())
        if len(others) > _MIN_OBSTACLE_MESSAGES:  # falling behind: only each source's newest report is news
            stats.inbound_superseded += _keep_newest_per_source(others)
        while len(others) > _MAX_BACKLOG:
            others.popleft()
            stats.inbound_dropped += 1
        while vehicle:
            handle(vehicle.popleft())
        link.peer = companion.autopilot  # commands go to the autopilot's address only
        handled = 0
        while others and (handled < _MIN_OBSTACLE_MESSAGES or clock() < next_tick):
            handle(others.popleft())
            handled += 1
        now = clock()
        if now >= next_tick:
            if marks is not None:
                marks.tick(now)
            outbox = companion.tick(now)
            for msg in outbox:
                packet = link.send(msg, t_s=now)  # stamped with the tick time: replay ticks at the same times
                if tlog is not None:
                    tlog.write(now, packet)
            if outbox and outbox[-1].get_type() == _SETPOINT:
                stats.note_setpoint(now)
            stats.ticks += 1
            stats.max_tick_s = max(stats.max_tick_s, clock() - now)
            next_tick += period
            if next_tick < now:
                stats.late_ticks += 1
                next_tick = now + period
            if stop is not None and stop(companion):
                break
        if not others:
            sleep(max(0.0, min(poll_period_s, next_tick - clock())))
    stats.wall_s = clock() - start
    stats.inbound_backlog_at_end = len(others)
    return stats
