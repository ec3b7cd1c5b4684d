"""The real-time edge: wall clock, sleeping, a real link and the planning worker around the pure :class:`Companion`.

Two processes. The *stream* (the caller of :func:`run_realtime`, one thread) polls the
links whenever one has bytes, at most once every 2 ms, and sleeps otherwise
(:mod:`companion.realtime.link_wait`; inbound messages are stamped by the link's clock when
they are read), and ticks the companion at its setpoint rate. It is a scheduler over the loop's
:class:`~companion.loop.driver.Driver`, which does what each call means (handle and answer a
message, tick, send, record the tlog and its marks through a
:class:`~companion.realtime.tlog_marks.TlogRecorder`); the stream decides only when, from the
wall clock and the obstacle budget. A tick builds a replan's request when one is due,
hands it to the :class:`PlanWorker` and sends the newest plan's command for the current
time. It never waits for the planner: a tick costs the request building and the
bookkeeping, not the solve. The *planning process* (:class:`PlanWorker`) solves one job
at a time, and the loop builds a request only when it is free (:attr:`PlanWorker.busy`),
so every solve starts from the freshest state; a job submitted before the process is
ready waits in a one-slot mailbox (a newer one replaces it, counted as superseded).
A plan that comes back is applied at the next tick; the executor brakes
within the acceleration bound once the plan in force is older than ``[companion]
max_plan_age_s`` (see :mod:`companion.loop.executor`).

If the stream thread falls behind, ticks are not bunched up: the schedule restarts from
now, as a late setpoint is better than a burst of stale ones. Every setpoint's send time
is measured (:class:`StreamStats`: rate and the largest gap).

(About 400 lines: the stream loop, the planning process it feeds and what both measure
are one mechanism; the obstacle backlog, the largest gap's probe and the stream's CPU
priority are their own modules: :mod:`companion.realtime.backlog`,
:mod:`companion.realtime.gap_probe`, :mod:`companion.realtime.stream_priority`.)
"""

from __future__ import annotations

import contextlib
import gc
import logging
import math
import multiprocessing
import os
import signal
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from typing import Callable

from companion.core import jit
from companion.core.planner import Planner, PlannerConfig
from companion.loop.app import Companion
from companion.realtime.backlog import ObstacleBacklog
from companion.realtime.collector import collector_for_real_time
from companion.realtime.gap_probe import GapProbe
from companion.realtime.link_wait import LinkWait
from companion.loop.planning import PlanResult
from companion.loop.request_builder import ReplanJob
from companion.realtime.tlog_marks import TlogRecorder
from companion.loop.driver import Driver
from companion.errors import LinkError
from companion.mavlink.link import Link
from companion.mavlink.tlog import TlogWriter

logger = logging.getLogger(__name__)

_WORKER_JOIN_S = 2.0
_ORPHAN_CHECK_S = 1.0          # how often an idle planning process checks that the stream is alive
_MAX_BACKLOG = 2000            # obstacle sources waiting; beyond, the longest-waiting is dropped
#: Default share of each setpoint period the stream may spend handling obstacle reports.
OBSTACLE_SHARE = 0.1


@dataclass
class WorkerStats:
    """What the planning process did (counted by the stream side)."""

    submitted: int = 0
    solved: int = 0
    superseded: int = 0
    errors: int = 0
    max_solve_s: float = 0.0
    max_send_s: float = 0.0      #: longest hand-over of a job to the process (wall, the stream's side)
    max_receive_s: float = 0.0   #: longest read of a finished plan (wall, the stream's side)


