"""The view's channels: a :class:`~companion.view.snapshot.TickSnapshot` as Foxglove messages.

Every channel, its schema and when it gets a message (``tick``: every tick; ``estimate``:
every tick once the drone has an estimate; ``replan``: every replan recorded; ``setpoint``:
every tick that sent a setpoint):

============================  ==========================  ==========  =========================================
topic                         schema                      when        what
============================  ==========================  ==========  =========================================
``/tf``                       foxglove.FrameTransforms    start, 1 s  ``world`` (ENU, z up) to ``ned`` (the loop's frame)
``/map``                      foxglove.SceneUpdate        start, 1 s  walls (thin plates), static obstacles, the goal
``/vehicle/pose``             foxglove.PoseInFrame        estimate    the drone's estimated position
``/vehicle/ellipsoid``        foxglove.SceneUpdate        estimate    its covariance ellipsoid
``/tracks``                   foxglove.SceneUpdate        tick        each track's ellipsoid and its id (1 s lifetime)
``/plan``                     foxglove.SceneUpdate        replan      the plan's positions (LinePrimitive) and the drone's
                                                                      predicted ellipsoid at each step (the horizon)
``/plan/summary``             companion.Replan (JSON)     replan      status, iterations, solve time, slack, positions
``/contour``                  companion.Contour (JSON)    replan      contour of touch per track: realised and planned
``/setpoint``                 companion.Setpoint (JSON)   setpoint    the velocity (and position) sent
``/loop``                     companion.Tick (JSON)       tick        mode, times, track count
============================  ==========================  ==========  =========================================

Ellipsoids are drawn at :data:`ELLIPSOID_SIGMA` standard deviations per principal axis (the
95 % region of a 3-D Gaussian). Positions are NED metres in frame ``ned``; ``/tf`` places it
in a ``world`` frame with z up, so Foxglove's 3D panel shows up as up.
"""

from __future__ import annotations

import math

import numpy as np

from companion.view.snapshot import Replan, TickSnapshot

#: Standard deviations per principal axis of the drawn ellipsoids: sqrt(chi2_3.ppf(0.95)).
ELLIPSOID_SIGMA = 2.7955
#: Frames: the loop's NED frame, and the z-up world Foxglove shows.
FRAME, WORLD = "ned", "world"
#: Lifetime of a track's entity (s): a track no longer reported vanishes after it.
TRACK_LIFETIME_S = 1.0

SCENE, POSE, TRANSFORMS, JSON = "scene", "pose", "transforms", "json"

#: topic -> (kind, schema name); the JSON channels' schemas are below.
TOPICS: dict[str, tuple[str, str]] = {
    "/tf": (TRANSFORMS, "foxglove.FrameTransforms"),
    "/map": (SCENE, "foxglove.SceneUpdate"),
    "/vehicle/pose": (POSE, "foxglove.PoseInFrame"),
    "/vehicle/ellipsoid": (SCENE, "foxglove.SceneUpdate"),
    "/tracks": (SCENE, "foxglove.SceneUpdate"),
    "/plan": (SCENE, "foxglove.SceneUpdate"),
    "/plan/summary": (JSON, "companion.Replan"),
    "/contour": (JSON, "companion.Contour"),
    "/setpoint": (JSON, "companion.Setpoint"),
    "/loop": (JSON, "companion.Tick"),
}

