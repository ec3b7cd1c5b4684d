"""Replay a MAVLink tlog through the companion's estimator and planner, in log time.

(About 700 lines: one job, rebuilding the recorded ticks and comparing the commands, in
the steps :func:`replay` lists; the stand-ins for the live edge are in
:mod:`companion.offline.replay_stand_ins`.)

:func:`replay` reads a tlog (:func:`companion.mavlink.tlog.read_tlog`), feeds every *inbound*
message (from any source other than the companion's own (system, component), by
default (1, 191): the autopilot, obstacle systems, a ground station) to a fresh
:class:`~companion.loop.app.Companion` and ticks it at the link times at which the recorded
companion ticked, through the same :class:`~companion.loop.driver.Driver` as the live
edges (its port, :class:`~companion.offline.replay_stand_ins.CollectingPort`, keeps what
would be sent, to compare with the recording). It reads no clock: a replay takes as
long as the computation, not the flight.

Two kinds of log
----------------
*Compare* (the log holds the companion's own packets, source (1, 191)). The recorded
ticks are rebuilt from the outbound records: a tick is a run of consecutive outbound
records with no inbound record between them, ended by its SET_POSITION_TARGET_LOCAL_NED
(the last message of a streaming tick), and its time is the stamp of its first record.
Ticks that sent nothing (the companion ticks at ``setpoint_rate_hz`` from its first tick
on, and a tick that is not streaming and not due a HEARTBEAT sends nothing) are put back
on the setpoint-rate grid between recorded ticks (never between two ticks that both sent a
setpoint: a streaming companion sends one every tick, so a wider gap there is a tick that
ran late in real time) and after the last one up to the end of the log, each after the
inbound records stamped up to its time. Each replayed setpoint is compared with the recorded one of the same tick.

*Marked* (a log from ``companion fly``, whose real-time loop marks its tlog, see
:mod:`companion.realtime.tlog_marks`). Every tick is marked, those that sent nothing too, and
every message that came on an obstacle link is marked with that link: the replay ticks
exactly where the recording did and feeds each message on its own link, inferring
nothing. Older logs without marks are replayed by the rules above; a real-time one then
agrees only as far as its silent ticks fall on the grid (the loop's jitter moves them)
and its links are guessed right (:func:`companion.loop.intake.obstacles.replay_link`).

*What-if* (no companion packets: mavsim's own ``--tlog``, a MAVProxy or QGroundControl
log). The companion ticks at its setpoint rate over the log's duration, and since no
vehicle in such a log ever accepted our OFFBOARD request, the offboard sequence is
replaced by a stand-in that counts as engaged from the first PX4 HEARTBEAT on: the
result is what the companion would have commanded, replanning from the vehicle's real
(logged) state each cycle. The vehicle did not follow those commands, so they are an
open-loop answer to "what would it have done here", not a prediction of a flight.

Time base
---------
The companion runs on *link time*: Unix time on a real link, simulated time in lockstep.
A lockstep tlog is stamped ``LOCKSTEP_EPOCH_S + simulated time``
(:data:`companion.offline.harness.LOCKSTEP_EPOCH_S`, see :class:`~companion.mavlink.link.MemoryLink`), so
the replay subtracts that offset. ``time_offset_s=None`` detects it: a log whose first
stamp lies within one day after ``LOCKSTEP_EPOCH_S`` (2024-01-01) is a lockstep log;
otherwise the offset is 0 (pass ``time_offset_s`` to override). Times are handled in
integer microseconds (the tlog's resolution) and converted as ``us * 1e-6``, the same
expression ``mavsim`` uses for its clock, so a lockstep log replays with bit-identical
times and therefore bit-identical commands. For a real-time log the recorded stamps are
the link's clock when each packet was sent (a few microseconds after the tick's own
clock reading), so its replay agrees only to that timing.

Plans in real time. ``companion fly`` plans in a process beside the stream, so a plan
is applied at the tick that collects it, usually some ticks after its request; the tlog
marks that tick (``plan_in``, also when it is the request's own; ``plan_lost`` for a job that
came back without a plan; :mod:`companion.realtime.tlog_marks`). Logs from before those marks
carry the same numbers as NAMED_VALUE_FLOAT ``plan_seq`` / ``plan_lost`` among the tick's
packets, which the replay takes out of the tick before comparing. A log with either is
replayed with :class:`~companion.offline.replay_stand_ins.RecordedArrivals`: each plan is
solved when its arrival comes and applied at that tick, so a real-time log reproduces its
commands exactly. Lockstep logs have none: plans apply at their request's tick.

Signatures. Packets the links rejected for their signature never reach the tlog; the
companion's count of them is marked (``sig_reject``) and handed to the replayed companion
before the same tick. Logs from before that mark give it only in the companion's
STATUSTEXT announcing it, which the replay then reads.

Comparison. SET_POSITION_TARGET_LOCAL_NED carries float32 velocities, so the replayed
velocities are rounded to float32 exactly as packing would before they are compared:
an exact reproduction gives a difference of 0.0, and any real discrepancy shows.
"""

