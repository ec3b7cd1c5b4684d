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
        Seconds between setpoints (the braking step is ``accel_max * setpoint_period_s``).
    lag : the planner's vehicle model (``Planner.lag``), for ``V_0`` of the next plan.
    max_plan_age_s : float
        Link seconds after its request past which a plan is no longer followed.
    """

    def __init__(self, config: PlannerConfig, setpoint_period_s: float, lag, max_plan_age_s: float = math.inf) -> None:
        self.cfg = config
        self._dt = float(setpoint_period_s)
        self._lag = lag
        self.max_plan_age_s = float(max_plan_age_s)
        self.plan: Plan | None = None
        self.plan_t0_v = 0.0          # vehicle time the plan starts from (s)
        self.plan_t_link_s = 0.0      # link time of the plan's request (s)
        self.command = np.zeros(3)    # last command sent, NED m/s

    def adopt(self, plan: Plan, t_vehicle_s: float, t_link_s: float) -> None:
        """Put ``plan`` in force; it starts at vehicle time ``t_vehicle_s``, requested at link time ``t_link_s``."""
        self.plan, self.plan_t0_v, self.plan_t_link_s = plan, float(t_vehicle_s), float(t_link_s)

    def drop(self) -> None:
        """No plan in force (the next commands brake)."""
        self.plan = None

    def hold(self) -> np.ndarray:
        """Zero velocity (hover while not engaged); returns the command."""
        self.command = np.zeros(3)
        return self.command

    def brake(self) -> np.ndarray:
        """Velocity one setpoint period closer to zero, within the acceleration bound; returns the command."""
        step = self.cfg.accel_max * self._dt
        self.command = np.sign(self.command) * np.maximum(np.abs(self.command) - step, 0.0)
        return self.command

    def follow(self, t_s: float, t_v: float) -> tuple[np.ndarray, Follow]:
        """This tick's command at link time ``t_s`` and vehicle time ``t_v``, and why."""
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
        if self.cfg.velocity_time_constant_s <= 0.0:
            return self.command.copy()
        if self.plan is None:
            return np.asarray(estimated_velocity, dtype=float).copy()
        return self._lag.velocity_at(self.plan.initial_velocity, self.plan.commands, t_v - self.plan_t0_v)
