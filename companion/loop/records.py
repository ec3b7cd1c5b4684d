"""What the control loop records: its modes, the planner's statuses and one record per applied replan.

Typed so that reports, figures and the replay compare enum members rather than strings.
Both enums are :class:`enum.StrEnum`: a member equals its value (``PlanStatus.FAILED ==
"failed"``) and serialises to it in JSON, so summaries keep their wire form.
"""

from __future__ import annotations

import enum
import logging
import math
from array import array
from collections import Counter, deque
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

logger = logging.getLogger(__name__)


class LoopMode(enum.StrEnum):
    """What the loop is doing at a tick.

    ``WAITING`` no stream yet; ``PRESTREAM`` streaming hover while PX4 is asked for
    OFFBOARD; ``TRACKING`` flying a plan; ``BRAKING`` decelerating within the
    acceleration bound (no valid plan, plan exhausted or older than ``max_plan_age_s``);
    ``STALE`` braking because the drone estimate is stale; ``IDLE`` not commanding
    (the sequence stopped streaming).
    """

    WAITING = "waiting"
    PRESTREAM = "prestream"
    TRACKING = "tracking"
    BRAKING = "braking"
    STALE = "stale"
    IDLE = "idle"


class PlanStatus(enum.StrEnum):
    """Outcome of one replan, as :class:`companion.core.planner.Plan` reports it."""

    OPTIMAL = "optimal"
    SLACK = "slack"
    FAILED = "failed"

    @classmethod
    def of(cls, plan: object) -> "PlanStatus":
        """The status of a :class:`~companion.core.planner.Plan` (its ``status`` string or enum)."""
        return cls(str(getattr(plan, "status")))


def status_counts(statuses: Iterable[PlanStatus | str]) -> dict[str, int]:
    """Replans per status, as plain strings in :class:`PlanStatus` order (statuses never seen omitted)."""
    counts = Counter(PlanStatus(s) for s in statuses)
    return {s.value: counts[s] for s in PlanStatus if counts[s]}


@dataclass(frozen=True)
class ReplanRecord:
    """One replan, recorded when its plan was applied (for summaries, figures and replay).

    Positions and covariances are NED metres / square metres at vehicle time
    ``t_vehicle_s`` (the request's). ``t_link_s`` is the link time of the request;
    ``t_applied_s`` the link time at which the loop adopted (or rejected) the plan: the
    same tick in lockstep, later in real time. ``realised_contour`` is the contour of
    touch between the drone's estimate and each tracked obstacle's estimate at the
    request (physical radii included), keyed by track. ``planned_contour`` is the plan's own
    contour of touch at its first step (``t_vehicle_s + step_s``, the step the vehicle flies
    before the next replan) for each constrained track within sensing range, keyed by track
    (empty for a failed plan): the promise the plan makes. ``tracks_unconstrained`` counts
    tracks in the request that the planner was not asked to avoid (over the
    ``max_constrained_tracks`` limit, see :mod:`companion.loop.track_selection`).
    ``tracks_giving_way`` and ``tracks_along_intent`` count the fleet's peers left out (they
    give way) and predicted along their announced plans (:mod:`companion.loop.peer_intents`).
    """

    t_link_s: float
    t_vehicle_s: float
    status: PlanStatus
    iterations: int
    solve_time_s: float
    slack_max: float
    planned_min_contour: float
    realised_contour: dict
    drone_position: np.ndarray
    drone_cov: np.ndarray
    drone_velocity: np.ndarray
    obstacle_positions: dict
    obstacle_covs: dict
    target: np.ndarray
    plan_positions: np.ndarray
    command: np.ndarray
    t_applied_s: float = 0.0
    tracks_unconstrained: int = 0
    planned_contour: dict = field(default_factory=dict)
    tracks_giving_way: int = 0
    tracks_along_intent: int = 0


class EventLog:
    """What the loop said, as (link time s, text) in order, in bounded memory.

    A long flight says a line at every slack replan (up to 3.3 a second in a crowd): the first
    ``head`` events are kept (the engagement, the first alerts) and the latest ``tail``; those
    between are counted (:attr:`total` less the kept). Iterates, compares and indexes like the
    list of the kept events.
    """

    def __init__(self, head: int = 500, tail: int = 1500) -> None:
        self._head: list[tuple[float, str]] = []
        self._tail: deque[tuple[float, str]] = deque(maxlen=tail)
        self._head_size = head
        self.total = 0   #: every event said, kept or not

    def append(self, event: tuple[float, str]) -> None:
        self.total += 1
        if len(self._head) < self._head_size:
            self._head.append(event)
        else:
            self._tail.append(event)

    @property
    def dropped(self) -> int:
        """Events said between the first and the latest kept, not kept."""
        return self.total - len(self)

    def __iter__(self):
        yield from self._head
        yield from self._tail

    def __len__(self) -> int:
        return len(self._head) + len(self._tail)

    def __bool__(self) -> bool:
        return self.total > 0

    def __getitem__(self, index: int) -> tuple[float, str]:
        if index == -1 and self._tail:
            return self._tail[-1]
        return list(self)[index]

    def __eq__(self, other: object) -> bool:
        return list(self) == list(other) if isinstance(other, (EventLog, list)) else NotImplemented

    def __repr__(self) -> str:
        return f"EventLog({list(self)!r}, total={self.total})"


