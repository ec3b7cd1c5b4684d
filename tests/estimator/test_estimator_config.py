"""Configuration validation, the public API surface and the package's purity."""

from __future__ import annotations

import ast
import dataclasses
import subprocess
import sys
from pathlib import Path

import pytest

import estimator
from estimator import DroneFilterConfig, EstimatorConfigError, TrackerConfig

PACKAGE = Path(estimator.__file__).parent


@pytest.mark.parametrize("cls", [DroneFilterConfig, TrackerConfig])
@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf"), "1.0", True])
def test_that_invalid_values_name_the_field_and_the_value(cls, bad):
    with pytest.raises(EstimatorConfigError, match=rf"{cls.__name__}\.reinit_gap_s must be .* got {bad!r}"):
        cls(reinit_gap_s=bad)


def test_that_gate_probability_must_be_below_one():
    with pytest.raises(EstimatorConfigError, match=r"gate_probability must be in \(0, 1\), got 1.0"):
        TrackerConfig(gate_probability=1.0)


def test_that_configs_are_frozen_and_reject_unknown_keywords():
    cfg = TrackerConfig()
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.drop_after_s = 1.0  # type: ignore[misc]
    with pytest.raises(TypeError, match="accel_noise"):
        DroneFilterConfig(accel_noise=1.0)  # type: ignore[call-arg]


def test_that_from_mapping_rejects_unknown_keys_and_says_where():
    with pytest.raises(EstimatorConfigError, match=r"antipodal.toml \[estimator.tracker\]: unknown key\(s\) \['drop_after'\]"):
        TrackerConfig.from_mapping({"drop_after": 2.0}, "antipodal.toml [estimator.tracker]")
    with pytest.raises(EstimatorConfigError, match=r"x.toml: DroneFilterConfig.position_noise_std_m"):
        DroneFilterConfig.from_mapping({"position_noise_std_m": -1}, "x.toml")
    assert TrackerConfig.from_mapping({"drop_after_s": 2.0}).drop_after_s == 2.0


def test_that_the_documented_api_is_exported():
    for name in ("DroneFilter", "DroneFilterConfig", "ObstacleTracker", "TrackerConfig", "GaussianState", "UpdateResult"):
        assert name in estimator.__all__ and hasattr(estimator, name)


def test_that_the_package_imports_neither_companion_nor_mavsim():
    code = "import estimator, sys; print(sorted({m.split('.')[0] for m in sys.modules} & {'companion', 'mavsim'}))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_that_the_package_is_pure_no_clocks_sockets_or_threads():
    forbidden = {"companion", "mavsim", "socket", "time", "threading", "asyncio", "datetime", "random"}
    for path in PACKAGE.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names = {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom):
                names = {(node.module or "").split(".")[0]}
            else:
                continue
            assert not names & forbidden, f"{path.name} imports {names & forbidden}"
