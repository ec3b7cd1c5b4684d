"""The executor: from the plan in force to the velocity command of this tick.

A plan is a sequence of velocity commands, each held ``step_s`` from the vehicle time its
request was built at. The executor sends the one for the current vehicle time, and
brakes (each tick one setpoint period closer to zero within the acceleration bound)
when there is no plan, when the plan is exhausted, or when it is older than
``[companion] max_plan_age_s`` in link time (a plan the planner has not refreshed is an
open-loop guess about obstacles that kept moving).
"""

from __future__ import annotations

import enum
import logging
import math

import numpy as np

from companion.core.planner import Plan, PlannerConfig

logger = logging.getLogger(__name__)


class Follow(enum.Enum):
    """Why the executor sent what it sent."""

    PLAN = "plan"            # the plan's command for now
    NO_PLAN = "no_plan"      # braking: no valid plan
    EXHAUSTED = "exhausted"  # braking: now is past the plan's horizon
    TOO_OLD = "too_old"      # braking: the plan is older than max_plan_age_s


class Executor:
    """Holds the plan in force and the last command; turns them into this tick's command.

    Parameters
    ----------
    config : PlannerConfig
        ``step_s``, ``horizon_steps``, ``accel_max`` and ``velocity_time_constant_s``.
    setpoint_period_s : float
        Seconds between setpoints (the braking step is the braking bound times this).
    lag : the planner's vehicle model (``Planner.lag``), for ``V_0`` of the next plan.
    max_plan_age_s : float
        Link seconds after its request past which a plan is no longer followed.
    brake_accel_mps2 : float or None
        Deceleration of :meth:`brake`, m/s^2 per axis; None: ``config.accel_max``.
    """

    def __init__(self, config: PlannerConfig, setpoint_period_s: float, lag, max_plan_age_s: float = math.inf,
                 brake_accel_mps2: float | None = None) -> None:
        self.cfg = config
        self._dt = float(setpoint_period_s)
        self._brake_step = (np.asarray(config.accel_max, dtype=float) if brake_accel_mps2 is None
                            else np.full(3, float(brake_accel_mps2))) * self._dt
        self._lag = lag
        self.max_plan_age_s = float(max_plan_age_s)
        self.plan: Plan | None = None
        self.plan_t0_v = 0.0          # vehicle time the plan starts from (s)
        self.plan_t_link_s = 0.0      # link time of the plan's request (s)
        self.plan_p0 = np.zeros(3)    # drone position the plan starts from, NED m
        self.command = np.zeros(3)    # last command sent, NED m/s
        self._next: tuple | None = None  # (plan, t0_v, t_link_s, p0) waiting for its start

    def adopt(self, plan: Plan, t_vehicle_s: float, t_link_s: float, position: np.ndarray | None = None,
              now_v: float | None = None) -> None:
        """Put ``plan`` in force; it starts at vehicle time ``t_vehicle_s`` from ``position`` (NED m),
        requested at link time ``t_link_s``.

        A plan that starts later than ``now_v`` (vehicle s; real time plans from where the
        drone will be when it arrives) waits while a plan is in force: the one in force is
        flown up to the new one's start, as the new one assumed. Without a plan in force it
        is flown at once.
        """
        p0 = np.zeros(3) if position is None else np.asarray(position, dtype=float).copy()
        if now_v is not None and self.plan is not None and t_vehicle_s > now_v + 0.5 * self._dt:
            self._next = (plan, float(t_vehicle_s), float(t_link_s), p0)
            return
        self._next = None
        self.plan, self.plan_t0_v, self.plan_t_link_s, self.plan_p0 = plan, float(t_vehicle_s), float(t_link_s), p0

    @property
    def waiting(self) -> bool:
        """A plan has arrived and waits for its start (see :meth:`adopt`)."""
        return self._next is not None

    def drop(self) -> None:
        """No plan in force or waiting (the next commands brake)."""
        self.plan = None
        self._next = None

    def hold(self) -> np.ndarray:
        """Zero velocity (hover while not engaged); returns the command."""
        self.command = np.zeros(3)
        return self.command

    def mirror(self, velocity: np.ndarray) -> np.ndarray:
        """The vehicle's own velocity (NED m/s) as the command (streamed while the autopilot flies);
        returns the command."""
        self.command = np.array(velocity, dtype=float).reshape(3)
        return self.command

    def brake(self) -> np.ndarray:
        """Velocity one setpoint period closer to zero, within the braking bound; returns the command."""
        self.command = np.sign(self.command) * np.maximum(np.abs(self.command) - self._brake_step, 0.0)
        return self.command

    def follow(self, t_s: float, t_v: float) -> tuple[np.ndarray, Follow]:
        """This tick's command at link time ``t_s`` and vehicle time ``t_v``, and why."""
        if self._next is not None and (self.plan is None or t_v >= self._next[1] - 0.5 * self._dt):
            (self.plan, self.plan_t0_v, self.plan_t_link_s, self.plan_p0), self._next = self._next, None
        if self.plan is None:
            return self.brake(), Follow.NO_PLAN
        if t_s - self.plan_t_link_s > self.max_plan_age_s + 1e-9:
            return self.brake(), Follow.TOO_OLD
        k = int(math.floor((t_v - self.plan_t0_v) / self.cfg.step_s + 1e-9))
        if k >= self.cfg.horizon_steps:
            return self.brake(), Follow.EXHAUSTED
        self.command = np.asarray(self.plan.commands[max(k, 0)], dtype=float).copy()
        return self.command, Follow.PLAN

    def initial_velocity(self, estimated_velocity: np.ndarray, t_v: float) -> np.ndarray:
        """``V_0`` of the next plan, NED m/s, at vehicle time ``t_v``.

        The velocity the vehicle flies under the commands sent so far, as the planner's
        model predicts it: without a velocity lag (the paper's model) that is the last
        command; with one, the current plan's velocity at ``t_v`` (its commands run
        through the planner's :class:`~companion.core.planner.vehicle_model.LagModel`). Both are smooth.
        Feeding the estimated velocity back instead (reports with 0.1 m/s noise) made
        the corridor runs weave: 0.6-0.75 m from the walls against 0.98 m (6 seeds).
        Without a current plan (braking, or before the first) the estimate is used.
        """
        if self._lag.instantaneous:
            return self.command.copy()
        if self.plan is None:
            return np.asarray(estimated_velocity, dtype=float).copy()
        return self._lag.velocity_at(self.plan.initial_velocity, self.plan.commands, t_v - self.plan_t0_v,
                                   self.plan.initial_response_state)

    def displacement(self, t_from_v: float, t_to_v: float, estimated_velocity: np.ndarray) -> np.ndarray:
        """How far the drone moves from vehicle time ``t_from_v`` to ``t_to_v`` (NED m): along the
        plan in force (its step-end positions, interpolated), else at ``estimated_velocity``."""
        if self.plan is None:
            return np.asarray(estimated_velocity, dtype=float) * (t_to_v - t_from_v)
        return self._plan_position(t_to_v - self.plan_t0_v) - self._plan_position(t_from_v - self.plan_t0_v)

    def _plan_position(self, dt):
        """Position of the plan in force ``dt`` s after its start (NED m; (3,), or (K, 3) for K
        times): its step-end positions interpolated from where it started, held at either end."""
        times = self.cfg.step_s * np.arange(self.plan.positions.shape[0] + 1)
        points = np.vstack([self.plan_p0[None], self.plan.positions])
        return np.stack([np.interp(dt, times, points[:, k]) for k in range(3)], axis=-1)

    def position_at(self, t_v):
        """Where the plan in force puts the drone at vehicle time ``t_v`` (NED m: (3,), or (K, 3)
        for an array of K times), or None without one."""
        return None if self.plan is None else self._plan_position(t_v - self.plan_t0_v)

    def reference(self, t_v: float) -> tuple[np.ndarray, np.ndarray] | None:
        """Position and velocity of the plan in force at vehicle time ``t_v`` (NED m, m/s), or None.

        The position interpolates the plan's step-end positions from where it started; the
        velocity is the vehicle's under the plan's commands (the planner's model). Sent as a
        position setpoint with velocity feed-forward, PX4's position loop then removes the
        slow tail of its velocity response (``MPC_XY_P (p - p_est)`` added to the feed-forward).
        """
        if self.plan is None:
            return None
        dt = t_v - self.plan_t0_v
        velocity = self._lag.velocity_at(self.plan.initial_velocity, self.plan.commands, dt, self.plan.initial_response_state)
        return self._plan_position(dt), np.asarray(velocity, dtype=float)