def _serve(conn: Connection, config: PlannerConfig, make_planner: Callable[[PlannerConfig], Planner]) -> None:
    """The planning process: solve each ``(seq, request, warm_start)`` received, send ``(seq, plan, error)``.

    Ctrl-C in a terminal signals the whole foreground process group, and systemd's default
    stop signals the whole service (SIGTERM): the process ignores both, and the stream side,
    which hands the vehicle back first (replanning meanwhile), ends it (``None``, or SIGKILL). A
    forked process holds both ends of the pipe, so it would never see the stream's end close:
    it checks every :data:`_ORPHAN_CHECK_S` whether its parent is still the stream.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    planner = make_planner(config)
    jit.warm_up()    # compile the planner's kernels (or load them from their cache) before the first replan
    gc.freeze()  # what exists now is never walked again: a full collection would add ~100 ms to a solve
    conn.send("ready")
    parent = os.getppid()
    while True:
        try:
            if not conn.poll(_ORPHAN_CHECK_S):
                if os.getppid() != parent:  # the stream's process died without a word (SIGKILL): end too
                    return
                continue
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

    The solve runs in its own process, not a thread: measured on a loaded
    2-core machine, a planning *thread* starved the stream thread of the GIL (ticks up to
    365 ms, gaps up to 442 ms, 15 Hz; see ``docs/REALTIME.md``). One job is in flight at a
    time (the loop submits only when :attr:`busy` is False); a job submitted meanwhile
    waits in a one-slot mailbox and a newer one replaces it.
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

    asynchronous = True  #: a plan is collected at whatever tick finds it back, the asking one included

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
        # The stream side runs the same compiled overlap kernel (the request builder's realised
        # contour of touch): load it now, while the planning process loads its own, so the
        # first request does not stall the setpoint stream for the load (0.7 s measured).
        jit.warm_up()
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
    def pid(self) -> int | None:
        """The planning process's id (None before it started)."""
        return self._proc.pid

    @property
    def busy(self) -> bool:
        """A job is being solved or waiting, or its answer has not been collected."""
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
            started = time.perf_counter()
            try:
                seq, plan, error = self._conn.recv()
            except (EOFError, OSError) as exc:
                self._die(f"planner process gone: {exc}")
                break
            self.stats.max_receive_s = max(self.stats.max_receive_s, time.perf_counter() - started)
            job, self._in_flight = self._in_flight, None
            if plan is None:
                self.stats.errors += 1
                logger.error("planner failed on replan %d: %s", seq, error)
                done.append(PlanResult(job, None))  # handed back so the loop knows the planner is free
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
        """Stop the process: ask it to end, wait up to ``timeout_s``, then kill it."""
        if not self._dead and self._in_flight is None:
            try:
                self._conn.send(None)
            except OSError:
                pass
        self._proc.join(timeout_s if self._in_flight is None else 0.0)
        if self._proc.is_alive():
            self._proc.kill()  # it ignores SIGTERM (see _serve)
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
        started = time.perf_counter()
        try:
            self._conn.send((job.seq, job.request, job.warm_start))
        except OSError as exc:
            self._die(f"cannot send to the planner process: {exc}")
            return
        self.stats.max_send_s = max(self.stats.max_send_s, time.perf_counter() - started)
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


class AutopilotPort:
    """The real-time driver's :class:`~companion.loop.driver.Port`: the autopilot link, addressed to
    the autopilot the companion follows (a ``udpin`` link answers that one address only)."""

    def __init__(self, link: Link, companion: Companion) -> None:
        self.link, self.companion = link, companion

    def send(self, msg, t_s: float) -> bytes:
        """Send ``msg`` stamped with link time ``t_s`` (s) in the link's own tlog, if it has one."""
        link = self.link
        link.peer = self.companion.autopilot  # commands go to the autopilot's address only
        return link.send(msg, t_s=t_s)


