"""Where the PX4 fleet flight puts its vehicles (no PX4 needed): :func:`tests.px4.fleet.plan_fleet`.

Drone i starts where SIH is told to put it (``PX4_HOME_LAT/LON/ALT``): on the 12 m circle of
``configs/swap_px4.toml`` about the fleet's origin, on the ground; its ``--goal`` is the
opposite point, 5 m above its home. Checked by mapping both back into the fleet's frame.
"""

from __future__ import annotations

import math

import pytest

from companion.loop.goal_frames import parse_goal
from mavsim.geo import global_to_ned
from tests.px4.fleet import SWAP_PX4, plan_fleet

ORIGIN = (47.397742, 8.545594, 488.0)


def test_three_drones_start_120_degrees_apart_on_the_circle_and_aim_at_the_opposite_point(tmp_path):
    drones = plan_fleet(SWAP_PX4, 3, tmp_path)
    assert len(drones) == 3 and all(d["scenario"].is_file() for d in drones)
    bearings = []
    for d in drones:
        north, east, down = global_to_ned(*d["home"], *ORIGIN)
        assert math.hypot(north, east) == pytest.approx(6.0, abs=1e-3) and down == pytest.approx(0.0, abs=1e-6)
        bearings.append(math.degrees(math.atan2(east, north)) % 360.0)
        goal = parse_goal(d["goal"])
        assert goal.frame == "geo" and goal.altitude == "rel" and goal.values[2] == pytest.approx(5.0)
        gn, ge, _ = global_to_ned(goal.values[0], goal.values[1], ORIGIN[2], *ORIGIN)
        assert (gn, ge) == pytest.approx((-north, -east), abs=1e-3)       # the antipodal point
    assert sorted(bearings) == pytest.approx([0.0, 120.0, 240.0], abs=1e-3)