class ReplanTally:
    """Every applied replan, summed: what the run report needs of them, in memory that does not grow with them.

    A :class:`ReplanRecord` holds the plan and every estimate of its request (about 7 KB with
    three tracks): one per replan (3.3 a second) is about 40 MB an hour of flight. A live flight
    keeps only its latest records (``Companion(replan_history=...)``) and reports from this
    tally instead, which is the same figures as from every record: the count, the statuses, the
    smallest planned contour, the solve times (8 bytes a replan, so the median and the 99th
    percentile stay exact) and the smallest realised contour per peer of a fleet.
    """

    def __init__(self) -> None:
        self.count = 0
        self.statuses: Counter = Counter()
        self.min_planned_contour: float | None = None
        self.solve_times_s = array("d")
        #: smallest realised contour of touch with each track matching ``peer`` (a fleet's peers)
        self.min_peer_contour: float | None = None

    def add(self, record: "ReplanRecord", is_peer=lambda key: False) -> None:
        """Count one applied replan (``is_peer(key)``: whether a track's key is a fleet peer's)."""
        self.count += 1
        self.statuses[PlanStatus(record.status)] += 1
        if math.isfinite(record.planned_min_contour):
            self.min_planned_contour = (record.planned_min_contour if self.min_planned_contour is None
                                        else min(self.min_planned_contour, record.planned_min_contour))
        self.solve_times_s.append(record.solve_time_s)
        for key, value in (record.realised_contour or {}).items():
            if is_peer(key):
                self.min_peer_contour = value if self.min_peer_contour is None else min(self.min_peer_contour, value)

    def status_counts(self) -> dict[str, int]:
        """As :func:`status_counts` over every record."""
        return {s.value: self.statuses[s] for s in PlanStatus if self.statuses[s]}


@dataclass
class TrackingError:
    """How far the vehicle strays from the plan in force before the next replan (NED m).

    At each replan request the drone's estimate is compared with where the plan in force
    put it at that time; the spread of these residuals is what a scenario's
    ``[companion] tracking_margin_m2`` must cover. Fixed size: sums, not samples.
    """

    samples: int = 0
    sum_sq: list = field(default_factory=lambda: [0.0, 0.0, 0.0])
    largest_m: float = 0.0

    def add(self, residual: np.ndarray) -> None:
        """One residual ``estimate - plan`` (3,), NED metres."""
        x, y, z = (float(v) for v in residual)
        self.samples += 1
        self.sum_sq = [self.sum_sq[0] + x * x, self.sum_sq[1] + y * y, self.sum_sq[2] + z * z]
        self.largest_m = max(self.largest_m, (x * x + y * y + z * z) ** 0.5)

    def summary(self) -> dict | None:
        """``{"samples", "rms_ned_m" (3,), "largest_m"}``, or None before the first residual."""
        if not self.samples:
            return None
        return {"samples": self.samples, "rms_ned_m": [(v / self.samples) ** 0.5 for v in self.sum_sq],
                "largest_m": self.largest_m}


def describe_tracking(summary: dict) -> str:
    """One line of a :meth:`TrackingError.summary`: rms per NED axis, the largest, how many."""
    rms = "/".join(f"{v:.3f}" for v in summary["rms_ned_m"])
    return f"rms N/E/D {rms} m, largest {summary['largest_m']:.3f} m over {summary['samples']} replans"


@dataclass
class CompanionState:
    """Counters and the current mode of the loop, for tests and the summary."""

    mode: LoopMode = LoopMode.WAITING
    goal_reached_t_s: float | None = None
    braking_events: int = 0
    stale_events: int = 0
    failed_plans: int = 0
    slack_plans: int = 0
    old_plan_events: int = 0
    estimator_resets: int = 0      #: the autopilot's estimator resets acted on (plan dropped, replanned)
    plans_before_reset: int = 0    #: plans discarded on arrival: built from an estimate before a reset
    #: times the autopilot's reported position became uncertain while engaged (``position_sd_warn_m``)
    position_uncertain_events: int = 0
    #: largest standard deviation of the autopilot's reported position while engaged (m); None: none reported
    reported_position_sd_max_m: float | None = None
    obstacle_rejections: int = 0
    drone_rejections: int = 0
    messages_rejected: int = 0
    tracks_unconstrained_max: int = 0
    #: most tracks set apart as beyond a wall for a whole horizon in one replan (no rows needed)
    tracks_beyond_walls_max: int = 0
    #: smallest realised contour of touch over every replan request (also those whose plan
    #: never came back or was superseded in real time); None until an obstacle was in range
    min_realised_contour: float | None = None
    #: smallest distance between the drone's estimate and any track's, less both radii (m), over
    #: every replan request; None until a track was heard
    min_track_clearance_m: float | None = None
    #: smallest signed distance (m) from the drone's estimate to the geofence over every replan
    #: request (negative: outside it); None without a fence
    min_fence_clearance_m: float | None = None
    #: largest drift of the autopilot's position estimate against its velocity per NED axis at a
    #: replan request, m/s (``[companion] drift_window_s``; zeros when off)
    drift_max_mps: list = field(default_factory=lambda: [0.0, 0.0, 0.0])
    #: the estimate against the plan in force at each replan request (see :class:`TrackingError`)
    tracking: TrackingError = field(default_factory=TrackingError)
    #: what the loop said, (link time s, text), in order (the first and the latest kept: :class:`EventLog`)
    events: "EventLog" = field(default_factory=lambda: EventLog())