class FleetPort:
    """The real-time driver's fleet :class:`~companion.loop.driver.Port`: every fleet link that can
    send to all it hears (``udpout``, broadcast, serial; a ``udpin`` link only listens), under the
    vehicle's system id and component 191 (onboard computer) once the vehicle is known; before
    that nothing is announced. A failed send is counted, never raised into the stream."""

    COMPONENT = 191

    def __init__(self, links: Sequence[Link], companion: Companion) -> None:
        self.links, self.companion = tuple(links), companion
        self.sent = 0
        self.failed = 0

    def send(self, msg, t_s: float) -> bytes | None:
        autopilot = self.companion.autopilot
        if autopilot is None:
            return None
        packet = None
        for link in self.links:
            if link.key != (autopilot[0], self.COMPONENT):
                link.set_source(autopilot[0], self.COMPONENT)
            if link.listens_only:
                continue
            try:
                packet = link.send(msg, t_s=t_s)
                self.sent += 1
            except LinkError as exc:
                self.failed += 1
                logger.debug("fleet link %r: %s", link, exc)
        return packet


def _signatures_rejected(links: Sequence[Link]) -> int:
    """Packets the links dropped for a bad or missing signature (a stand-in link without counters: 0)."""
    return sum(getattr(getattr(link, "stats", None), "signature_rejected", 0) for link in links)


@dataclass
class StreamStats:
    """What the stream thread did, measured on its clock (s).

    The gaps between consecutive setpoints are summed as they come (the largest, when it
    ended, how many exceeded ``gap_limit_s``), so a long flight holds no list of them;
    ``probe`` says where the largest one's time went (:mod:`companion.realtime.gap_probe`).
    """

    ticks: int = 0
    late_ticks: int = 0
    wall_s: float = 0.0
    setpoints: int = 0
    first_setpoint_s: float | None = None
    last_setpoint_s: float | None = None
    gap_limit_s: float = 0.15
    setpoint_gap_max_s: float | None = None
    setpoint_gap_max_end_s: float | None = None   #: when the largest gap ended (the stream's clock, s)
    setpoint_gaps_over_limit: int = 0
    max_tick_s: float = 0.0
    inbound_dropped: int = 0
    inbound_backlog_at_end: int = 0
    inbound_superseded: int = 0
    obstacle_handling_s: float = 0.0
    obstacles_handled_max: int = 0
    cpu_s: float = 0.0
    collections: int = 0
    max_collection_s: float = 0.0
    probe: GapProbe = field(default_factory=GapProbe)
    waits_on_links: bool = False    #: waits between polls end when a link is readable (:mod:`~companion.realtime.link_wait`)
    loops: int = 0                  #: passes of the loop (poll, maybe a tick, obstacle traffic, wait)

    def note_setpoint(self, t_s: float) -> None:
        gap = None if self.last_setpoint_s is None else t_s - self.last_setpoint_s
        self.probe.setpoint(gap)
        if gap is not None:
            if self.setpoint_gap_max_s is None or gap > self.setpoint_gap_max_s:
                self.setpoint_gap_max_s, self.setpoint_gap_max_end_s = gap, t_s
            self.setpoint_gaps_over_limit += gap > self.gap_limit_s
        if self.first_setpoint_s is None:
            self.first_setpoint_s = t_s
        self.last_setpoint_s = t_s
        self.setpoints += 1

    def summary(self) -> dict:
        """Rate (Hz), largest gap (ms), gaps over ``gap_limit_s``, the longest tick (ms)."""
        span = (self.last_setpoint_s or 0.0) - (self.first_setpoint_s or 0.0)
        gap_max = self.setpoint_gap_max_s
        return {
            "ticks": self.ticks,
            "late_ticks": self.late_ticks,
            "setpoints": self.setpoints,
            "setpoint_rate_hz": round((self.setpoints - 1) / span, 2) if span > 0 else None,
            "setpoint_gap_max_ms": round(gap_max * 1e3, 1) if gap_max is not None else None,
            # when the largest gap ended, seconds after the first setpoint
            "setpoint_gap_max_at_s": (round(self.setpoint_gap_max_end_s - self.first_setpoint_s, 2)
                                      if gap_max is not None else None),
            f"setpoint_gaps_over_{round(self.gap_limit_s * 1e3)}ms": self.setpoint_gaps_over_limit,
            "tick_max_ms": round(self.max_tick_s * 1e3, 1),
            "gc_collections": self.collections,
            "gc_pause_max_ms": round(self.max_collection_s * 1e3, 1),
            "inbound_dropped": self.inbound_dropped,
            "inbound_superseded": self.inbound_superseded,
            "obstacle_handling_share": round(self.obstacle_handling_s / self.wall_s, 3) if self.wall_s > 0 else None,
            "stream_cpu_share": round(self.cpu_s / self.wall_s, 3) if self.wall_s > 0 else None,
            "stream_waits_on_links": self.waits_on_links,
            "stream_loops_per_s": round(self.loops / self.wall_s, 1) if self.wall_s > 0 else None,
            # the largest gap's CPU time, run-queue wait, context switches and longest loop step
            "setpoint_gap_max_detail": self.probe.largest,
        }


