"""The fence's walls about the drone: a convex region that holds it and stays in (out of) every zone."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from companion.core.fence import (CIRCLE_SIDES, CircleZone, Fence, PolygonZone, point_in_polygon, polygon_walls)
from companion.loop.goal import route_target


def _star(seed: int, n: int) -> np.ndarray:
    """A star-shaped polygon about the origin, usually not convex (radii 5..30 m)."""
    rng = np.random.default_rng(seed)
    a = np.sort(rng.uniform(0, 2 * np.pi, n))
    r = rng.uniform(5, 30, n)
    return np.column_stack([r * np.cos(a), r * np.sin(a)])


def _region_samples(normals: np.ndarray, offsets: np.ndarray, rng, box: float = 60.0, k: int = 4000) -> np.ndarray:
    q = rng.uniform(-box, box, (k, 2))
    return q[np.all(q @ normals[:, :2].T <= offsets[None, :] - 1e-9, axis=1)]


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(3, 12), inclusion=st.booleans())
def test_the_walls_hold_the_drone_and_keep_every_allowed_point_on_its_side_of_the_zone(seed, n, inclusion):
    v = _star(seed, n)
    zone = PolygonZone(v, inclusion)
    rng = np.random.default_rng(seed + 1)
    # the drone where it may be: inside an inclusion zone, outside an exclusion zone
    draws = rng.uniform(-40, 40, (200, 2))
    allowed = [q for q in draws if point_in_polygon(v, q) == inclusion]
    assume(allowed)
    p = allowed[0]
    normals, offsets = polygon_walls(zone, p)
    assert normals.shape == (n, 2) and offsets.shape == (n,)
    assert np.all(normals @ p <= offsets + 1e-9)                               # the drone is on the allowed side
    for q in _region_samples(normals, offsets, rng):
        assert point_in_polygon(v, q) == inclusion, (p.tolist(), q.tolist())   # the region never crosses the zone


def test_a_convex_inclusion_polygon_with_the_drone_inside_is_its_own_edges():
    square = PolygonZone([[0, 0], [0, 10], [10, 10], [10, 0]], True)          # clockwise in north/east
    normals, offsets = polygon_walls(square, np.array([3.0, 4.0]))
    got = sorted((tuple(np.round(n, 9)), round(float(b), 9)) for n, b in zip(normals, offsets))
    assert got == sorted([((-1.0, 0.0), 0.0), ((0.0, -1.0), 0.0), ((1.0, 0.0), 10.0), ((0.0, 1.0), 10.0)])


def test_an_exclusion_circle_is_one_tangent_wall_and_an_inclusion_circle_its_inscribed_polygon():
    fence = Fence(circles=(CircleZone([0, 0], 10.0, False), CircleZone([0, 0], 50.0, True)), ceiling_up_m=30.0)
    assert fence.n_walls == 1 + CIRCLE_SIDES + 1
    normals, offsets = fence.walls(np.array([20.0, 0.0, -5.0]))
    assert normals.shape == (fence.n_walls, 3)
    # the exclusion circle's wall (last but the ceiling): tangent at (10, 0), facing the drone
    excl = [i for i in range(fence.n_walls) if np.allclose(normals[i], [-1.0, 0.0, 0.0]) and np.isclose(offsets[i], -10.0)]
    assert excl, (normals, offsets)
    assert np.allclose(normals[-1], [0, 0, -1]) and offsets[-1] == 30.0
    # the inscribed 16-gon: every vertex on the circle, every wall 50 cos(pi/16) from the centre
    assert np.allclose(np.sort(offsets[:CIRCLE_SIDES]), 50.0 * np.cos(np.pi / CIRCLE_SIDES))


def test_clearance_is_signed_by_the_breach():
    fence = Fence(polygons=(PolygonZone([[0, 0], [0, 10], [10, 10], [10, 0]], True),
                            PolygonZone([[4, 4], [4, 6], [6, 6], [6, 4]], False)), ceiling_up_m=20.0)
    assert fence.clearance(np.array([1.0, 5.0, -5.0])) == pytest.approx(1.0)
    assert fence.clearance(np.array([5.0, 5.0, -5.0])) == pytest.approx(-1.0)      # in the exclusion zone
    assert fence.clearance(np.array([12.0, 5.0, -5.0])) == pytest.approx(-2.0)     # out of the inclusion zone
    assert fence.clearance(np.array([2.0, 2.0, -21.0])) == pytest.approx(-1.0)     # above the ceiling


@pytest.mark.parametrize("vertices", [[[0, 0], [1, 1]], [[0, 0], [1, 1], [2, 2]], [[0, 0], [np.nan, 1], [1, 0]]])
def test_degenerate_polygons_are_refused(vertices):
    with pytest.raises(ValueError):
        PolygonZone(vertices, True)


def _follow(fence: Fence, start, goal, margin_m: float = 1.4, step_m: float = 0.3, steps: int = 600, at=None):
    """A point that moves ``step_m`` a step toward the router's target, the target taken 12 m ahead on
    the leg from ``start`` to ``goal`` (a mission leg's, :func:`route_target`): the points it passed
    and whether it got there; from ``at`` (default: the leg's start)."""
    router = fence.router(margin_m)
    leg = np.array([*start, -5.0])
    p, goal = np.array([*(start if at is None else at), -5.0]), np.array([*goal, -5.0])
    passed = [p[:2].copy()]
    for _ in range(steps):
        if np.linalg.norm(goal - p) < 0.05:
            return passed, True
        t = router.target(p, route_target(leg, goal, p, 12.0), goal)
        d = t - p
        p = p + d * min(1.0, step_m / max(np.linalg.norm(d), 1e-12))
        passed.append(p[:2].copy())
    return passed, False


def test_the_router_leads_round_a_building_the_leg_grazes_to_the_waypoint():
    """Mission campaign seed 1 episode 124: the last leg grazes a building's far edge. The drone
    reached the first corner of the way round and stayed there 28 s: the router kept giving that
    corner while the next one was not in sight with the margin."""
    building = np.array([[-28.1, -17.2], [-32.1, -18.0], [-31.3, -21.9], [-27.3, -21.2]])
    fence = Fence(polygons=(PolygonZone(np.array([[-47.1, -28.1], [-47.1, 12.5], [6.4, 12.5], [6.4, -28.1]]), True),
                            PolygonZone(building, False)))
    margin = 0.434 + 1.0                                      # the drone's radius + 1 m
    corner = fence.router(margin).nodes[3]                    # where it stayed: (-25.6, -22.3)
    assert np.linalg.norm(corner - [-25.6, -22.3]) < 0.1     # (the vertices rounded to 0.1 m)
    for at in (None, corner):
        passed, arrived = _follow(fence, (-21.9, -18.0), (-40.7, -21.7), margin_m=margin, at=at)
        assert arrived
        assert all(not point_in_polygon(building, q) for q in passed)


@settings(max_examples=40, deadline=None)
@given(side=st.floats(4.0, 6.0), turn=st.floats(0.0, np.pi / 2), offset=st.floats(-1.0, 1.0), along=st.floats(0.35, 0.65))
def test_the_router_leads_round_any_building_across_a_leg(side, turn, offset, along):
    """A square building of 4 to 6 m, any way turned, across a 25 m leg within 1 m of its line (the
    mission campaign's): followed, the router's targets take the drone round it to the waypoint."""
    start, goal = np.array([0.0, 0.0]), np.array([25.0, 0.0])
    centre = np.array([25.0 * along, offset])
    c, s = np.cos(turn), np.sin(turn)
    square = centre + 0.5 * side * np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) @ np.array([[c, s], [-s, c]])
    fence = Fence(polygons=(PolygonZone(np.array([[-8.0, -12.0], [33.0, -12.0], [33.0, 12.0], [-8.0, 12.0]]), True),
                            PolygonZone(square, False)))
    passed, arrived = _follow(fence, start, goal)
    assert arrived
    assert all(not point_in_polygon(square, q) for q in passed)
