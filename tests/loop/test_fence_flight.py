"""A geofence flown in mavsim lockstep: around an exclusion zone in the way, inside the inclusion zone.

The fence is a QGroundControl ``.plan``'s geoFence (latitude/longitude, placed through mavsim's
GPS_GLOBAL_ORIGIN): an inclusion rectangle north -6..30 m, east -8..8 m, and an exclusion
square north 10..14 m, east -2..2 m across the straight line from the start (0, 0) to the
goal (24, 0). The planner keeps the drone's c_min contour (and its radius) inside the walls.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from companion.core.fence import Fence, PolygonZone
from companion.loop.goal_frames import to_geodetic
from companion.offline.harness import run_lockstep
from tests.support.missions import MAVSIM_ORIGIN, plan_dict

ROOT = Path(__file__).resolve().parents[2]
INCLUSION = [(-6.0, -8.0), (-6.0, 8.0), (30.0, 8.0), (30.0, -8.0)]
EXCLUSION = [(10.0, -2.0), (10.0, 2.0), (14.0, 2.0), (14.0, -2.0)]


def _latlon(points):
    return [[p.lat_deg, p.lon_deg] for p in (to_geodetic(np.array([n, e, 0.0]), MAVSIM_ORIGIN) for n, e in points)]


def fence_plan(path: Path, circles=()) -> Path:
    plan = plan_dict([(24.0, 0.0, -5.0)])
    plan["geoFence"]["polygons"] = [{"inclusion": True, "version": 1, "polygon": _latlon(INCLUSION)},
                                    {"inclusion": False, "version": 1, "polygon": _latlon(EXCLUSION)}]
    plan["geoFence"]["circles"] = [{"inclusion": inc, "version": 1, "circle": {"center": _latlon([c])[0], "radius": r}}
                                   for c, r, inc in circles]
    path.write_text(json.dumps(plan))
    return path


def _scenario(fence_file: Path | None) -> dict:
    data = tomllib.loads((ROOT / "configs" / "antipodal.toml").read_text())
    data.pop("world", None)
    data["scenario"]["duration_s"] = 40.0
    if fence_file is not None:
        data["mission"]["fence_file"] = str(fence_file)
    return data


LOCAL = Fence(polygons=(PolygonZone(np.array(INCLUSION), True), PolygonZone(np.array(EXCLUSION), False)))


def _truth_clearance(run) -> float:
    return min(LOCAL.clearance(p) for _, p, _ in run.extra["replan_truth"])


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    d = tmp_path_factory.mktemp("fence")
    plan = fence_plan(d / "fence.plan")
    fenced = run_lockstep(_scenario(plan), seed=0, tlog_path=d / "fenced.tlog")
    free = run_lockstep(_scenario(None), seed=0)
    fenced.extra["plan"] = plan
    return fenced, free


def test_the_fence_is_placed_before_anything_is_flown_and_said(flights):
    fenced, _ = flights
    c = fenced.companion
    texts = [text for _, text in c.state.events]
    placed = texts.index("companion: fence of 2 zones placed")
    assert all(not t.startswith("ENGAGED") for t in texts[:placed])
    assert c.fence.fence is not None and c.fence.fence.n_walls == 8


def test_the_drone_goes_around_the_exclusion_zone_and_stays_inside_the_inclusion_zone(flights):
    fenced, free = flights
    # without the fence the straight line crosses the exclusion square
    assert _truth_clearance(free) < -1.0
    clearance = _truth_clearance(fenced)
    radius = fenced.companion.planner_config.drone_radius_m
    assert clearance >= radius - 0.05, clearance            # the drone's body, in truth, sampled at every replan
    assert fenced.truth["goal_reached"], fenced.truth
    assert abs(fenced.summary()["min_fence_clearance_m"] - clearance) < 0.3     # the companion's own figure, from its estimate
    assert "min_fence_clearance_m" not in free.summary()
    # every plan's c_min contour kept to the walls: the exact re-check accepted every adopted plan
    assert all(r.safety_slack <= 1e-6 for r in fenced.companion.records if getattr(r, "safety_slack", None) is not None)


def test_a_fence_in_a_mission_plan_needs_no_second_file(tmp_path):
    from companion.loop.config import MissionConfig
    from companion.loop.fence_source import scenario_fence
    from companion.loop.vehicle_reference import VehicleReference

    plan = fence_plan(tmp_path / "mission.plan", circles=[((5.0, 0.0), 3.0, False)])
    src = scenario_fence(MissionConfig(None, 0.3, plan_file=str(plan)), VehicleReference())
    assert src is not None and src.n_zones == 3
    assert scenario_fence(MissionConfig(np.array([1.0, 0.0, -5.0]), 0.3), VehicleReference()) is None


def test_the_fenced_flight_replays_exactly_given_the_fence_as_fly_would_be(flights, tmp_path):
    from companion.offline.campaign.toml_writer import write_scenario

    fenced, _ = flights
    without = write_scenario(_scenario(None), tmp_path / "no_fence.toml")

    def replay(*extra):
        return subprocess.run([sys.executable, "-m", "companion.cli", "replay", str(fenced.tlog_path), "--scenario",
                               str(without), "--json", *extra], capture_output=True, text=True, cwd=ROOT, timeout=300)

    out = replay("--fence", str(fenced.extra["plan"]))
    assert out.returncode == 0, out.stderr[-800:]
    s = json.loads(out.stdout)
    assert s["commands_compared"] == s["commands_recorded"] > 100 and s["max_abs_diff_mps"] == 0.0
    out = replay()
    assert out.returncode == 1 and "--fence" not in out.stdout


def test_a_file_without_a_fence_is_one_line_exit_2(tmp_path):
    empty = tmp_path / "nofence.plan"
    empty.write_text(json.dumps(plan_dict([(5.0, 0.0, -5.0)])))
    out = subprocess.run([sys.executable, "-m", "companion.cli", "fly", "--scenario", "antipodal", "--fence", str(empty)],
                         capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert out.returncode == 2
    assert out.stderr.strip().count("\n") == 0 and "no geofence in it" in out.stderr, out.stderr
    data = _scenario(empty)
    from companion.errors import ConfigError
    from companion.offline.campaign.toml_writer import write_scenario
    from companion.loop.config import load_scenario
    with pytest.raises(ConfigError, match="fence_file .* no geofence"):
        load_scenario(write_scenario(data, tmp_path / "s.toml"))


def _fence_items():
    """The fence as QGroundControl uploads it (mission type FENCE): polygon vertices with their count in param1."""
    from pymavlink.dialects.v20 import common as mavlink2

    items = []
    for cmd, ring in ((mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, INCLUSION),
                      (mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION, EXCLUSION)):
        for lat, lon in _latlon(ring):
            items.append(mavlink2.MAVLink_mission_item_int_message(
                1, 1, len(items), mavlink2.MAV_FRAME_GLOBAL, cmd, 0, 1, len(ring), 0, 0, 0,
                int(round(lat * 1e7)), int(round(lon * 1e7)), 0.0, mavlink2.MAV_MISSION_TYPE_FENCE))
    return items


def test_the_vehicles_own_fence_is_downloaded_placed_and_kept(monkeypatch):
    import mavsim.missions

    real_init = mavsim.missions.MissionStore.__init__

    def holding_a_fence(self):
        real_init(self)
        self.items[1] = _fence_items()

    monkeypatch.setattr(mavsim.missions.MissionStore, "__init__", holding_a_fence)
    data = _scenario(None)
    data["mission"]["fence_file"] = "vehicle"
    run = run_lockstep(data, seed=0)
    c = run.companion
    texts = [text for _, text in c.state.events]
    assert texts.index("companion: downloading the vehicle's fence") < texts.index("companion: fence of 2 zones placed")
    assert c.fence.transfer.done and c.fence.transfer.resent == 0 and len(c.fence.transfer.items) == 8
    assert _truth_clearance(run) >= c.planner_config.drone_radius_m - 0.05 and run.truth["goal_reached"]


def test_a_vehicle_without_a_fence_is_one_error_and_nothing_flown():
    data = _scenario(None)
    data["mission"]["fence_file"] = "vehicle"
    data["scenario"]["duration_s"] = 4.0
    run = run_lockstep(data, seed=0)
    assert run.companion.goal_error == "the vehicle holds no fence (--fence vehicle): upload one from the ground station"
    assert run.companion.sequencer.phase.name == "GAVE_UP"
    assert not run.companion.sequencer.state.engaged and run.truth["path_length_m"] < 0.5


def test_a_goal_outside_the_fence_is_one_error_and_nothing_flown(tmp_path):
    data = _scenario(fence_plan(tmp_path / "fence.plan"))
    data["mission"]["goal_ned_m"] = [40.0, 0.0, -5.0]           # 10 m beyond the inclusion zone's north side
    data["scenario"]["duration_s"] = 4.0
    run = run_lockstep(data, seed=0)
    c = run.companion
    assert c.goal_error is not None and c.goal_error.startswith("the goal at N 40.0 E 0.0 D -5.0 is 10.0 m outside the fence")
    assert c.sequencer.phase.name == "GAVE_UP" and not c.sequencer.state.engaged
    assert "companion: goal outside the fence" in [text for _, text in c.state.events]


def test_px4s_fence_about_home_is_read_and_flown_inside(monkeypatch):
    """GF_MAX_HOR_DIST and GF_MAX_VER_DIST of mavsim's PX4 (no fence items stored): read with
    PARAM_REQUEST_READ and placed about HOME_POSITION as an inclusion circle and a ceiling."""
    data = _scenario(None)
    data["mission"]["fence_file"] = "vehicle"
    data["sim"]["params"] = {"GF_MAX_HOR_DIST": 30.0, "GF_MAX_VER_DIST": 5.8}
    run = run_lockstep(data, seed=0)
    c = run.companion
    texts = [text for _, text in c.state.events]
    assert "companion: fence of 1 zone placed, ceiling 5.8 m above home" in texts, texts
    assert c.fence.param_read.done and c.fence.param_read.resent == 0
    fence = c.fence.fence
    home = np.array(c.reference.home.local_ned_m)
    assert fence.ceiling_up_m == pytest.approx(-home[2] + 5.8)
    assert len(fence.circles) == 1 and fence.circles[0].radius_m == 30.0
    assert np.allclose(fence.circles[0].center, home[:2])
    heights = [-p[2] for _, p, _ in run.extra["replan_truth"]]
    assert run.truth["goal_reached"] and max(heights) < -home[2] + 5.8 - c.planner_config.drone_radius_m + 0.05


def test_a_goal_beyond_px4s_largest_distance_from_home_is_one_error_and_nothing_flown():
    data = _scenario(None)
    data["mission"]["fence_file"] = "vehicle"
    data["sim"]["params"] = {"GF_MAX_HOR_DIST": 14.0}
    data["scenario"]["duration_s"] = 6.0
    run = run_lockstep(data, seed=0)
    c = run.companion
    assert c.goal_error is not None and "outside the fence" in c.goal_error, c.goal_error
    assert not c.sequencer.state.engaged and run.truth["path_length_m"] < 0.5


def test_a_vehicle_that_never_answers_the_fence_parameters_is_one_error_naming_them(monkeypatch):
    import mavsim.autopilot

    monkeypatch.setattr(mavsim.autopilot.Autopilot, "_on_param_request_read", lambda self, *args: [])
    data = _scenario(None)
    data["mission"]["fence_file"] = "vehicle"
    data["scenario"]["duration_s"] = 8.0
    run = run_lockstep(data, seed=0)
    c = run.companion
    assert c.goal_error == ("the vehicle's fence: GF_MAX_HOR_DIST, GF_MAX_VER_DIST not read: no PARAM_VALUE for "
                            "GF_MAX_HOR_DIST, GF_MAX_VER_DIST after 5 requests 1 s apart"), c.goal_error
    assert not c.sequencer.state.engaged and run.truth["path_length_m"] < 0.5
    assert "companion: fence parameters not read" in [text for _, text in c.state.events]