_NUM = {"type": "number"}
_NUM_OR_NULL = {"type": ["number", "null"]}
_TIME = {"type": "number", "description": "link time, s"}
JSON_SCHEMAS: dict[str, dict] = {
    "companion.Tick": {"type": "object", "properties": {
        "t_s": _TIME, "t_vehicle_s": _NUM_OR_NULL, "mode": {"type": "string"}, "tracks": {"type": "integer"},
        "replans": {"type": "integer"}}},
    "companion.Setpoint": {"type": "object", "properties": {
        "t_s": _TIME, "mode": {"type": "string"}, "vx": _NUM, "vy": _NUM, "vz": _NUM, "speed": _NUM,
        "x": _NUM_OR_NULL, "y": _NUM_OR_NULL, "z": _NUM_OR_NULL}},
    "companion.Replan": {"type": "object", "properties": {
        "t_s": _TIME, "t_vehicle_s": _NUM, "t_applied_s": _NUM, "status": {"type": "string"},
        "iterations": {"type": "integer"}, "solve_time_ms": _NUM, "slack_max": _NUM,
        "planned_min_contour": _NUM_OR_NULL, "command": {"type": "array", "items": _NUM},
        "positions": {"type": "array", "items": {"type": "array", "items": _NUM}},
        "tracks_unconstrained": {"type": "integer"}}},
    "companion.Contour": {"type": "object", "properties": {
        "t_s": _TIME, "min_realised": _NUM_OR_NULL, "min_planned": _NUM_OR_NULL,
        "tracks": {"type": "array", "items": {"type": "object", "properties": {
            "id": {"type": "string"}, "realised": _NUM_OR_NULL, "planned": _NUM_OR_NULL}}}}},
}

# colours (r, g, b, a)
VEHICLE_RGBA = (0.1, 0.5, 1.0, 0.35)
TRACK_RGBA = (1.0, 0.45, 0.1, 0.35)
PLAN_RGBA = {"optimal": (0.1, 0.8, 0.2, 1.0), "slack": (1.0, 0.8, 0.0, 1.0), "failed": (0.9, 0.1, 0.1, 1.0)}
HORIZON_ALPHA = 0.12
WALL_RGBA = (0.6, 0.6, 0.7, 0.25)
GOAL_RGBA = (0.2, 1.0, 0.4, 0.8)
#: Side of the square plate drawn for a wall (m) and its thickness.
WALL_SIDE_M, WALL_THICKNESS_M = 200.0, 0.05


def _num(x) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def ellipsoid(cov: np.ndarray, sigma: float = ELLIPSOID_SIGMA) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
    """Diameters along the principal axes (m) and the rotation to them as a quaternion (x, y, z, w)."""
    cov = 0.5 * (np.asarray(cov, dtype=float) + np.asarray(cov, dtype=float).T)
    values, vectors = np.linalg.eigh(cov)
    if np.linalg.det(vectors) < 0:
        vectors[:, 0] = -vectors[:, 0]
    size = tuple(float(2.0 * sigma * math.sqrt(max(v, 0.0))) for v in values)
    return size, _quaternion(vectors)


