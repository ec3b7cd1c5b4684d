"""The executor: the plan's command for the current time, braking within the acceleration bound."""

from __future__ import annotations

import numpy as np
import pytest

from companion.core.planner import Planner, PlannerConfig
from companion.loop.executor import Executor, Follow


class _Plan:
    """Just what the executor reads of a plan."""

    def __init__(self, commands):
        self.commands = np.asarray(commands, dtype=float)
        self.initial_velocity = np.zeros(3)


def _executor(max_age=1.0):
    cfg = PlannerConfig(horizon_steps=4, step_s=0.3, accel_max_mps2=(0.5, 0.5, 0.5))
    return Executor(cfg, 0.05, Planner(cfg).lag, max_plan_age_s=max_age), cfg


def test_that_the_command_is_the_plans_step_for_the_current_vehicle_time():
    ex, _ = _executor()
    ex.adopt(_Plan([[1, 0, 0], [2, 0, 0], [3, 0, 0], [4, 0, 0]]), t_vehicle_s=10.0, t_link_s=100.0)
    assert ex.follow(100.0, 10.0)[0].tolist() == [1, 0, 0]
    assert ex.follow(100.35, 10.35)[0].tolist() == [2, 0, 0]
    assert ex.follow(100.9, 10.9)[0].tolist() == [4, 0, 0]


def test_that_an_exhausted_plan_brakes_within_the_acceleration_bound():
    ex, cfg = _executor(max_age=100.0)
    ex.adopt(_Plan([[2, -1, 0.1]] * 4), t_vehicle_s=0.0, t_link_s=0.0)
    first, why = ex.follow(0.0, 0.0)
    assert why is Follow.PLAN
    previous = first.copy()
    for i in range(1, 200):
        cmd, why = ex.follow(1.2 + 0.05 * i, 1.2 + 0.05 * i)
        assert why is Follow.EXHAUSTED
        assert np.all(np.abs(cmd - previous) <= np.asarray(cfg.accel_max) * 0.05 + 1e-12)
        assert np.all(np.abs(cmd) <= np.abs(previous))
        previous = cmd.copy()
    assert np.all(previous == 0.0)


def test_that_a_plan_older_than_the_configured_age_is_not_followed():
    ex, _ = _executor(max_age=0.5)
    ex.adopt(_Plan([[1, 0, 0]] * 4), t_vehicle_s=0.0, t_link_s=0.0)
    assert ex.follow(0.5, 0.5)[1] is Follow.PLAN
    cmd, why = ex.follow(0.55, 0.55)
    assert why is Follow.TOO_OLD and cmd[0] < 1.0


def test_that_without_a_plan_the_executor_brakes():
    ex, _ = _executor()
    ex.command = np.array([1.0, 0.0, 0.0])
    cmd, why = ex.follow(0.0, 0.0)
    assert why is Follow.NO_PLAN and cmd[0] == 1.0 - 0.5 * 0.05


def test_that_a_configured_brake_decelerates_at_its_own_bound_not_the_planners():
    cfg = PlannerConfig(horizon_steps=4, step_s=0.3, accel_max_mps2=(0.5, 0.5, 0.5))
    ex = Executor(cfg, 0.05, Planner(cfg).lag, max_plan_age_s=1.0, brake_accel_mps2=1.0)
    ex.command = np.array([2.0, -1.0, 0.02])
    ticks = 0
    while np.any(ex.command != 0.0):
        cmd, why = ex.follow(0.0, 0.0)
        ticks += 1
        assert why is Follow.NO_PLAN
    assert ticks == 40           # 2 m/s at 1 m/s^2 in 0.05 s steps (at the planner's 0.5: 80)
    ex.command = np.array([2.0, -1.0, 0.0])
    assert ex.brake().tolist() == pytest.approx([1.95, -0.95, 0.0])


def test_that_the_companion_table_checks_the_brake_bound():
    from companion.errors import ConfigError
    from companion.loop.config import LoopConfig

    assert LoopConfig().brake_accel_mps2 is None
    assert LoopConfig(brake_accel_mps2=1).brake_accel_mps2 == 1.0
    for bad in (0.0, -1.0, 25.0, "1", float("nan")):
        with pytest.raises(ConfigError, match="brake_accel_mps2"):
            LoopConfig(brake_accel_mps2=bad)


class _PlanWithPath(_Plan):
    def __init__(self, commands, positions):
        super().__init__(commands)
        self.positions = np.asarray(positions, dtype=float)


def test_that_a_plan_starting_later_waits_while_the_plan_in_force_is_flown_up_to_its_start():
    ex, _ = _executor()
    ex.adopt(_Plan([[1, 0, 0]] * 4), t_vehicle_s=10.0, t_link_s=100.0)
    ex.adopt(_Plan([[0, 2, 0]] * 4), t_vehicle_s=10.25, t_link_s=100.05, now_v=10.1)  # arrived 0.15 s early
    assert ex.waiting
    assert ex.follow(100.1, 10.1)[0].tolist() == [1, 0, 0]
    assert ex.follow(100.15, 10.15)[0].tolist() == [1, 0, 0]
    cmd, why = ex.follow(100.25, 10.25)
    assert cmd.tolist() == [0, 2, 0] and why is Follow.PLAN and not ex.waiting
    assert ex.plan_t0_v == 10.25 and ex.plan_t_link_s == 100.05  # its age still counts from its request


def test_that_a_later_plan_is_flown_at_once_without_a_plan_in_force_and_a_drop_clears_a_waiting_one():
    ex, _ = _executor()
    ex.adopt(_Plan([[0, 2, 0]] * 4), t_vehicle_s=10.25, t_link_s=100.0, now_v=10.1)
    assert not ex.waiting and ex.follow(100.1, 10.1)[0].tolist() == [0, 2, 0]
    ex.adopt(_Plan([[3, 0, 0]] * 4), t_vehicle_s=10.5, t_link_s=100.2, now_v=10.2)
    assert ex.waiting
    ex.drop()
    assert not ex.waiting and ex.follow(100.6, 10.6)[1] is Follow.NO_PLAN


def test_that_the_displacement_follows_the_plan_in_force_and_the_estimate_without_one():
    ex, _ = _executor()
    assert ex.displacement(1.0, 1.2, np.array([1.0, -2.0, 0.0])).tolist() == pytest.approx([0.2, -0.4, 0.0])
    path = [[5.3, 0, -2], [5.9, 0, -2], [6.5, 0, -2], [7.1, 0, -2]]  # step-end positions, 0.3 s steps, NED m
    ex.adopt(_PlanWithPath([[1, 0, 0], [2, 0, 0], [2, 0, 0], [2, 0, 0]], path), t_vehicle_s=10.0, t_link_s=0.0,
             position=np.array([5.0, 0.0, -2.0]))
    assert ex.displacement(10.15, 10.45, np.zeros(3)).tolist() == pytest.approx([5.6 - 5.15, 0.0, 0.0])
