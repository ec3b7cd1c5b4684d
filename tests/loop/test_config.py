"""The companion's scenario loader: every section validated at load, errors naming file, section and key."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from companion.errors import ConfigError
from companion.loop.config import SIMULATOR_KEYS, load_scenario
from companion.mavlink.offboard import OffboardConfig
from mavsim import scenario as mavsim_scenario

ROOT = Path(__file__).resolve().parents[2]
MINIMAL = '[mission]\ngoal_ned_m = [4.0, 0.0, -5.0]\ngoal_tolerance_m = 0.3\n'


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "s.toml"
    path.write_text(MINIMAL + text)
    return path


def test_that_the_offboard_table_is_read_into_the_scenario(tmp_path):
    sc = load_scenario(write(tmp_path, "[offboard]\nprestream_s = 2.0\nmax_retries = 3\nreengage = true\n"))
    assert sc.offboard == OffboardConfig(prestream_s=2.0, max_retries=3, reengage=True)


def test_that_offboard_defaults_apply_without_the_table(tmp_path):
    assert load_scenario(write(tmp_path, "")).offboard == OffboardConfig()


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("[offboard]\nprestream_s = -1.0\n", r"s\.toml \[offboard\]: prestream_s = -1.0 must be >= 0"),
        ("[offboard]\nmax_retries = 2.5\n", r"s\.toml \[offboard\]: max_retries = 2.5 must be an integer"),
        ("[offboard]\nretry_s = 1.0\n", r"s\.toml \[offboard\]: unknown key\(s\) retry_s"),
        ("[offboard]\nheartbeat_timeout_s = inf\n", r"s\.toml \[offboard\]: heartbeat_timeout_s = inf must be a finite"),
        ("[companion]\nprestream_s = 1.0\n", r"s\.toml \[companion\]: unknown key\(s\) prestream_s"),
        ("[companion]\nsetpoint_rate_hz = inf\n", r"s\.toml \[companion\]: setpoint_rate_hz = inf must be a finite"),
        ("[companion]\nobstacle_radius_m = nan\n", r"s\.toml \[companion\]: obstacle_radius_m = nan must be a finite"),
        ("[companion]\nestimate_timeout_s = -1\n", r"s\.toml \[companion\]: estimate_timeout_s = -1 must be positive"),
        ("[companion]\ndrone_covariance = 'guess'\n", r"\[companion\]: drone_covariance = 'guess' is not one of"),
        ("[companion]\nresponse_state = 'carried'\n", r"\[companion\]: response_state = 'carried' is not one of"),
        ("[companion]\nresponse_state = 'observed'\n",
         r"s\.toml \[companion\]: response_state = 'observed' needs \[planner\] vehicle_response"),
        ("[companion]\nresponse_state = 'observed'\nsetpoint_kind = 'position_velocity'\n",
         r"s\.toml \[companion\]: response_state = 'observed' needs setpoint_kind = 'velocity'"),
        ("[planner]\nhorizon_steps = 100000000\n", r"\[planner\]: horizon_steps = 100000000 must be >= 2 and <= 400"),
        ("[sim]\nbogus = 1\n", r"s\.toml \[sim\]: unknown key\(s\) bogus"),
        ("[[world.obstacles]]\nname = 'a'\nwingspan_m = 2\n", r"s\.toml \[\[world\.obstacles\]\] #1: unknown key\(s\) wingspan_m"),
        ("[world]\nobstacles = 5\n", r"s\.toml \[\[world\.obstacles\]\]: must be an array of tables"),
        ("[map]\nwalls = [{normal_ned = [0, 0, 0], offset_m = 1}]\n", r"\[\[map\.walls\]\] #1: normal_ned must not be zero"),
        ("[[map.static_obstacles]]\ncenter_ned_m = [1, 2]\n", r"\[\[map\.static_obstacles\]\] #1: center_ned_m = \[1, 2\]"),
        ("[scenario]\nduration_s = nan\n", r"s\.toml \[scenario\]: duration_s = nan must be a finite"),
        ("[estimator]\ndrone = 3\n", r"s\.toml \[estimator\.drone\]: must be a table"),
        ("[mystery]\n", r"s\.toml: unknown section\(s\) mystery"),
    ],
)
def test_that_a_bad_value_names_file_section_and_key(tmp_path, text, match):
    with pytest.raises(ConfigError, match=match):
        load_scenario(write(tmp_path, text))


def test_that_a_section_that_is_not_a_table_is_named(tmp_path):
    path = tmp_path / "m.toml"
    path.write_text("mission = 5\n")
    with pytest.raises(ConfigError, match=r"m\.toml \[mission\]: must be a table, got int 5"):
        load_scenario(path)


def test_that_goal_tolerance_has_no_default_in_either_program(tmp_path):
    path = tmp_path / "g.toml"
    path.write_text("[mission]\ngoal_ned_m = [4.0, 0.0, -5.0]\n")
    with pytest.raises(ConfigError, match=r"g\.toml \[mission\]: goal_tolerance_m is required"):
        load_scenario(path)
    with pytest.raises(mavsim_scenario.ScenarioError, match=r"g\.toml: \[mission\] goal_tolerance_m: missing"):
        mavsim_scenario.load_scenario(path)


def test_that_both_programs_read_the_same_goal_tolerance_from_every_shipped_scenario():
    for path in sorted((ROOT / "configs").glob("*.toml")):
        comp, sim = load_scenario(path), mavsim_scenario.load_scenario(path)
        assert comp.mission.goal_tolerance_m == sim.goal_tolerance_m == tomllib.loads(path.read_text())["mission"]["goal_tolerance_m"]


def test_that_the_declared_simulator_schema_is_mavsims_own():
    assert SIMULATOR_KEYS == {
        "sim": frozenset(mavsim_scenario.SIM_KEYS),
        "world": frozenset(mavsim_scenario.WORLD_KEYS),
        "world.obstacles": frozenset(mavsim_scenario.OBSTACLE_KEYS),
    }


@pytest.mark.parametrize("content", [b"\xff\xfe\x00garbage\x9c" * 20, b"[mission\n"])
def test_that_a_file_that_is_not_utf8_toml_is_one_clear_error(tmp_path, content):
    path = tmp_path / "r.toml"
    path.write_bytes(content)
    with pytest.raises(ConfigError, match=r"r\.toml: not (a UTF-8 text file|valid TOML)"):
        load_scenario(path)


def test_that_a_directory_or_an_oversized_file_is_refused(tmp_path):
    with pytest.raises(ConfigError, match="is a directory, not a scenario file"):
        load_scenario(tmp_path)
    big = tmp_path / "big.toml"
    big.write_text(MINIMAL + "# " + "x" * (1 << 20) + "\n")
    with pytest.raises(ConfigError, match=r"big\.toml: scenario file larger than 1048576 bytes"):
        load_scenario(big)