from __future__ import annotations

import logging
import math
import os
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink.autopilots import DIALECT

from companion.mavlink import messages
from companion.mavlink.mission_protocol import CLIENT_ANSWERS
from companion.core.planner import Planner
from companion.loop.app import Companion
from companion.loop.driver import Driver
from companion.offline.replay_stand_ins import (AssumeEngaged, CollectingPort, RecordedArrivals, arrivals,
                                                is_legacy_plan_note, signatures_rejected)
from companion.loop.records import status_counts
from companion.errors import CompanionError
from companion.mavlink.link import DEFAULT_SOURCE_COMPONENT, DEFAULT_SOURCE_SYSTEM, Received
from companion.mavlink.offboard import OffboardConfig
from companion.loop.config import load_scenario
from companion.mavlink.tlog import read_tlog
from companion.offline.harness import LOCKSTEP_EPOCH_S
from companion.loop.intake.obstacles import replay_link
from companion.loop.intake.traffic_config import FLEET_LINK
from companion.realtime.tlog_marks import (HAND_BACK, HAND_BACK_REASONS, LEGACY_PLAN_ARRIVED, LEGACY_PLAN_LOST, PLAN_IN,
                                       PLAN_LOST, RX_LINK, SIGNATURES_REJECTED, TICK, link_name, mark_of)
from companion.loop.intake.traffic_config import AUTOPILOT_LINK

logger = logging.getLogger(__name__)

_SETPOINT = "SET_POSITION_TARGET_LOCAL_NED"
_US = 1_000_000
_LOCKSTEP_WINDOW_S = 86_400.0  # a lockstep log's first stamp lies within a day after LOCKSTEP_EPOCH_S


class ReplayError(CompanionError, ValueError):
    """A log cannot be replayed (no vehicle in it, bad arguments); the message names the file."""


