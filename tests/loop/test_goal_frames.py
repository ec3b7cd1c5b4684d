"""Goals in the three frames: parsing, placing through the vehicle's origin and home, the wait, and flight."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.core import geo
from companion.errors import ConfigError
from companion.loop.goal_frames import GeoPoint, GoalSpec, Home, parse_goal, place, to_geodetic
from companion.mavlink import traffic

ORIGIN = GeoPoint(47.397742, 8.545594, 488.0)


def test_that_the_projection_is_the_one_the_traffic_decoder_and_mavsim_use():
    from mavsim.geo import ned_to_global
    rng = np.random.default_rng(3)
    for north, east in rng.uniform(-5000.0, 5000.0, size=(50, 2)):
        lat, lon, _ = ned_to_global(north, east, 0.0, ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m)
        n, e = geo.project(lat, lon, ORIGIN.lat_deg, ORIGIN.lon_deg)
        assert (n, e) == pytest.approx((north, east), abs=1e-6)
        via_traffic = traffic.global_to_ned(lat, lon, ORIGIN.alt_m, traffic.GlobalOrigin(*vars(ORIGIN).values()))
        assert via_traffic[:2] == pytest.approx([n, e], abs=1e-9)
        assert geo.reproject(n, e, ORIGIN.lat_deg, ORIGIN.lon_deg) == pytest.approx((lat, lon), abs=1e-12)
    assert geo.project(ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.lat_deg, ORIGIN.lon_deg) == (0.0, 0.0)


@pytest.mark.parametrize("text, spec", [
    ("ned:24,0,-5", GoalSpec("ned", (24.0, 0.0, -5.0))),
    ("home:10, -3.5, 5", GoalSpec("home", (10.0, -3.5, 5.0))),
    ("geo:47.3978,8.5456,493amsl", GoalSpec("geo", (47.3978, 8.5456, 493.0), "amsl")),
    ("GEO:47.3978,8.5456,5 rel", GoalSpec("geo", (47.3978, 8.5456, 5.0), "rel")),
])
def test_that_the_goal_syntax_reads_each_frame(text, spec):
    assert parse_goal(text) == spec


@pytest.mark.parametrize("text, says", [
    ("24,0,-5", "expected ned:"), ("ecef:1,2,3", "expected ned:"), ("ned:1,2", "three"),
    ("geo:47.4,8.5,493", "amsl or"), ("geo:147.4,8.5,493amsl", "out of range"), ("ned:a,b,c", "not numbers"),
    ("ned:1e6,0,-5", "away"),
])
def test_that_a_bad_goal_says_what_is_wrong(text, says):
    with pytest.raises(ConfigError, match=says):
        parse_goal(text)


def test_that_one_point_placed_from_each_frame_is_the_same_point():
    home = Home(GeoPoint(47.3978, 8.5457, 489.5), (3.0, 7.0, -1.5))   # home is not the origin
    ned = np.array([40.0, -25.0, -6.0])
    point = to_geodetic(ned, ORIGIN)
    specs = [
        GoalSpec("ned", tuple(ned)),
        GoalSpec("home", (ned[0] - 3.0, ned[1] - 7.0, -(ned[2] + 1.5))),
        GoalSpec("geo", (point.lat_deg, point.lon_deg, point.alt_m), "amsl"),
        GoalSpec("geo", (point.lat_deg, point.lon_deg, point.alt_m - 489.5), "rel"),
    ]
    for spec in specs:
        assert place(spec, ORIGIN, home) == pytest.approx(ned, abs=1e-6), spec


def test_that_a_goal_is_not_placed_without_the_references_it_needs():
    home = Home(ORIGIN, (0.0, 0.0, 0.0))
    assert place(GoalSpec("geo", (47.4, 8.5, 500.0)), None, home) is None
    assert place(GoalSpec("geo", (47.4, 8.5, 5.0), "rel"), ORIGIN, None) is None
    assert place(GoalSpec("home", (1.0, 2.0, 3.0)), ORIGIN, None) is None
    assert place(GoalSpec("ned", (1.0, 2.0, -3.0)), None, None) == pytest.approx([1.0, 2.0, -3.0])
    assert math.isclose(place(GoalSpec("geo", (47.397742, 8.545594, 5.0), "rel"), ORIGIN, home)[2], -5.0)


# ---------------------------------------------------------------- in flight (mavsim, lockstep)

def _open_space(mission: dict, duration_s: float = 14.0) -> dict:
    import tomllib
    from pathlib import Path
    data = tomllib.loads((Path(__file__).resolve().parents[2] / "configs" / "antipodal.toml").read_text())
    data.pop("world", None)
    data["scenario"]["duration_s"] = duration_s
    data["mission"] = {"goal_tolerance_m": 0.3, **mission}
    return data


def test_that_one_geodetic_goal_given_in_the_three_frames_is_flown_to_the_same_point():
    """mavsim's home is its origin (lat 47.397742, lon 8.545594, 488 m AMSL): the same point
    given in local NED, from home, and on the earth (AMSL and relative) ends the flights
    within 0.1 m of each other, each asked for through GPS_GLOBAL_ORIGIN / HOME_POSITION."""
    from companion.offline.harness import run_lockstep
    ned = np.array([10.0, 4.0, -5.0])
    point = to_geodetic(ned, ORIGIN)
    frames = {
        "ned": {"goal_ned_m": ned.tolist()},
        "home": {"goal_home_m": [10.0, 4.0, 5.0]},
        "geo": {"goal_geo": [point.lat_deg, point.lon_deg, point.alt_m]},
        "geo rel": {"goal_geo": [point.lat_deg, point.lon_deg, 5.0], "goal_geo_altitude": "rel"},
    }
    ends = {}
    for name, mission in frames.items():
        run = run_lockstep(_open_space(mission), seed=0, stop_after_goal_s=None)
        c = run.companion
        assert c.goal.goal == pytest.approx(ned, abs=1e-6), name
        assert c.state.goal_reached_t_s is not None, name
        ends[name] = np.asarray(run.companion.records[-1].drone_position)
        if name.startswith("geo"):
            assert any("goal waits for GPS_GLOBAL_ORIGIN" in text for _, text in c.state.events)
    for name, end in ends.items():
        assert np.linalg.norm(end - ends["ned"]) < 0.1, name
        assert np.linalg.norm(end - ned) < 0.3, name


def test_that_a_goal_the_vehicle_never_places_ends_the_run_with_one_error_and_nothing_flown():
    from companion.mavlink.offboard import Phase
    from companion.offline.harness import run_lockstep

    def no_origin(_t, direction, packet: bytes) -> bool:   # the origin never reaches the companion
        return direction == "to_companion" and packet[0] == 0xFD and int.from_bytes(packet[7:10], "little") == 49

    run = run_lockstep(_open_space({"goal_geo": [47.3978, 8.5457, 5.0], "goal_geo_altitude": "rel", "goal_wait_s": 3.0},
                                   duration_s=6.0), drop=no_origin, stop_after_goal_s=None)
    c = run.companion
    assert c.sequencer.phase is Phase.GAVE_UP
    assert "not placed: no GPS_GLOBAL_ORIGIN from the autopilot after 3 s" in c.goal_error
    assert c.records == [] and run.truth["final_mode"] == "AUTO.LOITER"
    assert c.reference.origin_request.sent == 2   # at 0.05 s and 2.05 s, then it gave up