def run_realtime(
    companion: Companion,
    link: Link,
    *,
    duration_s: float | None = None,
    stop: Callable[[Companion, float], bool] | None = None,
    clock: Callable[[], float] = time.time,
    sleep: Callable[[float], None] = time.sleep,
    poll_period_s: float = 0.002,
    tlog: TlogWriter | None = None,
    obstacle_links: Sequence[Link] = (),
    obstacle_share: float = OBSTACLE_SHARE,
    after_tick: Callable[[Companion, float, list], None] | None = None,
    fleet_links: Sequence[Link] = (),
) -> StreamStats:
    """Run the companion against a live link until ``duration_s`` passes or ``stop(companion)``.

    The companion should plan through a :class:`PlanWorker` (``Companion(...,
    planning=worker)``); with inline planning a tick lasts as long as a solve.

    Each loop polls the links, handles every message of the autopilot (and every
    HEARTBEAT) at once, ticks when a tick is due, and then spends on obstacle traffic at
    most ``obstacle_share`` of a setpoint period per period, never past the next tick's
    time (one report per period at least, so intake never stops). Obstacle traffic waits
    in an :class:`~companion.realtime.backlog.ObstacleBacklog`: the newest report of each
    source, so an overloaded stream fuses every obstacle's freshest report in turn and
    neither the setpoints nor the drone's own estimate ever wait for obstacle reports.
    Reports replaced by a newer one or pushed out of the backlog are counted
    (``StreamStats.inbound_superseded``, ``inbound_dropped``). The tlog is written by
    the driver's recorder, in the order the companion handled the messages (each stamped
    with its arrival), so a replay feeds them in that order and reproduces the commands;
    open the link without a tlog.

    Parameters
    ----------
    companion : the control loop.
    link : an open link (its clock should be ``clock`` so receive stamps and ticks agree).
    duration_s : wall seconds to run; None runs until ``stop`` or KeyboardInterrupt.
        The loop ends at the first poll after it (a tick never waits for the planner).
    stop : ``stop(companion, t_s)`` is checked after every tick (link time ``t_s``, s); True ends the run.
    clock, sleep : injectable for tests.
    tlog : record every message handled and every packet sent.
    obstacle_links : receive-only links carrying traffic (their messages reach the companion
        tagged with the link's name, in the obstacle backlog; nothing is ever sent on them).
    obstacle_share : fraction of each setpoint period (0, 1] the stream may spend handling
        obstacle traffic (measured on ``clock``).
    after_tick : ``after_tick(companion, t_s, outbox)`` after each tick's packets are sent (a
        view, :mod:`companion.view`; it must not block: it counts in ``tick_max_ms``).
    fleet_links : the fleet's links (``companion fly --fleet``, a companion built with
        ``fleet=True``): what arrives on them waits in the obstacle backlog like traffic; each
        tick's :attr:`Companion.fleet_outbox` goes out on them (:class:`FleetPort`).

    The tlog also gets the marks a replay needs (:mod:`companion.realtime.tlog_marks`): each
    tick's time, the links' signature-rejection count, the plans each tick collected, and
    the link of each message from an obstacle link.
    """
    if duration_s is not None and not (math.isfinite(duration_s) and duration_s >= 0.0):
        raise ValueError(f"duration_s must be finite seconds >= 0, got {duration_s!r}")
    if not (math.isfinite(obstacle_share) and 0.0 < obstacle_share <= 1.0):
        raise ValueError(f"obstacle_share must be in (0, 1], got {obstacle_share!r}")
    period = 1.0 / companion.settings.setpoint_rate_hz
    stats = StreamStats()
    others = ObstacleBacklog(_MAX_BACKLOG)

    driver = Driver(companion, AutopilotPort(link, companion),
                    TlogRecorder(tlog, link.key) if tlog is not None else None,
                    fleet_port=FleetPort(fleet_links, companion) if fleet_links else None)
    links = (link, *obstacle_links, *fleet_links)
    receive_only = (*obstacle_links, *fleet_links)

    start, cpu_start = clock(), time.process_time()
    next_tick = start
    budget_s = obstacle_share * period  # obstacle handling left in this period
    handled_in_period = 0
    waiter = LinkWait(links, sleep, poll_period_s)  # between polls: asleep until a link has bytes or a tick is due
    stats.waits_on_links = waiter.on_descriptors
    with collector_for_real_time() as pauses, contextlib.closing(waiter):  # a full collection of the startup heap stopped the stream ~100 ms
        while True:
            now = clock()
            if duration_s is not None and now - start >= duration_s:
                break
            step_start = now
            stats.loops += 1
            for rx in link.poll():  # the autopilot's messages at once (its first HEARTBEAT makes it known)
                autopilot = companion.autopilot
                if rx.msg.get_type() == "HEARTBEAT" or (autopilot is not None and rx.msg.get_srcSystem() == autopilot[0]):
                    driver.receive(rx)
                else:
                    others.put(rx)
            for obstacle_link in receive_only:  # traffic and the fleet: never ahead of the autopilot
                for rx in obstacle_link.poll():
                    others.put(rx)
            now = clock()
            stats.probe.step("poll", now - step_start)
            if now >= next_tick:
                stats.probe.tick_started()
                outbox = driver.tick(now, _signatures_rejected(links))
                if driver.streamed:
                    stats.note_setpoint(now)
                if after_tick is not None:
                    after_tick(companion, now, outbox)
                stats.ticks += 1
                tick_s = clock() - now
                stats.max_tick_s = max(stats.max_tick_s, tick_s)
                stats.probe.step("tick", tick_s)
                next_tick += period
                if next_tick < now:
                    stats.late_ticks += 1
                    next_tick = now + period
                budget_s, handled_in_period = obstacle_share * period, 0
                ended = stop is not None and stop(companion, now)
                driver.mark_hand_backs()  # asked from outside the loop (a signal, the end of the run)
                if ended:
                    break
            t_prev = clock()
            while others and budget_s > 0.0 and (t_prev < next_tick or handled_in_period == 0):
                driver.receive(others.take())
                handled_in_period += 1
                t_now = clock()
                budget_s -= t_now - t_prev
                stats.obstacle_handling_s += t_now - t_prev
                stats.probe.step("obstacle report", t_now - t_prev)
                t_prev = t_now
            stats.obstacles_handled_max = max(stats.obstacles_handled_max, handled_in_period)
            t_prev = clock()
            waiter.wait(next_tick - t_prev)
            stats.probe.step("sleep", clock() - t_prev)
    stats.wall_s = clock() - start
    stats.cpu_s = time.process_time() - cpu_start
    stats.collections, stats.max_collection_s = pauses.collections, pauses.max_pause_s
    stats.inbound_backlog_at_end = len(others)
    stats.inbound_dropped = others.dropped
    stats.inbound_superseded = others.superseded
    return stats