@dataclass
class ReplayResult:
    """What a replay did and how it compares with the recording.

    Attributes
    ----------
    path, scenario_path : the tlog and the scenario file.
    mode : ``"compare"`` (the log holds the companion's commands) or ``"what-if"``.
    time_offset_s : subtracted from tlog stamps to get link time (s); ``lockstep`` says
        whether it was detected (or given) as the lockstep epoch.
    messages, inbound, outbound : valid messages read, fed to the companion, sent by it.
    duration_s : log time from the first to the last record (s).
    start_s : link time of the first record (s); the summary's times count from it.
    ticks : ticks replayed (recorded ones plus the silent ones put back on the grid).
    recorded_ticks : ticks rebuilt from the outbound records.
    commands_recorded : recorded SET_POSITION_TARGET_LOCAL_NED.
    commands_compared : recorded setpoints matched with a replayed one of the same tick.
    unmatched_commands : recorded setpoints the replay did not send, plus setpoints the
        replay sent at ticks where the recording sent none.
    tick_mismatches : recorded ticks whose message types differ from the replayed ones,
        plus silent ticks at which the replay sent something.
    max_abs_diff_mps : largest absolute difference over axes and compared setpoints (m/s,
        float32 wire values); None if nothing was compared.
    max_diff_t_s : link time (s) of the tick with that difference; ``max_diff_index`` its
        index among the compared setpoints.
    command_times_s, commands_mps : every replayed setpoint, link time (s) and NED velocity
        (m/s, float64 as computed) - (K,), (K, 3).
    recorded_commands_mps : (K, 3) recorded velocity at the same ticks (NaN where none).
    status_counts : planner status per replan (``optimal``, ``slack``, ``failed``).
    companion : the replayed :class:`Companion` (records, state) for figures and reports.
    """

    path: Path
    scenario_path: Path
    mode: str
    time_offset_s: float
    lockstep: bool
    messages: int
    inbound: int
    outbound: int
    duration_s: float
    start_s: float
    ticks: int
    recorded_ticks: int
    commands_recorded: int
    commands_compared: int
    unmatched_commands: int
    tick_mismatches: int
    max_abs_diff_mps: float | None
    max_diff_t_s: float | None
    max_diff_index: int | None
    command_times_s: np.ndarray
    commands_mps: np.ndarray
    recorded_commands_mps: np.ndarray
    status_counts: dict
    companion: Companion
    notes: list = field(default_factory=list)

    @property
    def replans(self) -> int:
        return len(self.companion.records)

    def summary(self) -> dict:
        """JSON-serialisable numbers (what ``companion replay --json`` prints); times (s) count
        from the log's first record (``start_link_s``), not from the link clock's epoch."""
        state = self.companion.state

        def since_start(t: float | None) -> float | None:
            return None if t is None else round(t - self.start_s, 6)

        return {
            "tlog": str(self.path),
            "scenario": str(self.scenario_path),
            "mode": self.mode,
            "time_offset_s": self.time_offset_s,
            "lockstep": self.lockstep,
            "messages": self.messages,
            "inbound": self.inbound,
            "outbound": self.outbound,
            "log_duration_s": round(self.duration_s, 6),
            "start_link_s": self.start_s,
            "ticks": self.ticks,
            "recorded_ticks": self.recorded_ticks,
            "replans": self.replans,
            "plan_status": dict(self.status_counts),
            "commands_replayed": int(self.command_times_s.size),
            "commands_recorded": self.commands_recorded,
            "commands_compared": self.commands_compared,
            "unmatched_commands": self.unmatched_commands,
            "tick_mismatches": self.tick_mismatches,
            "max_abs_diff_mps": self.max_abs_diff_mps,
            "max_diff_t_s": since_start(self.max_diff_t_s),
            "max_diff_index": self.max_diff_index,
            "max_commanded_speed_mps": float(np.max(np.linalg.norm(self.commands_mps, axis=1))) if self.commands_mps.size else None,
            "goal_reached_t_s": since_start(state.goal_reached_t_s),
            "braking_events": state.braking_events,
            "stale_events": state.stale_events,
            "messages_rejected": state.messages_rejected,
            "tracks": len(self.companion.tracker),
            "tracking_error": state.tracking.summary(),
            "events": [(round(t - self.start_s, 3), text) for t, text in state.events],
            "notes": list(self.notes),
        }


# --------------------------------------------------------------------------- log reading


@dataclass
class _Rec:
    t_us: int  # link time, integer microseconds
    msg: object
    raw: bytes
    link: str | None = None  # the link it came on, when the recording marked it (else inferred)


@dataclass
class _TickMark:
    t_us: int  # a tick the recording marked (companion.realtime.tlog_marks.TICK)
    arrived: list = field(default_factory=list)  # replan numbers marked PLAN_IN at this tick
    lost: list = field(default_factory=list)     # replan numbers marked PLAN_LOST at this tick
    signatures: int | None = None                # the links' count marked SIGNATURES_REJECTED before this tick
    hand_back: str | None = None                 # asked from outside after this tick, for this reason (HAND_BACK)

    def note(self, name: str, value: int) -> None:
        """A mark that belongs to this tick (written after its TICK mark)."""
        if name == PLAN_IN:
            self.arrived.append(value)
        elif name == PLAN_LOST:
            self.lost.append(value)
        elif name == SIGNATURES_REJECTED:
            self.signatures = value
        elif name == HAND_BACK:
            self.hand_back = HAND_BACK_REASONS[value] if 0 <= value < len(HAND_BACK_REASONS) else HAND_BACK_REASONS[0]


@dataclass
class _Tick:
    t_us: int
    recorded: list = field(default_factory=list)  # recorded outbound messages ([] for a silent tick)
    silent: bool = False
    arrived: list = field(default_factory=list)  # replans whose plan the recording collected at this tick
    lost: list = field(default_factory=list)     # replans that came back without a plan at this tick
    signatures: int | None = None                # the links' rejected-signature count before this tick
    hand_back: str | None = None                 # a hand-back asked from outside after this tick (its reason)

    @property
    def setpoint(self):
        return next((m for m in reversed(self.recorded) if m.get_type() == _SETPOINT), None)


