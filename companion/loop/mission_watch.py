"""The autopilot flying its own mission, watched: its progress followed, its path predicted and judged.

With ``[offboard] takeover = "watch"`` (``companion fly --takeover watch``) the companion never
commands. :class:`MissionProgress` follows the autopilot through its mission (MISSION_CURRENT,
MISSION_ITEM_REACHED: PX4 sends each reached item about eleven times, so items are counted
once each, not per message). :class:`MissionWatch`, every replan period while the vehicle is
armed in its mission mode, predicts where the autopilot takes it over the planner's horizon
(straight legs from the estimate through the mission's remaining waypoints, each at the speed
the mission's DO_CHANGE_SPEED items set for it, else ``[mission] autopilot_speed_mps``;
:func:`companion.core.guard.path_along_route`; on the NAV_TAKEOFF item a climb where it is at
``autopilot_climb_mps`` first, then the leg to the item), predicts
every track and static obstacle in sensing range over the same steps, and judges the path by
the planner's promise: the contour of touch of the drone's Gaussian (with the tracking margin)
and each obstacle's, bodies included, may not fall below ``c_min``; and the drone's body and
``c_min`` ellipsoid may not reach the geofence (:meth:`MissionWatch._fence_step`). A predicted conflict is
announced when it appears (STATUSTEXT ``companion: conflict in 2.4 s, contour 0.42``) and when
the path is clear again, and each is kept for the report; the smallest predicted contour goes
to the ground station every evaluation as NAMED_VALUE_FLOAT ``ct_pred``.
Pure: link time (s) and the perception's vehicle time (s) come in as arguments.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.core.guard import first_conflict, path_along_route, path_contours
from companion.core.planner import PlannerConfig
from companion.loop.config import LoopConfig, MissionConfig
from companion.loop.perception import Perception
from companion.loop.request_builder import RequestBuilder
from companion.loop.supervisor import SEV_NOTICE, SEV_WARNING, RateLimiter, Supervisor
from companion.loop.track_selection import confidence_radius, reach_m
from companion.mavlink import messages

logger = logging.getLogger(__name__)

Outbox = list[mavlink2.MAVLink_message]

#: Items reached and conflicts kept for the report (the latest; all are counted).
KEPT = 1000


class MissionProgress:
    """The autopilot's own progress through its stored mission, from its MISSION_CURRENT and
    MISSION_ITEM_REACHED (link time s)."""

    def __init__(self) -> None:
        self.current_seq: int | None = None   #: the autopilot's current item (None: not heard)
        self.total: int | None = None         #: items in its mission (None: not said)
        self.mission_state = 0                #: MISSION_STATE of the latest MISSION_CURRENT
        #: items reached, as (link time s, seq), in order: each once (the latest :data:`KEPT`)
        self.reached: deque[tuple[float, int]] = deque(maxlen=KEPT)
        self.reached_count = 0
        self._lap: set[int] = set()   # items reached since the current item last went back (a jump, a restart)

    def on_current(self, t_s: float, current: messages.MissionCurrent) -> None:
        if current.seq != self.current_seq:
            logger.info("autopilot mission: current item %d", current.seq)
            if self.current_seq is not None and current.seq < self.current_seq:
                self._lap = set()    # flown again from an earlier item: its items may be reached again
        self.current_seq = current.seq
        self.total = None if current.total == 65535 else current.total
        self.mission_state = current.mission_state

    def on_reached(self, t_s: float, seq: int) -> bool:
        """MISSION_ITEM_REACHED ``seq``; whether it is news: not a repeat of the last item reached (PX4
        repeats it for about ten seconds, across a jump back too), nor of one reached since the
        mission last went back to an earlier item."""
        if (self.reached and self.reached[-1][1] == seq) or seq in self._lap:
            return False
        self._lap.add(seq)
        self.reached.append((t_s, seq))
        self.reached_count += 1
        return True

    def summary(self) -> dict:
        return {"autopilot_items_reached": [seq for _, seq in self.reached],
                "autopilot_items_reached_t_s": [t for t, _ in self.reached],
                "autopilot_items_reached_count": self.reached_count,
                "autopilot_current_item": self.current_seq,
                "autopilot_mission_state": self.mission_state}


@dataclass
class Conflict:
    """A predicted conflict on the autopilot's path, from its first evaluation to the first clear one.

    Times are link time (s); ``lead_s`` is how far ahead it was first predicted (s);
    ``min_contour`` the smallest predicted contour of touch meanwhile (NaN: only the fence was in
    the way); ``track`` what was first in the way (a track key as text, ``static k``, or ``fence``).
    """

    start_s: float
    lead_s: float
    track: str
    min_contour: float
    end_s: float | None = None


class MissionWatch:
    """The autopilot's path along its mission, predicted and judged (see the module docstring).

    Parameters
    ----------
    planner_config, settings, mission : the scenario's ``[planner]``, ``[companion]`` and ``[mission]``.
    builder : the request builder (its goal, a :class:`~companion.loop.mission_goal.MissionGoal`,
        gives the route; its obstacle radii, ranges, static sources and drone covariances are the planner's).
    supervisor : says what was found.
    progress : the autopilot's progress through its mission.
    """

    def __init__(self, planner_config: PlannerConfig, settings: LoopConfig, mission: MissionConfig, *,
                 builder: RequestBuilder, supervisor: Supervisor, progress: MissionProgress) -> None:
        self.cfg, self.settings, self.mission = planner_config, settings, mission
        self.builder, self.supervisor, self.progress = builder, supervisor, progress
        self._period = RateLimiter(planner_config.replan_period_s, tolerance_s=1e-9)
        n, tau = planner_config.horizon_steps, planner_config.step_s
        self._ahead = tau * np.arange(1, n + 1)      # s after now of each step
        self._sigmas = confidence_radius(planner_config.c_min)
        self.evaluations = 0
        self.min_predicted_contour: float | None = None
        self.conflicts: deque[Conflict] = deque(maxlen=KEPT)
        self.conflict_count = 0
        self._open: Conflict | None = None
        #: how far ahead the latest evaluation found its first step below ``c_min`` (s; None: clear)
        self.lead_s: float | None = None

    @property
    def open(self) -> Conflict | None:
        """The conflict predicted at the latest evaluation (None: the path was clear)."""
        return self._open

    def step(self, t_s: float, perception: Perception, active: bool, from_seq: int | None = None) -> Outbox:
        """At link time ``t_s``: judge the mission path when due (every replan period while
        ``active``, with a fresh estimate and the mission's route known): the path the autopilot
        flies from item ``from_seq`` on (default: its current item, MISSION_CURRENT)."""
        if not active or not self._period.ready(t_s):
            return []
        t_v = perception.vehicle_time(t_s)
        est = perception.drone.state
        if t_v is None or est is None or t_v - est.t_s > self.settings.estimate_timeout_s:
            return []
        position = est.position + est.velocity * max(0.0, t_v - est.t_s)
        route, speeds = self._route(self.progress.current_seq if from_seq is None else from_seq, position)
        if route is None:
            return []
        self._period.take(t_s)
        self.evaluations += 1
        path = path_along_route(position, route, speeds, self._ahead)
        _, drone_covs = self.builder.drone_covariances(perception, t_v)
        drone_covs = drone_covs + self.settings.tracking_margin_m2 * np.eye(3)
        contours, names = self._contours(perception, t_v, position, path, drone_covs)
        out: Outbox = []
        if contours.size:
            smallest = float(contours.min())
            best = self.min_predicted_contour
            self.min_predicted_contour = smallest if best is None else min(best, smallest)
            out.append(messages.named_value_float(int(round(t_s * 1000)), "ct_pred", smallest))
        found = first_conflict(contours, self._ahead, self.cfg.c_min)
        fence_step = self._fence_step(path, drone_covs)
        if fence_step is not None and (found is None or fence_step < found.step):
            lead, what, contour, text = float(self._ahead[fence_step]), "fence", math.nan, "fence"
        elif found is not None:
            lead, what, contour = found.in_s, names[found.obstacle], found.min_contour
            text = f"contour {found.contour:.2f}"
        else:
            lead = None
        self.lead_s = lead
        if lead is not None and self._open is None:
            self._open = Conflict(t_s, lead, what, contour)
            self.conflicts.append(self._open)
            self.conflict_count += 1
            out.append(self.supervisor.say(t_s, SEV_WARNING, f"companion: conflict in {lead:.1f} s, {text}"))
            logger.warning("predicted conflict on the autopilot's path: %s in %.1f s, %s", what, lead, text)
        elif lead is not None:
            if found is not None:
                self._open.min_contour = (found.min_contour if math.isnan(self._open.min_contour)
                                          else min(self._open.min_contour, found.min_contour))
        elif self._open is not None:
            self._open.end_s = t_s
            self._open = None
            out.append(self.supervisor.say(t_s, SEV_NOTICE, "companion: mission path clear"))
        return out

    def _route(self, from_seq: int | None, position: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | float]:
        """The autopilot's path ahead from item ``from_seq`` for a vehicle at ``position`` (NED m): the
        points it flies through and its speed on each leg to them (m/s); None when no item is known
        (:meth:`~companion.loop.mission_goal.MissionGoal.autopilot_path`)."""
        if from_seq is None:
            return None, self.mission.autopilot_speed_mps
        return self.builder.goal.autopilot_path(from_seq, position, self.mission.autopilot_speed_mps,
                                                self.mission.autopilot_climb_mps)

    def _fence_step(self, path: np.ndarray, drone_covs: np.ndarray) -> int | None:
        """The first step of ``path`` at which the drone's body and ``c_min`` ellipsoid would reach
        the geofence (outside an inclusion zone, into an exclusion zone), or None (or no fence)."""
        fence = getattr(getattr(self.builder, "fence", None), "fence", None)
        if fence is None:
            return None
        for k, p in enumerate(path):
            if fence.clearance(p) < reach_m(self.cfg.drone_radius_m, drone_covs[k], self._sigmas):
                return k
        return None

    def _contours(self, perception: Perception, t_v: float, position: np.ndarray,
                  path: np.ndarray, drone_covs: np.ndarray) -> tuple[np.ndarray, list[str]]:
        """Contours of touch (M, N) along ``path`` with every obstacle in sensing range now, and their names."""
        times = t_v + self._ahead
        tracker = perception.tracker
        tracker.prune(t_v)
        keys = list(tracker.keys())
        means, covs, radii, names = [], [], [], []
        if keys:   # every track now (column 0) and over the horizon, in one pass; those in range kept
            m, c = tracker.predict_many(keys, np.concatenate([[t_v], times]))
            for i, k in enumerate(keys):
                if np.linalg.norm(m[i, 0] - position) <= self.builder.obstacle_range(k):
                    means.append(m[i, 1:])
                    covs.append(c[i, 1:])
                    radii.append(self.builder.obstacle_radius(k))
                    names.append(str(k))
        for source in self.builder.sources:
            h = source.horizon(times)
            for i in range(len(h.radii)):
                if np.linalg.norm(h.means[i][0] - position) <= self.cfg.sensing_range_m:
                    means.append(h.means[i])
                    covs.append(h.covs[i])
                    radii.append(float(h.radii[i]))
                    names.append(f"static {i}")
        n = len(self._ahead)
        if not means:
            return np.empty((0, n)), names
        radii_sum = self.cfg.drone_radius_m + np.asarray(radii, dtype=float)
        return path_contours(path, drone_covs, np.asarray(means), np.asarray(covs), radii_sum), names

    def summary(self) -> dict:
        """For the run report: the evaluations, the smallest predicted contour and the conflicts."""
        return {
            "watch_evaluations": self.evaluations,
            "watch_min_predicted_contour": self.min_predicted_contour,
            "watch_conflicts_count": self.conflict_count,
            "watch_conflicts": [{"start_s": c.start_s, "end_s": c.end_s, "lead_s": c.lead_s, "track": c.track,
                                 "min_contour": None if math.isnan(c.min_contour) else c.min_contour}
                                for c in self.conflicts],
            **self.progress.summary(),
        }
