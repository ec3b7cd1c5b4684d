"""From estimates, the goal, the obstacle sources and the map to one planning problem (:class:`ReplanJob`).

Covariance policy for the drone, the tracks' prediction over the horizon (the most
threatening tracks constrained, the rest left out or set apart beyond walls), the other
obstacle sources (:mod:`companion.loop.obstacle_sources`), the goal source's target
(:mod:`companion.loop.goal`) and the choice of the obstacles the ``c_max`` upper bound
follows. The job also carries what the loop records about the request (the
estimates it was built from, the realised contour of touch), so a plan that comes back
later (real time) is recorded against the state it was planned from.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass

import numpy as np

from companion.core.overlap import contour_of_touch
from companion.core.planner import Plan, PlanRequest
from companion.loop.config import CompanionScenario
from companion.loop.goal import GoalSource, ScenarioGoal, leads_the_way
from companion.loop.obstacle_sources import ObstacleSource, StaticObstacles
from companion.loop.peer_intents import PeerIntents
from companion.loop.perception import Perception
from companion.loop.right_of_way import RightOfWay
from companion.loop.track_selection import beyond_walls, choose, confidence_radius, rank_by_risk, reach_m
from estimator.models import propagate_position

logger = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class ReplanJob:
    """One replan asked of the planner, with the context the loop records beside its answer.

    Attributes
    ----------
    seq : int
        Replan number (0, 1, ...) of this companion.
    t_link_s, t_vehicle_s : float
        Link time of the request and the vehicle time the plan starts from (s): the
        request's own in lockstep, a lead later in real time (see :meth:`RequestBuilder.build`).
    request : PlanRequest
        The problem.
    warm_start : Plan or None
        The plan in force when the request was built.
    position, drone_cov, drone_velocity, target : ndarray
        Drone position the plan starts from (NED m: the estimate extrapolated to the request,
        moved along the plan in force up to ``t_vehicle_s``), its planning covariance now
        (m^2), its velocity estimate (m/s) and the waypoint (NED m).
    position_now : ndarray
        The drone's position estimate extrapolated to the request (NED m), without the
        lead: what the goal is judged on (``position`` in lockstep).
    obstacle_positions, obstacle_covs : dict
        Every track's estimate at the request (NED m, m^2), keyed by track.
    realised_contour : dict
        Contour of touch between the drone's and each track's estimate now, keyed by track.
    tracks_unconstrained : tuple
        Tracks left out of ``request`` (over the constrained-track limit).
    tracks_constrained : tuple
        The tracks in ``request``, in its obstacle order (static obstacles follow them).
    tracks_beyond_walls : tuple
        Tracks beyond a wall for the whole horizon: no rows needed (see
        :func:`~companion.loop.track_selection.beyond_walls`); neither constrained nor left out.
    tracks_giving_way : tuple
        Peers left out because they give way to this drone (``[fleet] coordination =
        "prioritised"``, :meth:`~companion.loop.peer_intents.PeerIntents.gives_way`).
    tracks_along_intent : tuple
        Constrained tracks predicted along their peer's announced plan instead of at constant velocity.
    """

    seq: int
    t_link_s: float
    t_vehicle_s: float
    request: PlanRequest
    warm_start: Plan | None
    position: np.ndarray
    position_now: np.ndarray
    drone_cov: np.ndarray
    drone_velocity: np.ndarray
    target: np.ndarray
    obstacle_positions: dict
    obstacle_covs: dict
    realised_contour: dict
    tracks_unconstrained: tuple = ()
    tracks_constrained: tuple = ()
    tracks_beyond_walls: tuple = ()
    tracks_giving_way: tuple = ()
    tracks_along_intent: tuple = ()


#: How far (m, beyond the drone's radius) the way round a fence's zones keeps off their corners.
FENCE_CORNER_MARGIN_M = 1.0
#: A lower-priority peer is left out while the contour of touch between its announced plan and
#: this drone's stays at least this fraction of ``c_min`` (it keeps ``c_min`` itself when it can;
#: a plan with slack comes far inside). See :meth:`RequestBuilder._clear_of_plan`.
GIVE_WAY_FLOOR = 0.5


class RequestBuilder:
    """Builds :class:`ReplanJob` s for one scenario (mission, map, planner and loop settings).

    Holds no state of its own but its sources': the goal source keeps where the route started,
    the fleet's right of way its deadlock watch.

    Parameters
    ----------
    scenario : CompanionScenario
        Mission, map, planner and loop settings.
    obstacle_radius : callable (track key) -> float, optional
        Body radius of a tracked obstacle, m (e.g. from its traffic reports, see
        :meth:`companion.loop.intake.obstacles.ObstacleIntake.radius`); default: every track
        has ``[companion] obstacle_radius_m``.
    obstacle_range : callable (track key) -> float or None, optional
        How far out a tracked obstacle is planned around, m (its source's ``range_m``,
        :meth:`companion.loop.intake.obstacles.ObstacleIntake.planning_range`); None, and the default
        for every track and for the other sources' obstacles: ``[planner] sensing_range_m``.
    goal : GoalSource, optional
        Where the drone is going (default: :class:`~companion.loop.goal.ScenarioGoal`).
    sources : sequence of ObstacleSource, optional
        Obstacles besides the tracks (default: the scenario's static obstacles).
    fence : FenceSource, optional
        A geofence: its walls about the plan's start join the scenario's walls.
    peers : PeerIntents, optional
        The fleet's intents: peers predicted along their announced plans, or left out when
        they give way (:mod:`companion.loop.peer_intents`); None: every track at constant velocity.
    right_of_way : RightOfWay, optional
        The fleet's rules of the road: the target moved right when a peer is met, and out of a
        standoff (:mod:`companion.loop.right_of_way`); needs ``peers``.
    """

    def __init__(self, scenario: CompanionScenario,
                 obstacle_radius: Callable[[Hashable], float] | None = None, *,
                 obstacle_range: Callable[[Hashable], float | None] | None = None,
                 goal: GoalSource | None = None, sources: Sequence[ObstacleSource] | None = None,
                 fence=None, peers: PeerIntents | None = None, right_of_way: RightOfWay | None = None) -> None:
        self.scenario = scenario
        self.cfg = scenario.planner
        self.settings = scenario.companion
        default_radius_m = scenario.companion.obstacle_radius_m
        self.obstacle_radius: Callable[[Hashable], float] = obstacle_radius or (lambda key: default_radius_m)
        self._obstacle_range: Callable[[Hashable], float | None] = obstacle_range or (lambda key: None)
        #: where the drone is going (default: the scenario's ``[mission]`` goal)
        self.goal: GoalSource = goal if goal is not None else ScenarioGoal(scenario.mission)
        #: obstacles besides the tracks (default: the scenario's static obstacles)
        self.sources: tuple[ObstacleSource, ...] = (
            tuple(sources) if sources is not None else (StaticObstacles(scenario.static_obstacles),))
        self._sigmas = confidence_radius(self.cfg.c_min)
        #: the geofence (:class:`~companion.loop.fence_source.FenceSource`): walls about each plan's start
        self.fence = fence
        #: the fleet's intents (None: no fleet)
        self.peers = peers
        #: the fleet's rules of the road (None: none)
        self.right_of_way = right_of_way if peers is not None else None

    def obstacle_range(self, key: Hashable) -> float:
        """How far out track ``key`` is planned around, m: its source's range, else the sensing range."""
        r = self._obstacle_range(key)
        return self.cfg.sensing_range_m if r is None else r

    # ------------------------------------------------------------------ estimates

    def drone_covariances(self, perception: Perception, t_v: float) -> tuple[np.ndarray, np.ndarray]:
        """The drone's covariance now (3, 3) and over the horizon (N, 3, 3), m^2.

        ``[companion] drone_covariance`` picks the source (see :class:`~companion.loop.config.LoopConfig`).
        The tracking margin (``tracking_margin_m2``) is not in them: the request carries it
        apart (:attr:`~companion.core.planner.request.PlanRequest.margin_cov`), so the
        realised contour of touch is judged on the estimate alone.
        """
        n, tau = self.cfg.horizon_steps, self.cfg.step_s
        est = perception.drone.state
        if self.settings.drone_covariance == "reported" and perception.reported_cov is not None:
            cov_now = perception.reported_cov
        else:
            cov_now = est.position_cov
        if self.settings.drone_covariance == "predicted":
            covs = perception.drone.predict_position_covariances(t_v, np.zeros((n, 3)), tau)
        else:
            covs = np.broadcast_to(cov_now, (n, 3, 3)).copy()
        return cov_now, covs

    def build(
        self,
        *,
        seq: int,
        t_s: float,
        t_v: float,
        perception: Perception,
        initial_velocity: np.ndarray,
        warm_start: Plan | None,
        lead_s: float = 0.0,
        shift: np.ndarray | None = None,
        response_state: np.ndarray | None = None,
        plan_in_force: Callable[[np.ndarray], np.ndarray | None] | None = None,
    ) -> ReplanJob:
        """The planning problem at link time ``t_s`` / vehicle time ``t_v`` from the current estimates.

        ``initial_velocity`` is ``V_0`` (NED m/s, see :meth:`companion.loop.executor.Executor.initial_velocity`)
        at the plan's start. The plan starts ``lead_s`` after ``t_v`` (0 in lockstep; in real
        time about when it will arrive), from the position estimate now moved by ``shift``
        (NED m: how far the plan in force takes the drone meanwhile); obstacles are predicted
        from that start. Tracks silent for longer than the tracker's ``drop_after_s`` are pruned first.
        ``response_state`` (3, 2) is the response model's internal state at the plan's start
        (:attr:`~companion.core.planner.request.PlanRequest.response_state`; ``None``: steady).
        ``plan_in_force(times)`` is where the plan being flown puts the drone at vehicle times
        ``times`` (N,) (NED m, (N, 3); None without one:
        :meth:`companion.loop.executor.Executor.position_at`); a prioritised drone leaves a
        lower-priority peer out only while that peer's announced plan keeps clear of it
        (:meth:`_clear_of_plan`).
        """
        est = perception.drone.state
        n, tau = self.cfg.horizon_steps, self.cfg.step_s
        position_now = est.position + est.velocity * max(0.0, t_v - est.t_s)
        position = position_now if shift is None else position_now + shift
        t0 = t_v + lead_s
        cov_now, drone_covs = self.drone_covariances(perception, t0)

        tracker = perception.tracker
        tracker.prune(t_v)
        times = t0 + tau * np.arange(1, n + 1)
        keys = list(tracker.keys())
        margin = self.settings.tracking_margin_m2 * np.eye(3)
        giving_way: list = []
        giving_way_now: dict = {}     # key -> (mean (3,), cov (3, 3)) at t_v, predicted once
        if self.peers is not None:
            giving_way = [k for k in keys if self.peers.gives_way(k, t_v)]
            if giving_way:
                gm, gc = tracker.predict_many(giving_way, np.array([t_v]))
                giving_way_now = {k: (m0, c0) for k, m0, c0 in zip(giving_way, gm[:, 0], gc[:, 0])}
                giving_way = self._clear_of_plan(giving_way_now, times, t_v, plan_in_force, drone_covs + margin, margin)
                keys = [k for k in keys if k not in set(giving_way)]
        # every track's estimate read once, as arrays (row k for keys[k]), when they are set apart or ranked
        stack = tracker.stacked(keys) if len(keys) > self.settings.max_constrained_tracks or self.scenario.walls else None
        row = {k: i for i, k in enumerate(keys)} if stack is not None else {}
        near, beyond = self._split_beyond_walls(keys, stack, perception, t0)
        constrained, left_out = self._select(near, stack, row, t0, position, initial_velocity, cov_now + margin)
        now_left_out = self._estimates_now(left_out + beyond, stack, row, t_v)
        # every constrained track now (t_v, column 0) and over the horizon, in one pass
        predicted_means, predicted_covs = tracker.predict_many(constrained, np.concatenate([[t_v], times]))
        means, covs = list(predicted_means[:, 1:]), list(predicted_covs[:, 1:])
        radii = [self.obstacle_radius(key) for key in constrained]
        ranges = [self.obstacle_range(key) for key in constrained]
        now_pos = dict(zip(constrained, predicted_means[:, 0]))
        now_cov = dict(zip(constrained, predicted_covs[:, 0]))
        for key, (m0, c0) in now_left_out.items():
            now_pos[key], now_cov[key] = m0, c0
        along_intent = []
        if self.peers is not None:
            for i, key in enumerate(constrained):
                # the peer strays from its plan in force as this drone does from its own: its
                # intent carries the tracking margin too (a fleet flies one configuration)
                along = self.peers.predict(key, times, predicted_covs[i, 0] + margin, t_v)
                if along is not None:
                    means[i], covs[i] = along
                    along_intent.append(key)
            for key in giving_way:
                now_pos[key], now_cov[key] = giving_way_now[key]
        goal = self.goal.goal
        # an obstacle leads the way (and is followed under c_max) only if it stands in it: within both
        # bodies and both c_min reaches of the line to the goal
        drone_reach = reach_m(self.cfg.drone_radius_m, cov_now, self._sigmas)
        leading = [leads_the_way(goal, position, now_pos[k],
                                 drone_reach + reach_m(self.obstacle_radius(k), now_cov[k], self._sigmas))
                   for k in constrained]
        for source in self.sources:  # the obstacles that are not tracks, after the tracks
            h = source.horizon(times)
            means.extend(h.means)
            covs.extend(h.covs)
            radii.extend(h.radii.tolist())
            ranges.extend([self.cfg.sensing_range_m] * len(h.radii))
            leading.extend(bool(lead) and leads_the_way(goal, position, m[0], drone_reach + reach_m(r, c[0], self._sigmas))
                           for lead, m, c, r in zip(h.may_lead, h.means, h.covs, h.radii))
        target = self.goal.target(position)
        walls_normal, walls_offset = self.scenario.walls_normal, self.scenario.walls_offset
        if self.fence is not None:
            # the way round the fence's zones (the walls alone would hold the drone at a face)
            target = self.fence.route_target(position, target, self.cfg.drone_radius_m + FENCE_CORNER_MARGIN_M, goal)
            fence_normal, fence_offset = self.fence.walls(position)
            walls_normal = np.concatenate([walls_normal, fence_normal])
            walls_offset = np.concatenate([walls_offset, fence_offset])
        if self.right_of_way is not None:
            # the peers this plan avoids (not those that give way), with how near counts as meeting
            peers = [(now_pos[k], tracker.state(k).velocity,
                      drone_reach + reach_m(self.obstacle_radius(k), now_cov[k], self._sigmas))
                     for k in (*constrained, *left_out) if self.peers.is_peer(k)]
            target = self.right_of_way.target(t_v, position, initial_velocity, target, goal, peers)
        request = PlanRequest(
            position=position,
            velocity=initial_velocity,
            drone_covs=drone_covs,
            target=target,
            obstacle_means=np.array(means).reshape(-1, n, 3),
            obstacle_covs=np.array(covs).reshape(-1, n, 3, 3),
            obstacle_radii=np.array(radii, dtype=float),
            walls_normal=walls_normal,
            walls_offset=walls_offset,
            upper_bound_mask=np.array(leading, dtype=bool),
            obstacle_ranges_m=np.array(ranges, dtype=float),
            margin_cov=margin if self.settings.tracking_margin_m2 > 0.0 else None,
            response_state=response_state,
        )
        return ReplanJob(
            seq=seq,
            t_link_s=t_s,
            t_vehicle_s=t0,
            request=request,
            warm_start=warm_start,
            position=position,
            position_now=position_now,
            drone_cov=cov_now,
            drone_velocity=est.velocity.copy(),
            target=target,
            obstacle_positions=now_pos,
            obstacle_covs=now_cov,
            realised_contour=self._realised_contour(position_now, cov_now, keys + giving_way, now_pos, now_cov),
            tracks_unconstrained=tuple(left_out),
            tracks_constrained=tuple(constrained),
            tracks_beyond_walls=tuple(beyond),
            tracks_giving_way=tuple(giving_way),
            tracks_along_intent=tuple(along_intent),
        )

    def _clear_of_plan(self, giving_way: dict, times: np.ndarray, t_v: float,
                       plan_in_force: Callable[[np.ndarray], np.ndarray | None] | None, safety_covs: np.ndarray,
                       margin: np.ndarray) -> list:
        """The lower-priority peers of ``giving_way`` whose announced plans keep clear of this drone's plan.

        ``giving_way`` maps each lower-priority peer's key to its track's (mean, covariance)
        at ``t_v`` (NED m, m^2), predicted once by the caller.

        A peer that gives way plans around this drone's announced plan. When it cannot (its
        plan needed slack: it was boxed in, or met this drone too fast for its acceleration),
        its announced plan comes inside this drone's: the contour of touch between the two
        plans (this drone's covariances with the tracking margin, ``safety_covs`` (N, 3, 3) m^2;
        the peer's as its intent predicts them, with the same ``margin`` (3, 3) m^2) falls below ``GIVE_WAY_FLOOR * c_min`` at some
        step. Such a peer is planned around like any other (counted ``not_giving_way``), so
        the higher-priority drone moves too. Without a plan in force every peer keeps clear.
        """
        path = None if plan_in_force is None else plan_in_force(times)
        if path is None:
            return list(giving_way)
        floor = GIVE_WAY_FLOOR * self.cfg.c_min
        clear = []
        for key, (_, cov_now) in giving_way.items():
            along = self.peers.along(key, times, cov_now + margin, t_v)
            if along is not None:
                contour = contour_of_touch(path, safety_covs, along[0], along[1],
                                           self.cfg.drone_radius_m + self.obstacle_radius(key))
                if float(np.min(contour)) < floor:
                    self.peers.counts["not_giving_way"] += 1
                    continue
            clear.append(key)
        return clear

    # ------------------------------------------------------------------ many tracks

    def _split_beyond_walls(self, keys: list, stack: tuple | None, perception: Perception,
                            t_v: float) -> tuple[list, list]:
        """The tracks that may reach the drone's side of the walls, and those beyond a wall for the whole horizon.

        See :func:`~companion.loop.track_selection.beyond_walls`: a track beyond a wall at
        every step of the request with its ``c_min`` ellipsoid and radius cannot come within
        ``c_min`` of a plan that keeps to the walls, so it needs no rows. Tracker order is kept.
        ``stack``: :meth:`estimator.ObstacleTracker.stacked` of ``keys``.
        """
        if not keys or not self.scenario.walls:
            return keys, []
        n, tau = self.cfg.horizon_steps, self.cfg.step_s
        t_est, mean, cov = stack
        lags = (t_v + tau * np.arange(1, n + 1))[None, :] - t_est[:, None]
        beyond = beyond_walls(
            mean, cov, lags,
            perception.tracker.config.accel_noise_psd_m2ps3,
            self.scenario.walls_normal, self.scenario.walls_offset,
            np.array([self.obstacle_radius(k) for k in keys], dtype=float), self._sigmas,
        )
        return [k for k, b in zip(keys, beyond) if not b], [k for k, b in zip(keys, beyond) if b]

    def _select(self, keys: list, stack: tuple | None, row: dict, t_v: float, position, velocity,
                cov_now) -> tuple[list, list]:
        """The tracks to constrain (tracker order) and those left out (riskiest first), see :mod:`~companion.loop.track_selection`.

        With no more tracks than ``max_constrained_tracks`` every track is constrained and
        nothing is ranked. Otherwise the ranking propagates every track's mean and
        covariance (without process noise: a ranking, not a prediction) from its last
        estimate in one vectorised step, so 200 tracks cost about as much as a few.
        ``stack`` holds every track's estimate, ``keys[k]``'s in its row ``row[keys[k]]``.
        """
        limit = self.settings.max_constrained_tracks
        if len(keys) <= limit:
            return keys, []
        n, tau = self.cfg.horizon_steps, self.cfg.step_s
        lag0, mean, cov = self._rows_at(keys, stack, row, t_v)   # (P,), (P, 6), (P, 6, 6)
        steps = tau * np.arange(0, n + 1)
        lags = lag0[:, None] + steps[None, :]               # (P, N+1)
        track_means = mean[:, None, :3] + lags[..., None] * mean[:, None, 3:]
        tr_pp = np.trace(cov[:, :3, :3], axis1=1, axis2=2)
        tr_pv = np.trace(cov[:, :3, 3:], axis1=1, axis2=2)
        tr_vv = np.trace(cov[:, 3:, 3:], axis1=1, axis2=2)
        track_var = tr_pp[:, None] + 2.0 * lags * tr_pv[:, None] + lags**2 * tr_vv[:, None]  # trace >= largest eigenvalue
        drone_path = position[None, :] + steps[:, None] * np.asarray(velocity)[None, :]
        order, _, _ = rank_by_risk(
            drone_path, track_means, track_var, float(np.trace(cov_now)),
            self.cfg.drone_radius_m + np.array([[self.obstacle_radius(k)] for k in keys]), tau, self._sigmas,
        )
        chosen, rest = choose(order, limit)
        return [keys[i] for i in chosen], [keys[i] for i in rest]

    @staticmethod
    def _rows_at(keys: list, stack: tuple, row: dict, t_v: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Seconds from each track's estimate to ``t_v`` (0 for a newer one), its mean and its
        covariance: the rows ``row[key]`` of ``stack`` (:meth:`estimator.ObstacleTracker.stacked`)."""
        rows = np.array([row[k] for k in keys], dtype=int)
        return np.maximum(t_v - stack[0][rows], 0.0), stack[1][rows], stack[2][rows]

    @classmethod
    def _estimates_now(cls, keys: list, stack: tuple | None, row: dict, t_v: float) -> dict:
        """Position mean (NED m) and covariance (m^2) at ``t_v`` of tracks the planner does not get.

        Propagated from each track's estimate (``stack``, row ``row[key]``) without process
        noise, all in one vectorised pass of the tracker's own propagation
        (:func:`estimator.models.propagate_position` with no noise; its full prediction
        costs about 0.2 ms a track, too much for 200 tracks in one tick, and a per-track
        product cost 1.5 ms for 200).
        """
        if not keys:
            return {}
        lag, mean, cov = cls._rows_at(keys, stack, row, t_v)
        position, position_cov = propagate_position(mean, cov, lag[:, None], 0.0)
        return {key: (position[i, 0], position_cov[i, 0]) for i, key in enumerate(keys)}

    def _realised_contour(self, position, cov_now, keys, now_pos, now_cov) -> dict:
        """Contour of touch between the drone's estimate and each track's, keyed by track."""
        if not keys:
            return {}
        ct = contour_of_touch(
            np.broadcast_to(position, (len(keys), 3)),
            np.broadcast_to(cov_now, (len(keys), 3, 3)),
            np.array([now_pos[k] for k in keys]),
            np.array([now_cov[k] for k in keys]),
            self.cfg.drone_radius_m + np.array([self.obstacle_radius(k) for k in keys]),
        )
        return {k: float(v) for k, v in zip(keys, np.atleast_1d(ct))}