def _reparse(parser: mavlink2.MAVLink, raw: bytes, fallback):
    """The message as the companion's link parses it (MAVLink 2 ``common``); ``fallback`` if it cannot."""
    try:
        msgs = parser.parse_buffer(raw) or []
    except Exception:  # robust_parsing should not raise; a log must never stop the replay
        msgs = []
    parser.buf = bytearray()
    parser.buf_index = 0
    parser.expected_length = mavlink2.HEADER_LEN_V1 + 2
    good = [m for m in msgs if m.get_type() != "BAD_DATA"]
    return good[0] if len(good) == 1 else fallback


def _has_vehicle(inbound: list[_Rec]) -> bool:
    for rec in inbound:
        if rec.msg.get_type() == "HEARTBEAT":
            hb = messages.decode(rec.msg)
            if isinstance(hb, messages.VehicleHeartbeat) and hb.is_autopilot:
                return True
    return False


def _velocity(msg) -> np.ndarray:
    return np.array([msg.vx, msg.vy, msg.vz], dtype=float)


def _wire(v: np.ndarray) -> np.ndarray:
    """Velocities as SET_POSITION_TARGET_LOCAL_NED carries them (float32)."""
    return np.asarray(v, dtype=np.float32).astype(float)


# --------------------------------------------------------------------------- replay


def replay(
    tlog_path: str | os.PathLike,
    scenario_path: str | os.PathLike,
    *,
    time_offset_s: float | None = None,
    companion_key: tuple[int, int] = (DEFAULT_SOURCE_SYSTEM, DEFAULT_SOURCE_COMPONENT),
    assume_engaged: bool | None = None,
    offboard: OffboardConfig | None = None,
    after_tick=None,
    companion_keywords: dict | None = None,
    **planner_overrides,
) -> ReplayResult:
    """Replay a tlog through a fresh companion and compare with its recorded commands.

    The steps: read the log, align its clock with link time (:func:`_align_clocks`), parse
    it into inbound records, outbound records and marks (:func:`_parse`), schedule the
    ticks among the inbound records (:func:`_schedule_ticks`), run a fresh companion
    through them (:func:`_run`), compare what it sent with the recording (:func:`_compare`)
    and report (:func:`_report`).

    Parameters
    ----------
    tlog_path : the log (any tlog pymavlink reads: companion, mavsim, MAVProxy, QGC).
    scenario_path : scenario TOML the companion flew (mission, planner, estimator, map).
    time_offset_s : seconds subtracted from tlog stamps to get the companion's link time;
        None detects a lockstep log (offset ``LOCKSTEP_EPOCH_S``) or else uses 0.
    companion_key : the companion's (system id, component id); its packets are outbound.
    assume_engaged : replace the offboard sequence with :class:`AssumeEngaged`; None does
        so exactly when the log holds no companion setpoint (what-if mode).
    offboard : engagement settings the recorded companion used (default: the scenario's).
    after_tick : ``after_tick(companion, t_s, outbox)`` after every replayed tick (a view, :mod:`companion.view`).
    companion_keywords : more :class:`Companion` keywords the recorded run was built with
        (a ``goal`` and its ``reference`` for ``--goal`` / ``--mission``).
    **planner_overrides : ``[planner]`` overrides the recorded run used (``formulation`` ...).

    Returns
    -------
    ReplayResult

    Raises
    ------
    TlogError
        Missing, empty or non-tlog file, or no valid MAVLink message in it.
    ReplayError
        No PX4 autopilot HEARTBEAT among the inbound messages, or a bad offset.
    ConfigError
        Bad scenario file or override.
    """
    path = Path(tlog_path)
    records = list(read_tlog(path))  # raises TlogError first: a bad log is the likelier mistake
    scenario = load_scenario(scenario_path, goal_elsewhere="goal" in (companion_keywords or {}), **planner_overrides)
    time_offset_s, lockstep = _align_clocks(records[0][0], time_offset_s)
    parsed = _parse(path, records, int(round(time_offset_s * _US)), companion_key)
    period_us = int(round(_US / scenario.companion.setpoint_rate_hz))  # as the harness advances mavsim: round(dt * 1e6)
    timeline = _schedule_ticks(parsed.stream, period_us)

    mode = "compare" if timeline.commands_recorded else "what-if"
    if assume_engaged is None:
        assume_engaged = mode == "what-if"
    notes = []
    if timeline.marked:
        notes.append("ticks and links as the recording marked them (companion.realtime.tlog_marks)")
    elif mode == "compare" and not lockstep:
        notes.append("real-time log: ticks are timed by their first packet's stamp (exact for logs from companion fly, which stamps packets with the tick time on a microsecond clock)")
    schedule = RecordedArrivals(Planner(scenario.planner)) if timeline.realtime_plans else None
    if timeline.legacy_plans:
        notes.append("plans applied at the ticks the recording announced their arrival on the wire "
                     "(NAMED_VALUE_FLOAT plan_seq: a log from before the plan marks; real-time planning)")
    elif timeline.realtime_plans:
        notes.append("plans applied at the ticks the recording marked their arrival (real-time planning)")
    keywords = dict(companion_keywords or {})
    if any(getattr(rec, "link", None) == FLEET_LINK for _, rec in parsed.stream):
        keywords.setdefault("fleet", True)   # flown in a fleet: the peers' intents it heard are used again
        notes.append("a fleet's announcements heard on the fleet link are used as they were ([fleet])")
    companion = Companion(scenario, offboard=offboard, sequencer=AssumeEngaged() if assume_engaged else None,
                          planning=schedule, **keywords)
    if assume_engaged:
        notes.append("offboard sequence assumed engaged from the first autopilot HEARTBEAT (what-if)")

    ticked = _run(companion, timeline, schedule, after_tick)
    comparison = _compare(ticked, mode)
    if schedule is not None and schedule.missing:
        notes.append(f"{schedule.missing} announced plan arrivals had no matching replan request (the log and the scenario disagree)")
    return _report(path, Path(scenario_path), records, parsed, timeline, comparison, companion,
                   mode=mode, time_offset_s=time_offset_s, lockstep=lockstep, notes=notes)


