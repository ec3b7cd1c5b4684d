"""A geofence as the planner's walls: each zone's half-planes about the drone, in local NED.

A fence is a set of zones in the local frame (north/east metres; the fence is vertical, a
zone covers every altitude): inclusion polygons and circles the drone must stay in,
exclusion polygons and circles it must stay out of, and an optional ceiling (metres up
from the local origin). The planner keeps the drone's ``c_min`` contour on the inner side of
straight walls (:class:`~companion.core.planner.request.PlanRequest` ``walls_normal``,
``walls_offset``: ``n . p <= b`` for every step), so each replan turns the fence into
walls about the plan's start position ``p``: a *local convexification*.

**Polygons**, inclusion or exclusion, convex or not: one wall per edge, the line through
the point of the edge nearest ``p``, square to the direction from ``p`` to it; except that
for an inclusion zone, while ``p`` is inside the edge's line, the wall is that line (for a
convex zone its edges are then exactly its walls; for an exclusion zone the edge's line
would reach past its corners and hold the drone beside the zone). Every wall has ``p`` on its
allowed side and leaves the whole edge on its boundary or beyond it, so the walls'
intersection is a convex region that holds ``p`` and meets no edge inside it: it cannot
cross the zone's boundary, and lies inside an inclusion zone that holds ``p`` and outside
an exclusion zone that does not. For a convex inclusion polygon with ``p`` inside, the
walls are exactly its edges. The region is re-made every replan as the drone moves, as
the obstacles' separating hyperplanes are.

**Circles.** An inclusion circle is flown as its inscribed regular polygon of
:data:`CIRCLE_SIDES` sides (inside the circle by at most ``r (1 - cos(pi / 16))``, 1.9 %
of its radius); an exclusion circle is one wall, tangent at the point of the circle
nearest ``p`` (the whole circle beyond it).

**Ceiling**: one wall, ``-z <= ceiling_up_m``.

Every zone gives a fixed number of walls (:attr:`Fence.n_walls`), whatever ``p`` is, so a
flight's QP keeps its layout. Pure: arrays in, arrays out; metres, NED.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Sides of the regular polygon an inclusion circle is flown as (inscribed).
CIRCLE_SIDES = 16
#: A corner of the way round counts as reached within this fraction of the router's margin.
REACHED_FRACTION = 0.5
_EPS = 1e-9


@dataclass(frozen=True)
class PolygonZone:
    """A polygon zone: ``vertices`` (V, 2) north/east m in order (either winding), V >= 3."""

    vertices: np.ndarray
    inclusion: bool

    def __post_init__(self) -> None:
        v = np.asarray(self.vertices, dtype=float).reshape(-1, 2)
        if v.shape[0] >= 2 and np.allclose(v[0], v[-1]):
            v = v[:-1]                                        # a closed ring: the last vertex repeats the first
        if v.shape[0] < 3 or not np.all(np.isfinite(v)):
            raise ValueError(f"a fence polygon needs 3 or more finite vertices, got {v.shape[0]}")
        if abs(_signed_area(v)) < 1e-6:
            raise ValueError("a fence polygon has no area")
        object.__setattr__(self, "vertices", v)

    @property
    def n_walls(self) -> int:
        return int(self.vertices.shape[0])


@dataclass(frozen=True)
class CircleZone:
    """A circle zone: ``center`` (2,) north/east m, ``radius_m`` > 0."""

    center: np.ndarray
    radius_m: float
    inclusion: bool

    def __post_init__(self) -> None:
        c = np.asarray(self.center, dtype=float).reshape(2)
        if not (np.all(np.isfinite(c)) and np.isfinite(self.radius_m) and self.radius_m > 0):
            raise ValueError("a fence circle needs a finite centre and a positive radius")
        object.__setattr__(self, "center", c)

    @property
    def n_walls(self) -> int:
        return CIRCLE_SIDES if self.inclusion else 1

    def inscribed(self) -> PolygonZone:
        """The inscribed regular polygon of :data:`CIRCLE_SIDES` sides (an inclusion circle as flown)."""
        a = 2 * np.pi * np.arange(CIRCLE_SIDES) / CIRCLE_SIDES
        return PolygonZone(self.center + self.radius_m * np.column_stack([np.cos(a), np.sin(a)]), self.inclusion)


@dataclass(frozen=True)
class Fence:
    """Zones in the local frame and an optional ceiling (m above the local origin)."""

    polygons: tuple[PolygonZone, ...] = ()
    circles: tuple[CircleZone, ...] = ()
    ceiling_up_m: float | None = None
    _flown: tuple[PolygonZone, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        flown = tuple(self.polygons) + tuple(c.inscribed() for c in self.circles if c.inclusion)
        object.__setattr__(self, "_flown", flown)

    @property
    def n_walls(self) -> int:
        """Walls this fence gives at every replan."""
        return (sum(p.n_walls for p in self.polygons) + sum(c.n_walls for c in self.circles)
                + (self.ceiling_up_m is not None))

    @property
    def empty(self) -> bool:
        return self.n_walls == 0

    def walls(self, position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Normals (W, 3) and offsets (W,) of the walls about ``position`` (NED m): ``n . p <= b``."""
        p = np.asarray(position, dtype=float).reshape(3)
        normals, offsets = [], []
        for zone in self._flown:
            n, b = polygon_walls(zone, p[:2])
            normals.append(np.column_stack([n, np.zeros(len(b))]))
            offsets.append(b)
        for circle in self.circles:
            if not circle.inclusion:
                n, b = exclusion_circle_wall(circle, p[:2])
                normals.append(np.array([[n[0], n[1], 0.0]]))
                offsets.append(np.array([b]))
        if self.ceiling_up_m is not None:
            normals.append(np.array([[0.0, 0.0, -1.0]]))
            offsets.append(np.array([float(self.ceiling_up_m)]))
        if not normals:
            return np.zeros((0, 3)), np.zeros(0)
        return np.concatenate(normals), np.concatenate(offsets)

    def clearance(self, point: np.ndarray) -> float:
        """Signed distance (m) from a NED point to the fence: positive inside every inclusion
        zone, outside every exclusion zone and below the ceiling; negative by how far it breaches."""
        q = np.asarray(point, dtype=float).reshape(3)
        d = np.inf
        for zone in self.polygons:
            inside = point_in_polygon(zone.vertices, q[:2])
            dist = distance_to_boundary(zone.vertices, q[:2])
            d = min(d, dist if inside == zone.inclusion else -dist)
        for c in self.circles:
            r = float(np.linalg.norm(q[:2] - c.center))
            d = min(d, (c.radius_m - r) if c.inclusion else (r - c.radius_m))
        if self.ceiling_up_m is not None:
            d = min(d, self.ceiling_up_m + q[2])
        return float(d)


    def router(self, margin_m: float) -> "FenceRouter":
        """A router around the exclusion zones, corners kept ``margin_m`` off (see :class:`FenceRouter`)."""
        return FenceRouter(self, margin_m)


