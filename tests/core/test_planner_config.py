"""PlannerConfig: defaults, validation messages, TOML loading, unknown keys and keywords."""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

import pytest

from companion.errors import ConfigError
from companion.core.planner import FORMULATIONS, PlannerConfig

ROOT = Path(__file__).resolve().parents[2]


def test_that_defaults_are_valid_and_frozen():
    cfg = PlannerConfig()
    assert cfg.formulation == "hyperplane"
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.c_min = 0.5  # type: ignore[misc]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"formulation": "magic"}, r"formulation = 'magic' is not one of hyperplane, paper"),
        ({"horizon_steps": 1}, r"horizon_steps = 1 must be >= 2"),
        ({"horizon_steps": 100_000_000}, r"horizon_steps = 100000000 must be >= 2 and <= 400"),
        ({"scp_max_iterations": 10**9}, r"scp_max_iterations = 1000000000 must be >= 1 and <= 100"),
        ({"horizon_steps": 2.5}, r"horizon_steps = 2.5 must be an integer"),
        ({"step_s": 0.0}, r"step_s = 0.0 must be positive"),
        ({"c_min": 1.0}, r"c_min = 1.0 must be < 1"),
        ({"c_min": 0.6, "c_max": 0.5}, r"c_max = 0.5 must be greater than c_min = 0.6"),
        ({"velocity_max_mps": (1.0, -1.0, 1.0)}, r"velocity_max_mps = .* three positive finite numbers"),
        ({"accel_max_mps2": (1.0, 1.0)}, r"accel_max_mps2 = .* three positive finite numbers"),
        ({"drone_radius_m": -0.1}, r"drone_radius_m = -0.1 must be >= 0"),
        ({"sensing_range_m": float("nan")}, r"sensing_range_m = nan must be a finite number"),
        ({"step_s": float("inf")}, r"step_s = inf must be a finite number"),
        ({"step_s": "0.3"}, r"step_s = '0.3' is not a number"),
        ({"slack_penalty": 0}, r"slack_penalty = 0 must be positive"),
        ({"scp_max_iterations": 0}, r"scp_max_iterations = 0 must be >= 1"),
        ({"solver_polish": "yes"}, r"solver_polish = 'yes' must be true or false"),
        ({"solver": "gurobi"}, r"solver = 'gurobi' is not one of osqp, piqp"),
        ({"solver_rho": 0.0}, r"solver_rho = 0.0 must be positive"),
        ({"solver_max_iter": 0}, r"solver_max_iter = 0 must be >= 1"),
        ({"replan_work_budget": 199}, r"replan_work_budget = 199 must be >= 200"),
        ({"replan_work_budget": 1e4}, r"replan_work_budget = 10000.0 must be an integer"),
        ({"replan_work_budget": True}, r"replan_work_budget = True must be an integer"),
    ],
)
def test_that_bad_values_get_clear_errors(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        PlannerConfig(**kwargs)


def test_that_unknown_keyword_arguments_are_rejected():
    with pytest.raises(TypeError, match="c_minimum"):
        PlannerConfig(c_minimum=0.5)  # type: ignore[call-arg]


def test_that_sensing_range_may_be_infinite():
    assert PlannerConfig(sensing_range_m=float("inf")).sensing_range_m == float("inf")


def test_that_from_toml_table_names_source_key_and_value():
    with pytest.raises(ConfigError, match=r"x\.toml \[planner\]: unknown key\(s\) horizon \(allowed: "):
        PlannerConfig.from_toml_table({"horizon": 20}, source="x.toml [planner]")
    with pytest.raises(ConfigError, match=r"x\.toml \[planner\]: c_min = 2 must be < 1"):
        PlannerConfig.from_toml_table({"c_min": 2}, source="x.toml [planner]")


def test_that_from_toml_table_reads_lists_and_overrides():
    cfg = PlannerConfig.from_toml_table({"velocity_max_mps": [1, 2, 3], "formulation": "paper"},
                                        drone_radius_m=0.3, formulation="bhattacharyya")
    assert cfg.velocity_max_mps == (1.0, 2.0, 3.0)
    assert cfg.drone_radius_m == 0.3
    assert cfg.formulation == "bhattacharyya"


def test_that_the_single_obstacle_scenario_planner_table_loads():
    data = tomllib.loads((ROOT / "configs" / "single_obstacle.toml").read_text())
    cfg = PlannerConfig.from_toml_table(data["planner"], source="single_obstacle.toml [planner]")
    assert (cfg.horizon_steps, cfg.step_s, cfg.c_min) == (20, 1.0, 0.6)


def test_that_every_formulation_is_accepted():
    for name in FORMULATIONS:
        assert PlannerConfig(formulation=name).formulation == name