# --------------------------------------------------------------------------- the steps


@dataclass
class _Parsed:
    """A log split into what the companion received and sent, with the recording's marks."""

    stream: list   # (outbound, _Rec | _TickMark) in log order
    inbound: int   # records fed to the companion
    outbound: int  # records the companion sent


@dataclass
class _Timeline:
    """Inbound records and ticks in the order the recorded companion saw them."""

    events: list                # _Rec (fed to handle) and _Tick (a tick)
    marked: bool                # the recording marked its ticks (companion.realtime.tlog_marks)
    legacy_plans: bool          # plan arrivals were sent on the wire (a log from before the plan marks)
    recorded_ticks: int         # ticks rebuilt from the outbound records
    commands_recorded: int      # recorded setpoints

    @property
    def realtime_plans(self) -> bool:
        """Plans arrived at ticks of their own (real-time planning): replay them there."""
        return any(ev.arrived or ev.lost for ev in self.events if isinstance(ev, _Tick))


@dataclass
class _Comparison:
    """The replayed setpoints against the recorded ones."""

    ticks: int
    times: list
    commands: list
    recorded: list
    diffs: list          # (max abs diff over axes, t_s) per compared setpoint
    unmatched: int
    mismatches: int


def _align_clocks(first_s: float, time_offset_s: float | None) -> tuple[float, bool]:
    """The offset (s) from tlog stamps to link time, and whether the log is a lockstep one."""
    lockstep = time_offset_s is None and LOCKSTEP_EPOCH_S <= first_s < LOCKSTEP_EPOCH_S + _LOCKSTEP_WINDOW_S
    if time_offset_s is None:
        time_offset_s = LOCKSTEP_EPOCH_S if lockstep else 0.0
    else:
        lockstep = float(time_offset_s) == LOCKSTEP_EPOCH_S
    if not math.isfinite(time_offset_s):
        raise ReplayError(f"time_offset_s must be finite seconds, got {time_offset_s!r}")
    return float(time_offset_s), lockstep


