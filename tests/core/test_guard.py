"""The autopilot's predicted path along its route, and the first predicted conflict on it."""

from __future__ import annotations

import numpy as np
import pytest

from companion.core.guard import first_conflict, path_along_route, path_contours
from companion.core.overlap import contour_of_touch
from companion.errors import InputError


def test_that_the_path_runs_the_legs_at_the_speed_and_holds_at_the_end():
    route = np.array([[10.0, 0.0, -5.0], [10.0, 10.0, -5.0]])
    times = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 10.0])
    path = path_along_route([0.0, 0.0, -5.0], route, 5.0, times)
    np.testing.assert_allclose(path, [[0, 0, -5], [5, 0, -5], [10, 0, -5], [10, 5, -5], [10, 10, -5], [10, 10, -5]])
    # distance along the path grows at the speed until the end of the route
    steps = np.linalg.norm(np.diff(path, axis=0), axis=1)
    np.testing.assert_allclose(steps[:4], 5.0)


def test_that_points_on_top_of_each_other_and_an_empty_route_are_held():
    p = [1.0, 2.0, -3.0]
    np.testing.assert_allclose(path_along_route(p, np.empty((0, 3)), 3.0, [0.0, 5.0]), [p, p])
    path = path_along_route(p, [p, [1.0, 5.0, -3.0]], 1.0, [0.0, 1.0, 3.0, 9.0])
    np.testing.assert_allclose(path[:, 1], [2.0, 3.0, 5.0, 5.0])


def test_that_each_leg_is_flown_at_its_own_speed():
    """A DO_CHANGE_SPEED between the legs: 10 m at 5 m/s (2 s), then 10 m at 2 m/s (5 s)."""
    route = np.array([[10.0, 0.0, -5.0], [10.0, 10.0, -5.0]])
    times = np.array([0.0, 1.0, 2.0, 3.0, 4.5, 7.0, 9.0])
    path = path_along_route([0.0, 0.0, -5.0], route, [5.0, 2.0], times)
    np.testing.assert_allclose(path, [[0, 0, -5], [5, 0, -5], [10, 0, -5], [10, 2, -5], [10, 5, -5], [10, 10, -5],
                                      [10, 10, -5]])
    np.testing.assert_allclose(path_along_route([0.0, 0.0, -5.0], route, [4.0, 4.0], times),
                               path_along_route([0.0, 0.0, -5.0], route, 4.0, times))


def test_that_speeds_not_one_per_leg_are_refused():
    with pytest.raises(InputError, match="one per leg"):
        path_along_route([0, 0, 0], [[1, 0, 0], [2, 0, 0]], [1.0, 1.0, 1.0], [0.0])


@pytest.mark.parametrize("speed", [0.0, -1.0, float("nan"), [1.0, 0.0]])
def test_that_a_speed_that_is_not_positive_is_refused(speed):
    with pytest.raises(InputError, match="speed_mps"):
        path_along_route([0, 0, 0], [[1, 0, 0], [2, 0, 0]], speed, [0.0])


def test_that_the_first_conflict_is_the_earliest_step_below_c_min():
    times = np.arange(1, 6) * 0.5
    contours = np.array([[0.99, 0.95, 0.40, 0.10, 0.30],
                         [0.99, 0.85, 0.95, 0.95, 0.99]])
    c = first_conflict(contours, times, 0.9)
    assert (c.obstacle, c.step, c.in_s, c.contour, c.min_contour) == (1, 1, 1.0, 0.85, 0.85)
    c = first_conflict(contours, times, 0.5)        # only obstacle 0 goes below 0.5, at step 2
    assert (c.obstacle, c.step, c.in_s, c.contour, c.min_contour) == (0, 2, 1.5, 0.40, 0.10)
    assert first_conflict(contours, times, 0.05) is None
    assert first_conflict(np.empty((0, 5)), times, 0.9) is None


def test_that_path_contours_are_the_overlap_contours_of_each_pair():
    """A drone flying east past an obstacle hovering 2 m north of its path: the contour dips at
    the closest step, and each entry is :func:`contour_of_touch` of that pair."""
    times = np.arange(1, 11) * 0.5
    drone = path_along_route([0.0, -5.0, -5.0], [[0.0, 5.0, -5.0]], 2.0, times)
    dcov = np.broadcast_to(0.04 * np.eye(3), (10, 3, 3))
    obst = np.broadcast_to([2.0, 0.0, -5.0], (1, 10, 3))
    ocov = np.broadcast_to(0.25 * np.eye(3), (1, 10, 3, 3))
    ct = path_contours(drone, dcov, obst, ocov, np.array([0.8]))
    assert ct.shape == (1, 10)
    assert int(np.argmin(ct[0])) == 4            # 5 m east at 2 m/s: at 2.5 s, step 4
    want = contour_of_touch(drone[4], dcov[4], obst[0, 4], ocov[0, 4], 0.8)
    assert ct[0, 4] == pytest.approx(float(want))
    assert ct[0, 0] > ct[0, 4]