def _quaternion(r: np.ndarray) -> tuple[float, float, float, float]:
    """The unit quaternion (x, y, z, w) of rotation matrix ``r``."""
    t = float(np.trace(r))
    if t > 0.0:
        s = math.sqrt(t + 1.0) * 2.0
        return ((r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, 0.25 * s)
    i = int(np.argmax(np.diag(r)))
    j, k = (i + 1) % 3, (i + 2) % 3
    s = math.sqrt(1.0 + r[i, i] - r[j, j] - r[k, k]) * 2.0
    q = [0.0, 0.0, 0.0, 0.0]
    q[i] = 0.25 * s
    q[j] = (r[j, i] + r[i, j]) / s
    q[k] = (r[k, i] + r[i, k]) / s
    q[3] = (r[k, j] - r[j, k]) / s
    return (float(q[0]), float(q[1]), float(q[2]), float(q[3]))


# NED -> ENU: x_enu = y_ned, y_enu = x_ned, z_enu = -z_ned (a rotation of 180 degrees about (1, 1, 0)/sqrt 2)
NED_IN_WORLD = (math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0)


class MessageBuilder:
    """Builds the Foxglove messages of a snapshot (needs the foxglove SDK: the ``view`` extra).

    ``time_offset_s`` is added to link time for the messages' stamps and log times (lockstep
    runs: the tlog's epoch, so the recording has calendar times).
    """

    def __init__(self, time_offset_s: float = 0.0) -> None:
        import foxglove.messages as fm

        self.fm = fm
        self.time_offset_s = float(time_offset_s)
        self._last_tf_s: float | None = None

    def stamp_ns(self, t_s: float) -> int:
        return int(round((t_s + self.time_offset_s) * 1e9))

    def _time(self, t_s: float):
        ns = self.stamp_ns(t_s)
        return self.fm.Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)

    def _pose(self, p, q=(0.0, 0.0, 0.0, 1.0)):
        fm = self.fm
        return fm.Pose(position=fm.Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                       orientation=fm.Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]))

    def _ellipsoid(self, p, cov, rgba):
        fm = self.fm
        size, q = ellipsoid(cov)
        return fm.SpherePrimitive(pose=self._pose(p, q), size=fm.Vector3(x=size[0], y=size[1], z=size[2]),
                                  color=fm.Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]))

    def messages(self, snap: TickSnapshot) -> list[tuple[str, object]]:
        """``(topic, message)`` pairs of one snapshot, in :data:`TOPICS` order."""
        fm = self.fm
        t = snap.t_s
        stamp = self._time(t)
        out: list[tuple[str, object]] = []
        if self._last_tf_s is None or t - self._last_tf_s >= 1.0 or t < self._last_tf_s:
            self._last_tf_s = t
            q = NED_IN_WORLD
            out.append(("/tf", fm.FrameTransforms(transforms=[fm.FrameTransform(
                timestamp=stamp, parent_frame_id=WORLD, child_frame_id=FRAME, translation=fm.Vector3(),
                rotation=fm.Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]))])))
            if snap.scenario is not None:
                out.append(("/map", self._map(snap.scenario, stamp)))
        if snap.drone is not None:
            d = snap.drone
            out.append(("/vehicle/pose", fm.PoseInFrame(timestamp=stamp, frame_id=FRAME, pose=self._pose(d.position))))
            out.append(("/vehicle/ellipsoid", fm.SceneUpdate(entities=[fm.SceneEntity(
                timestamp=stamp, frame_id=FRAME, id="vehicle", spheres=[self._ellipsoid(d.position, d.cov, VEHICLE_RGBA)])])))
        lifetime = fm.Duration(int(TRACK_LIFETIME_S), int(round((TRACK_LIFETIME_S % 1) * 1e9)))
        white = fm.Color(r=1.0, g=1.0, b=1.0, a=1.0)
        out.append(("/tracks", fm.SceneUpdate(entities=[fm.SceneEntity(
            timestamp=stamp, frame_id=FRAME, id=f"track/{tr.key}", lifetime=lifetime,
            metadata=[fm.KeyValuePair(key="track", value=tr.key)],
            spheres=[self._ellipsoid(tr.position, tr.cov, TRACK_RGBA)],
            texts=[fm.TextPrimitive(pose=self._pose(tr.position - np.array([0.0, 0.0, 1.0])), billboard=True,
                                    font_size=14.0, scale_invariant=True, color=white, text=tr.key)])
            for tr in snap.tracks])))
        for replan in snap.replans:
            out += self._replan(replan)
        if snap.setpoint is not None:
            sp = snap.setpoint
            out.append(("/setpoint", {"t_s": t, "mode": snap.mode, **sp,
                                      "speed": math.sqrt(sp["vx"] ** 2 + sp["vy"] ** 2 + sp["vz"] ** 2)}))
        out.append(("/loop", {"t_s": t, "t_vehicle_s": snap.t_vehicle_s, "mode": snap.mode,
                              "tracks": len(snap.tracks), "replans": len(snap.replans)}))
        return out

    def _map(self, scenario, stamp):
        """Walls as thin plates through their point nearest the origin, static obstacles, the goal."""
        fm = self.fm
        cubes, spheres = [], []
        wr = fm.Color(r=WALL_RGBA[0], g=WALL_RGBA[1], b=WALL_RGBA[2], a=WALL_RGBA[3])
        for wall in getattr(scenario, "walls", ()):
            n = np.asarray(wall.normal, dtype=float)
            n = n / np.linalg.norm(n)
            # a rotation taking z to the normal: its columns an orthonormal basis with n last
            a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
            u = np.cross(a, n)
            u /= np.linalg.norm(u)
            r = np.column_stack([u, np.cross(n, u), n])
            cubes.append(fm.CubePrimitive(pose=self._pose(n * float(wall.offset), _quaternion(r)),
                                          size=fm.Vector3(x=WALL_SIDE_M, y=WALL_SIDE_M, z=WALL_THICKNESS_M), color=wr))
        for ob in getattr(scenario, "static_obstacles", ()):
            d = 2.0 * float(ob.radius)
            spheres.append(fm.SpherePrimitive(pose=self._pose(ob.center), size=fm.Vector3(x=d, y=d, z=d),
                                              color=fm.Color(r=TRACK_RGBA[0], g=TRACK_RGBA[1], b=TRACK_RGBA[2], a=0.6)))
        goal = getattr(getattr(scenario, "mission", None), "goal_ned_m", None)
        if goal is not None:
            spheres.append(fm.SpherePrimitive(pose=self._pose(goal), size=fm.Vector3(x=0.6, y=0.6, z=0.6),
                                              color=fm.Color(r=GOAL_RGBA[0], g=GOAL_RGBA[1], b=GOAL_RGBA[2], a=GOAL_RGBA[3])))
        return fm.SceneUpdate(entities=[fm.SceneEntity(timestamp=stamp, frame_id=FRAME, id="map", cubes=cubes,
                                                       spheres=spheres)])

    def _replan(self, replan: Replan) -> list[tuple[str, object]]:
        fm = self.fm
        rec = replan.record
        stamp = self._time(rec.t_applied_s)
        status = str(rec.status.value if hasattr(rec.status, "value") else rec.status)
        rgba = PLAN_RGBA.get(status, PLAN_RGBA["failed"])
        positions = np.asarray(rec.plan_positions, dtype=float).reshape(-1, 3)
        points = [fm.Point3(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in positions]
        line = fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineStrip, pose=self._pose((0.0, 0.0, 0.0)),
                                thickness=3.0, scale_invariant=True, points=points,
                                color=fm.Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]))
        spheres = []
        if replan.horizon_covs is not None:
            faint = (*rgba[:3], HORIZON_ALPHA)
            spheres = [self._ellipsoid(p, c, faint) for p, c in zip(positions, replan.horizon_covs)]
        scene = fm.SceneUpdate(entities=[fm.SceneEntity(
            timestamp=stamp, frame_id=FRAME, id="plan", lines=[line], spheres=spheres,
            metadata=[fm.KeyValuePair(key="status", value=status)])])
        summary = {
            "t_s": rec.t_link_s, "t_vehicle_s": rec.t_vehicle_s, "t_applied_s": rec.t_applied_s, "status": status,
            "iterations": int(rec.iterations), "solve_time_ms": float(rec.solve_time_s) * 1e3,
            "slack_max": _num(rec.slack_max), "planned_min_contour": _num(rec.planned_min_contour),
            "command": [float(v) for v in rec.command], "positions": positions.tolist(),
            "tracks_unconstrained": int(rec.tracks_unconstrained),
        }
        keys = sorted(set(rec.realised_contour) | set(rec.planned_contour), key=str)
        from companion.view.snapshot import _track_name

        tracks = [{"id": _track_name(k), "realised": _num(rec.realised_contour[k]) if k in rec.realised_contour else None,
                   "planned": _num(rec.planned_contour[k]) if k in rec.planned_contour else None} for k in keys]
        realised = [c["realised"] for c in tracks if c["realised"] is not None]
        planned = [c["planned"] for c in tracks if c["planned"] is not None]
        contour = {"t_s": rec.t_link_s, "min_realised": min(realised) if realised else None,
                   "min_planned": min(planned) if planned else None, "tracks": tracks}
        return [("/plan", scene), ("/plan/summary", summary), ("/contour", contour)]