def _parse(path: Path, records: list, offset_us: int, companion_key: tuple[int, int]) -> _Parsed:
    """Inbound and outbound records in log order, each in link time (integer us), the marks
    taken out (a tick mark stays as a :class:`_TickMark` carrying its plan and signature
    marks; a link mark goes to the next record, which is inbound whatever its source). Raises :class:`ReplayError` when
    no autopilot is among the inbound messages."""
    parser = DIALECT.MAVLink(None, *companion_key)
    parser.robust_parsing = True
    key = tuple(int(k) for k in companion_key)
    stream: list[tuple[bool, _Rec | _TickMark]] = []
    n_in = n_out = 0
    next_link: str | None = None
    last_tick: _TickMark | None = None
    for t_s, msg in records:
        raw = bytes(msg.get_msgbuf())
        # mavutil stores stamp_us * 1e-6; rounding back recovers the integer exactly.
        rec = _Rec(int(round(t_s * _US)) - offset_us, _reparse(parser, raw, msg), raw)
        # A record the recording marked as received on a link is inbound whatever its source:
        # in a fleet, a peer's companion may send as the same (system, component) as ours on
        # the autopilot link (every companion starts as (1, 191) there).
        out = next_link is None and messages.source_key(rec.msg) == key
        mark = mark_of(rec.msg) if out else None
        if mark is not None:  # the recording's own notes (tlog_marks), never sent
            name, value = mark
            if name == TICK:
                last_tick = _TickMark(rec.t_us)
                stream.append((True, last_tick))
            elif name == RX_LINK:  # the next record's link
                next_link = link_name(value)
            elif last_tick is not None:  # plans and signatures of the tick just marked
                last_tick.note(name, value)
            continue
        if out and _is_clock_answer(rec.msg):
            n_out += 1
            continue  # answered inside handle (not at a tick) from the inbound request: the replay answers it too
        if not out:
            rec.link, next_link = next_link, None
        n_out += out
        n_in += not out
        stream.append((out, rec))
    inbound = [r for out, r in stream if not out]
    if not _has_vehicle(inbound):
        sources = sorted({messages.source_key(r.msg) for r in inbound if r.msg.get_type() == "HEARTBEAT"})
        raise ReplayError(
            f"{path}: no vehicle in the log: no PX4 autopilot HEARTBEAT (component 1, autopilot 12) among "
            f"{len(inbound)} inbound messages" + (f"; heartbeats only from {sources}" if sources else "; no HEARTBEAT at all")
        )
    return _Parsed(stream, n_in, n_out)


def _schedule_ticks(stream: list, period_us: int) -> _Timeline:
    """The ticks among the inbound records: as marked, or rebuilt from the outbound records
    (:func:`_marked_schedule`, :func:`_schedule`); an old log's plan notes taken out of them."""
    marked = any(isinstance(rec, _TickMark) for _, rec in stream)
    events = _marked_schedule(stream) if marked else _schedule(stream, period_us)
    legacy_plans = _take_legacy_notes(events)
    return _Timeline(
        events=events,
        marked=marked,
        legacy_plans=legacy_plans,
        recorded_ticks=sum(1 for ev in events if isinstance(ev, _Tick) and not ev.silent),
        commands_recorded=sum(1 for ev in events if isinstance(ev, _Tick) and ev.setpoint is not None),
    )


def _run(companion: Companion, timeline: _Timeline, schedule: RecordedArrivals | None, after_tick=None) -> list:
    """Drive ``companion`` (:class:`~companion.loop.driver.Driver`) through the inbound records and the
    ticks, as the recording did; each tick with what it sent (what the port collected during it);
    ``after_tick(companion, t_s, sent)`` after each (a view or a recording)."""
    port = CollectingPort()
    driver = Driver(companion, port)
    ticked: list[tuple[_Tick, list]] = []
    for ev in timeline.events:
        if isinstance(ev, _Rec):
            link = (ev.link or AUTOPILOT_LINK) if timeline.marked else replay_link(ev.msg, companion.autopilot)
            driver.receive(Received(ev.t_us * 1e-6, ev.msg, ev.raw, link))
            continue
        if schedule is not None:
            schedule.arrivals = list(ev.arrived)
            schedule.lost = list(ev.lost)
        port.take()  # the TIMESYNC answers since the last tick: not compared (_parse left the recorded ones out)
        # the signature count the recording's links had (a dropped packet is not in a tlog); None: not marked
        driver.tick(ev.t_us * 1e-6, ev.signatures)
        ticked.append((ev, port.take()))
        if after_tick is not None:
            after_tick(companion, ev.t_us * 1e-6, ticked[-1][1])
        if ev.hand_back is not None:  # after the tick, as the recording's edge asked it
            driver.hand_back(ev.t_us * 1e-6, ev.hand_back)
    return ticked