class FenceRouter:
    """The shortest way around the fence's zones, for the planner's target: a visibility graph.

    Straight walls keep the drone safe but cannot show it the way round: flying at an
    exclusion zone's face, the face's wall holds it where the straight line to the goal
    meets it. The router gives the planner a target along the shortest polyline from the
    drone to its target that keeps out of every exclusion zone and inside every inclusion
    zone: its nodes are the zones' corners moved ``margin_m`` out of the exclusion zones
    (into the inclusion zones), and exclusion circles' circumscribed octagons likewise.
    The graph among the corners is built once; each call adds the start and the end.
    Guidance only: the walls keep the promise, not the route.
    """

    def __init__(self, fence: Fence, margin_m: float) -> None:
        self.margin_m = float(margin_m)
        self.blocked = tuple(PolygonZone(z.vertices, False) for z in fence.polygons if not z.inclusion) + tuple(
            _octagon(c, 0.0) for c in fence.circles if not c.inclusion)
        self.allowed = tuple(z for z in fence._flown if z.inclusion)
        nodes = [_pushed(z.vertices, margin_m, outward=True) for z in fence.polygons if not z.inclusion]
        nodes += [_octagon(c, margin_m).vertices for c in fence.circles if not c.inclusion]
        nodes += [_pushed(z.vertices, margin_m, outward=False) for z in self.allowed]
        pts = np.concatenate(nodes) if nodes else np.zeros((0, 2))
        self.nodes = pts[[self._free_point(q) for q in pts]] if len(pts) else pts
        n = len(self.nodes)
        self._dist = np.full((n, n), np.inf)
        for i in range(n):
            for j in range(i + 1, n):
                if self.visible(self.nodes[i], self.nodes[j]):
                    self._dist[i, j] = self._dist[j, i] = float(np.linalg.norm(self.nodes[i] - self.nodes[j]))

    def _free_point(self, q: np.ndarray) -> bool:
        return (all(not point_in_polygon(z.vertices, q) for z in self.blocked)
                and all(point_in_polygon(z.vertices, q) for z in self.allowed))

    def visible(self, a: np.ndarray, b: np.ndarray, clearance_m: float = 0.0) -> bool:
        """Whether the segment a-b crosses no zone's edge, its midpoint is free, and it passes
        at least ``clearance_m`` from every exclusion zone."""
        for z in self.blocked + self.allowed:
            if _crosses(z.vertices, a, b):
                return False
        if clearance_m > 0.0 and any(_segment_to_polygon(z.vertices, a, b) < clearance_m for z in self.blocked):
            return False
        return self._free_point(0.5 * (a + b))

    def path(self, start: np.ndarray, end: np.ndarray) -> list[np.ndarray]:
        """The shortest polyline start ... end (north/east m) through the corners; [start, end] when
        the straight line is free or no way round is found."""
        start, end = np.asarray(start, dtype=float)[:2], np.asarray(end, dtype=float)[:2]
        if self.visible(start, end, self.margin_m) or len(self.nodes) == 0:
            return [start, end]
        n = len(self.nodes)
        d = np.full((n + 2, n + 2), np.inf)
        d[:n, :n] = self._dist
        for k, q in ((n, start), (n + 1, end)):
            for i in range(n):
                if self.visible(q, self.nodes[i]):
                    d[k, i] = d[i, k] = float(np.linalg.norm(q - self.nodes[i]))
        best = np.full(n + 2, np.inf)
        prev = np.full(n + 2, -1)
        best[n] = 0.0
        done = np.zeros(n + 2, dtype=bool)
        for _ in range(n + 2):                                        # Dijkstra, dense
            k = int(np.argmin(np.where(done, np.inf, best)))
            if not np.isfinite(best[k]) or k == n + 1:
                break
            done[k] = True
            alt = best[k] + d[k]
            better = alt < best
            best[better], prev[better] = alt[better], k
        if not np.isfinite(best[n + 1]):
            return [start, end]
        order, k = [], n + 1
        while k != -1:
            order.append(k)
            k = prev[k]
        pts = np.concatenate([self.nodes, start[None], end[None]])
        return [pts[k] for k in reversed(order)]

    def target(self, position: np.ndarray, target: np.ndarray, goal: np.ndarray | None = None) -> np.ndarray:
        """The planner's target on the way round (NED m; the target's altitude kept).

        ``target`` is a point on the way to ``goal`` (default: the target itself), ``|target -
        position|`` ahead. It is kept while the straight line to it is free and passes the
        margin off every exclusion zone; else the way is the shortest path to the goal (the
        target may lie inside a zone, the goal may not), and the new target is the point as far
        along it if that is in sight so, else the path's first corner the drone has not reached
        (within :data:`REACHED_FRACTION` of the margin): a drone at a corner goes on to the next.
        """
        p, t = np.asarray(position, dtype=float), np.asarray(target, dtype=float)
        if self.visible(p[:2], t[:2], self.margin_m):
            return t
        end = t if goal is None else np.asarray(goal, dtype=float)
        path = self.path(p[:2], end[:2])
        if len(path) == 2:
            return t
        left = float(np.linalg.norm(t[:2] - p[:2]))
        ahead = path[-1]
        for a, b in zip(path[:-1], path[1:]):
            seg = float(np.linalg.norm(b - a))
            if seg >= left:
                ahead = a + (b - a) * (left / max(seg, _EPS))
                break
            left -= seg
        if self.visible(p[:2], ahead, self.margin_m):
            q = ahead
        else:   # the path's first corner not yet reached (at a corner, the next: else it holds the drone there)
            q = next((c for c in path[1:] if np.linalg.norm(c - p[:2]) > REACHED_FRACTION * self.margin_m), path[-1])
        return np.array([q[0], q[1], t[2]])