def _compare(ticked: list, mode: str) -> _Comparison:
    """Each replayed tick against the recorded one: message types (but the mission protocol's
    answers), and the setpoint's velocity as the wire carries it."""
    times, cmds, recs = [], [], []
    diffs: list[tuple[float, float]] = []  # (max abs diff, t_s)
    unmatched = mismatches = 0
    for ev, out in ticked:
        t = ev.t_us * 1e-6
        sp = next((m for m in reversed(out) if m.get_type() == _SETPOINT), None)
        if ev.silent:
            if mode == "compare":  # the recorded companion sent nothing at this tick
                mismatches += bool(out)
                unmatched += sp is not None
                if out:
                    logger.debug("silent tick at %.6f s: replayed %s", t, [m.get_type() for m in out])
        elif _compared_types(out) != _compared_types(ev.recorded):
            mismatches += 1
            logger.debug("tick at %.6f s: replayed %s, recorded %s", t, [m.get_type() for m in out],
                         [m.get_type() for m in ev.recorded])
        rec_sp = ev.setpoint
        if sp is not None:
            v = _velocity(sp)
            times.append(t)
            cmds.append(v)
            recs.append(_velocity(rec_sp) if rec_sp is not None else np.full(3, np.nan))
            if rec_sp is not None:
                diffs.append((float(np.max(np.abs(_wire(v) - _velocity(rec_sp)))), t))
            elif not ev.silent:
                unmatched += 1
        elif rec_sp is not None:
            unmatched += 1
    return _Comparison(len(ticked), times, cmds, recs, diffs, unmatched, mismatches)


def _report(path: Path, scenario_path: Path, records: list, parsed: _Parsed, timeline: _Timeline,
            comparison: _Comparison, companion: Companion, *, mode: str, time_offset_s: float, lockstep: bool,
            notes: list) -> ReplayResult:
    """The :class:`ReplayResult` (and its log line)."""
    diffs = comparison.diffs
    if diffs:
        i_max = int(np.argmax([d for d, _ in diffs]))
        max_diff, max_t = diffs[i_max]
    else:
        i_max, max_diff, max_t = None, None, None
    result = ReplayResult(
        path=path,
        scenario_path=scenario_path,
        mode=mode,
        time_offset_s=time_offset_s,
        lockstep=lockstep,
        messages=len(records),
        inbound=parsed.inbound,
        outbound=parsed.outbound,
        duration_s=float(records[-1][0] - records[0][0]),
        start_s=float(records[0][0] - time_offset_s),
        ticks=comparison.ticks,
        recorded_ticks=timeline.recorded_ticks,
        commands_recorded=timeline.commands_recorded,
        commands_compared=len(diffs),
        unmatched_commands=comparison.unmatched,
        tick_mismatches=comparison.mismatches,
        max_abs_diff_mps=max_diff,
        max_diff_t_s=max_t,
        max_diff_index=i_max,
        command_times_s=np.array(comparison.times, dtype=float),
        commands_mps=np.array(comparison.commands, dtype=float).reshape(-1, 3),
        recorded_commands_mps=np.array(comparison.recorded, dtype=float).reshape(-1, 3),
        status_counts=status_counts(r.status for r in companion.records),
        companion=companion,
        notes=notes,
    )
    logger.info(
        "replayed %s (%s): %d messages, %d ticks, %d replans, %d commands compared, max diff %s m/s",
        path, mode, result.messages, result.ticks, result.replans, result.commands_compared, max_diff,
    )
    return result


def _compared_types(sent: list) -> list[str]:
    """The message types of a tick compared with the recording's: all but the mission protocol's answers.

    Those (``CLIENT_ANSWERS``: the upload's items, the download's item requests and ack) are sent on
    receipt of the vehicle's messages. A log files them under a tick (an unmarked one stamps them like
    the tick's packets); the replay sends them on receipt too, so they are not compared."""
    return [m.get_type() for m in sent if m.get_type() not in CLIENT_ANSWERS]


def _is_clock_answer(msg) -> bool:
    """The companion's answer to the autopilot's TIMESYNC request (sent on receipt, not by a tick)."""
    if msg.get_type() != "TIMESYNC":
        return False
    sync = messages.decode(msg)
    return isinstance(sync, messages.TimeSync) and not sync.is_request