def _pushed(v: np.ndarray, margin_m: float, *, outward: bool) -> np.ndarray:
    """Each vertex moved ``margin_m`` off both its edges (out of the polygon, or into it)."""
    ccw = _signed_area(v) > 0
    prev, nxt = np.roll(v, 1, axis=0), np.roll(v, -1, axis=0)
    e1 = v - prev
    e2 = nxt - v
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 /= np.linalg.norm(e2, axis=1, keepdims=True)
    out1 = np.column_stack([e1[:, 1], -e1[:, 0]])                 # right of the edge: outside when CCW
    out2 = np.column_stack([e2[:, 1], -e2[:, 0]])
    if not ccw:
        out1, out2 = -out1, -out2
    bis = out1 + out2
    norm = np.linalg.norm(bis, axis=1, keepdims=True)
    bis = np.where(norm > _EPS, bis / np.maximum(norm, _EPS), out1)
    cos_half = np.clip(np.einsum("ij,ij->i", bis, out1), 0.2, 1.0)  # sharp corners: at most 5 x the margin
    step = (margin_m / cos_half)[:, None] * bis
    return v + step if outward else v - step


def _octagon(circle: CircleZone, margin_m: float) -> PolygonZone:
    """The regular octagon circumscribed about the circle grown by ``margin_m``."""
    a = 2 * np.pi * (np.arange(8) + 0.5) / 8
    r = (circle.radius_m + margin_m) / np.cos(np.pi / 8)
    return PolygonZone(circle.center + r * np.column_stack([np.cos(a), np.sin(a)]), False)


def _segment_to_polygon(v: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Smallest distance (m) between segment a-b and the edges of polygon ``v`` (0 if they cross)."""
    c, d = v, np.roll(v, -1, axis=0)
    if _crosses(v, a, b):
        return 0.0
    to_edges = min(float(np.min(np.linalg.norm(_closest_on_segments(c, d, q) - q, axis=1))) for q in (a, b))
    ab = np.broadcast_to(a, c.shape), np.broadcast_to(b, c.shape)
    to_segment = float(np.min(np.linalg.norm(_closest_on_segments(ab[0], ab[1], c) - c, axis=1)))
    return min(to_edges, to_segment)


def _crosses(v: np.ndarray, a: np.ndarray, b: np.ndarray) -> bool:
    """Whether segment a-b properly crosses an edge of polygon ``v`` (touching a vertex does not count)."""
    c, d = v, np.roll(v, -1, axis=0)

    def orient(p, q, r):
        return (q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0])

    o1, o2 = orient(a, b, c), orient(a, b, d)
    o3, o4 = orient(c, d, a), orient(c, d, b)
    tol = 1e-9
    return bool(np.any((o1 * o2 < -tol) & (o3 * o4 < -tol)))


def _signed_area(v: np.ndarray) -> float:
    x, y = v[:, 0], v[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _closest_on_segments(a: np.ndarray, b: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The point of each segment [a_i, b_i] (E, 2) nearest p (2,)."""
    ab = b - a
    t = np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), _EPS)
    return a + np.clip(t, 0.0, 1.0)[:, None] * ab


def polygon_walls(zone: PolygonZone, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One wall per edge of ``zone`` about ``p`` (north/east): normals (V, 2), offsets (V,) (module docstring)."""
    v = zone.vertices
    a, b = v, np.roll(v, -1, axis=0)
    edge = b - a
    # the normal of each edge's line pointing out of the region the drone may be in
    outward = np.column_stack([edge[:, 1], -edge[:, 0]])            # right of the edge: outside for a CCW polygon
    if _signed_area(v) < 0:
        outward = -outward
    if not zone.inclusion:
        outward = -outward                                         # an exclusion zone's allowed side is its outside
    outward /= np.linalg.norm(outward, axis=1, keepdims=True)
    offsets = np.einsum("ij,ij->i", outward, a)
    # an inclusion zone's edge line holds the whole (convex) zone: kept while the drone is inside it;
    # an exclusion zone's edge line would reach beyond its corners: always the nearest point's line
    allowed = (outward @ p < offsets - _EPS) if zone.inclusion else np.zeros(len(offsets), dtype=bool)
    # behind the line: the line through the nearest point of the edge, square to the way there
    near = _closest_on_segments(a, b, p)
    to_edge = near - p
    dist = np.linalg.norm(to_edge, axis=1)
    use_sep = ~allowed & (dist > _EPS)
    sep = to_edge[use_sep] / dist[use_sep, None]
    normals = outward.copy()
    normals[use_sep] = sep
    offsets = offsets.copy()
    offsets[use_sep] = np.einsum("ij,ij->i", sep, near[use_sep])
    return normals, offsets


def exclusion_circle_wall(circle: CircleZone, p: np.ndarray) -> tuple[np.ndarray, float]:
    """The wall tangent to an exclusion circle at its point nearest ``p``: normal (2,), offset."""
    d = circle.center - p
    r = float(np.linalg.norm(d))
    n = d / r if r > _EPS else np.array([1.0, 0.0])
    return n, float(n @ circle.center - circle.radius_m)


def point_in_polygon(v: np.ndarray, q: np.ndarray) -> bool:
    """Whether ``q`` (2,) is inside the polygon ``v`` (V, 2) (even-odd rule)."""
    x, y = q
    inside = False
    for (x1, y1), (x2, y2) in zip(v, np.roll(v, -1, axis=0)):
        if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
            inside = not inside
    return inside


def distance_to_boundary(v: np.ndarray, q: np.ndarray) -> float:
    """Distance (m) from ``q`` (2,) to the polygon's boundary."""
    near = _closest_on_segments(v, np.roll(v, -1, axis=0), q)
    return float(np.min(np.linalg.norm(near - q, axis=1)))