def _take_legacy_notes(events: list) -> bool:
    """Take an old log's bookkeeping out of its ticks; whether it had plan notes on the wire.

    Before the plan and signature marks (:mod:`companion.realtime.tlog_marks`) the companion sent
    NAMED_VALUE_FLOAT ``plan_seq`` / ``plan_lost`` among a tick's packets: they become the tick's
    arrivals and losses and leave its recorded messages (today's companion sends none, so
    they are not compared). Without any signature mark in the log, the count is read from
    the companion's STATUSTEXT announcing it (which stays: it is compared).
    """
    ticks = [ev for ev in events if isinstance(ev, _Tick)]
    sig_marked = any(t.signatures is not None for t in ticks)
    legacy = False
    for tick in ticks:
        if any(is_legacy_plan_note(m) for m in tick.recorded):
            legacy = True
            tick.arrived.extend(arrivals(tick.recorded, LEGACY_PLAN_ARRIVED))
            tick.lost.extend(arrivals(tick.recorded, LEGACY_PLAN_LOST))
            tick.recorded = [m for m in tick.recorded if not is_legacy_plan_note(m)]
        if not sig_marked:
            tick.signatures = signatures_rejected(tick.recorded)
    return legacy


def _marked_schedule(stream: list) -> list:
    """Inbound records and ticks of a log with tick marks: exactly in the recorded order.

    Each tick mark opens a tick; the outbound records after it (up to the next mark or
    inbound record) are what that tick sent, none for a tick that sent nothing.
    """
    events: list = []
    cur: _Tick | None = None
    for out, rec in stream:
        if isinstance(rec, _TickMark):
            cur = _Tick(rec.t_us, arrived=list(rec.arrived), lost=list(rec.lost), signatures=rec.signatures,
                        hand_back=rec.hand_back)
            events.append(cur)
        elif not out:
            cur = None
            events.append(rec)
        elif cur is not None:
            cur.recorded.append(rec.msg)
        else:  # a packet outside a marked tick: keep it as a tick of its own (it is compared, so it shows)
            events.append(_Tick(rec.t_us, [rec.msg]))
    return events


def _schedule(stream: list[tuple[bool, _Rec]], period_us: int) -> list:
    """Inbound records and ticks in the order the recorded companion saw them.

    Recorded ticks sit where their first outbound record is; silent ticks are put on the
    setpoint grid between recorded ticks and after the last one up to the last record's
    time (or over the whole log when none was recorded), each after every inbound record
    stamped up to its time.
    """
    events: list = []
    cur: _Tick | None = None
    for out, rec in stream:
        if not out:
            cur = None
            events.append(rec)
            continue
        if cur is None or cur.setpoint is not None or abs(rec.t_us - cur.t_us) > period_us // 2:
            cur = _Tick(rec.t_us)
            events.append(cur)
        cur.recorded.append(rec.msg)

    ticks = [ev for ev in events if isinstance(ev, _Tick)]
    if not ticks:
        inbound = [ev for ev in events if isinstance(ev, _Rec)]
        t0, t1 = inbound[0].t_us, inbound[-1].t_us
        grid = deque(t0 + k * period_us for k in range(1, (t1 - t0) // period_us + 1))
        return _merge(events, {None: grid}, period_us)
    gaps = {}
    for a, b in zip(ticks, ticks[1:]):
        silent, t = deque(), a.t_us + period_us
        # Between two streaming ticks there is none that sent nothing (a streaming tick always
        # sends its setpoint): a wider gap there is a late tick in real time, not a silent one.
        streaming = a.setpoint is not None and b.setpoint is not None
        while not streaming and t < b.t_us - period_us // 2:
            silent.append(t)
            t += period_us
        gaps[id(a)] = silent
    # After the last recorded tick the companion kept ticking silently up to the end of the log.
    end_us = max(ev.t_us for ev in events)
    gaps[id(ticks[-1])] = deque(range(ticks[-1].t_us + period_us, end_us + 1, period_us))
    return _merge(events, gaps, period_us)


def _merge(events: list, gaps: dict, period_us: int) -> list:
    """Insert silent ticks: ``gaps[id(tick)]`` follow that tick (``gaps[None]``: from the start)."""
    out: list = []
    pending: deque = gaps.get(None, deque())
    for ev in events:
        if isinstance(ev, _Tick):
            out.extend(_Tick(t, silent=True) for t in pending)
            out.append(ev)
            pending = gaps.get(id(ev), deque())
            continue
        while pending and ev.t_us > pending[0]:
            out.append(_Tick(pending.popleft(), silent=True))
        out.append(ev)
    out.extend(_Tick(t, silent=True) for t in pending)  # grid points after the last record, up to its time
    return out
