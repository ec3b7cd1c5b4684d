"""The geofence the companion flies inside: read from a plan, placed through the vehicle's origin.

A QGroundControl ``.plan`` holds the fence as latitude/longitude polygons and circles
(:class:`~companion.loop.mission_file.FencePolygon`, :class:`~companion.loop.mission_file.FenceCircle`).
:class:`FenceSource` places them once in the autopilot's local frame, with the map PX4 itself
uses (:func:`companion.core.geo.project` about GPS_GLOBAL_ORIGIN), and from then on gives
the planner its walls about each plan's start (:meth:`companion.core.fence.Fence.walls`).

``--fence vehicle`` (:meth:`FenceSource.from_vehicle`) downloads the fence stored on the
autopilot first (the mission protocol with mission type FENCE, as a ground station reads it;
:func:`zones_from_items`), then reads the parameters of its failsafe fence about home where
the autopilot has them (PX4's GF_MAX_HOR_DIST and GF_MAX_VER_DIST,
:attr:`~companion.mavlink.autopilots.base.Autopilot.fence_params`), and places it all the
same way: the largest distance from home as an inclusion circle about HOME_POSITION's local
position, the largest height above home as a ceiling. A vehicle holding no fence (no zone and
no limit), or a download or parameter read that fails, ends the run with one error before
anything is flown.

Until the origin is known the offboard sequence is held at its start, as for a goal that
must be placed (:class:`companion.loop.goal_stage.GoalStage`): nothing is armed or flown
without the fence. After ``[mission] goal_wait_s`` without an origin the run gives up with
one error naming GPS_GLOBAL_ORIGIN. A fence whose zones leave no room for the drone where
it is (start outside an inclusion zone or inside an exclusion zone) is flown anyway: the
planner's slack then pushes it back in, and the report's ``min_fence_clearance_m`` says so.
"""

from __future__ import annotations

import logging

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.core import geo
from companion.core.fence import CircleZone, Fence, PolygonZone
from companion.errors import ConfigError
from companion.loop.goal import Preparation
from companion.loop.mission_file import FenceCircle, FencePolygon, MissionPlan
from companion.mavlink.autopilots.base import FenceLimits
from companion.mavlink.mission_protocol import DOWNLOAD_REPLIES, FENCE, MissionDownload, MissionItem
from companion.mavlink.param_read import ParamRead
from companion.loop.vehicle_reference import VehicleReference

logger = logging.getLogger(__name__)


class FenceSource:
    """A plan's fence, placed in the local frame once the vehicle's origin is known.

    Parameters
    ----------
    plan : MissionPlan
        Its ``fence_polygons`` and ``fence_circles`` (latitude/longitude degrees, radii m).
    reference : VehicleReference
        The vehicle's origin (shared with the goal and the obstacle intake).
    wait_s : float
        Seconds to wait for the origin from the first tick the autopilot is known.
    source : str
        Where the fence came from (a file name), for messages.
    """

    #: the mission-protocol messages a fence download takes (MISSION_ITEM for old autopilots' answers)
    MISSION_MESSAGES = DOWNLOAD_REPLIES

    def __init__(self, plan: MissionPlan | None, reference: VehicleReference, wait_s: float, source: str = "fence") -> None:
        if plan is not None and not plan.polygons and not plan.circles:
            raise ConfigError(f"{source}: no geofence in it (geoFence polygons or circles)")
        #: the fence as read (None while it is still to be downloaded from the vehicle)
        self.plan = plan
        #: the download of the vehicle's fence (``from_vehicle``), while it runs and after
        self.transfer: MissionDownload | None = None
        self.reference = reference
        self.wait_s = float(wait_s)
        self.source = source
        #: the fence in the local frame (None until placed)
        self.fence: Fence | None = None
        self.failed: str | None = None
        #: the read of the autopilot's fence parameters (``from_vehicle``), while it runs and after
        self.param_read: ParamRead | None = None
        #: the autopilot's fence about home (``from_vehicle``; none from a file)
        self.limits = FenceLimits()
        self._limits_due = plan is None               # the vehicle's fence: its limits are read after its zones
        self._wait_from: float | None = None
        self._router = None

    @classmethod
    def from_vehicle(cls, reference: VehicleReference, wait_s: float) -> FenceSource:
        """The fence stored on the autopilot, downloaded before it is placed."""
        return cls(None, reference, wait_s, "the vehicle's fence")

    @property
    def n_zones(self) -> int:
        zones = 0 if self.plan is None else len(self.plan.polygons) + len(self.plan.circles)
        return zones + (self.limits.max_horizontal_m is not None)

    @property
    def downloading(self) -> bool:
        return self.transfer is not None and not self.transfer.over

    @property
    def reading_params(self) -> bool:
        return self.param_read is not None and not self.param_read.over

    def takes(self, msg_type: str) -> bool:
        """Whether a message of this type is the fence's now (its download's, its parameter read's)."""
        return (self.downloading and msg_type in self.MISSION_MESSAGES) or (self.reading_params and msg_type == "PARAM_VALUE")

    def on_message(self, t_s: float, msg) -> list:
        """The autopilot's MISSION_* messages while the download runs, PARAM_VALUE while the
        parameters are read; the answers to send at once."""
        if self.downloading:
            return self.transfer.on_message(t_s, msg)
        if self.reading_params:
            self.param_read.on_message(t_s, msg)
        return []

    def prepare(self, t_s: float, autopilot: tuple[int, int] | None, kind=None) -> Preparation:
        """Download the fence and read its limits if it is the vehicle's (``kind``: the autopilot's
        :class:`~companion.mavlink.autopilots.base.Autopilot`, once heard); place it once the origin
        (and, for limits about home, home) is known; ask for them and wait (bounded) until then."""
        if self.fence is not None:
            return Preparation(True)
        if self.failed is not None:
            return Preparation(False)
        if self.plan is None:
            return self._download(t_s, autopilot)
        if self._limits_due:
            return self._read_limits(t_s, autopilot, kind)
        origin = self.reference.origin_point
        home = self.reference.home
        if origin is not None and (home is not None or not self.limits.any):
            try:
                self.fence = place_fence(self.plan, origin.lat_deg, origin.lon_deg, self.limits,
                                         None if home is None else home.local_ned_m)
            except ValueError as exc:
                return self._fail(f"{self.source}: {exc}", "companion: fence not usable, not flown")
            text = f"companion: fence of {self.n_zones} zone{'' if self.n_zones == 1 else 's'} placed" + (
                f", ceiling {self.limits.max_up_m:g} m above home" if self.limits.max_up_m is not None else "")
            logger.info("%s (%d walls)", text, self.fence.n_walls)
            return Preparation(True, [(mavlink2.MAV_SEVERITY_INFO, text)])
        if autopilot is None:
            return Preparation(False)
        waits_for = "GPS_GLOBAL_ORIGIN" if origin is None else "HOME_POSITION"
        (self.reference.origin_request if origin is None else self.reference.home_request).wanted = True
        if self._wait_from is None:
            self._wait_from = t_s
            return Preparation(False, [(mavlink2.MAV_SEVERITY_NOTICE, f"companion: fence waits for {waits_for}")])
        if t_s - self._wait_from >= self.wait_s - 1e-9:
            self.reference.origin_request.wanted = self.reference.home_request.wanted = False
            return self._fail(f"{self.source}: fence not placed: no {waits_for} from the autopilot after "
                              f"{self.wait_s:g} s (does it have a position fix?)", "companion: fence not placed, no "
                              + ("origin" if origin is None else "home"))
        return Preparation(False)

    def _read_limits(self, t_s: float, autopilot: tuple[int, int] | None, kind) -> Preparation:
        """The autopilot's fence about home, from its parameters (none for an autopilot that names none)."""
        if autopilot is None or kind is None:
            return Preparation(False)
        names = tuple(kind.fence_params)
        if not names:                                  # an autopilot whose fence parameters are not read
            self._limits_due = False
            return self._no_zones_check()
        if self.param_read is None:
            self.param_read = ParamRead(autopilot, names)
            return Preparation(False, send=self.param_read.start(t_s))
        send = self.param_read.step(t_s)
        if self.param_read.failed is not None:
            return self._fail(f"the vehicle's fence: {', '.join(names)} not read: {self.param_read.failed}",
                              "companion: fence parameters not read")
        if not self.param_read.done:
            return Preparation(False, send=send)
        self.limits = kind.fence_limits(self.param_read.values)
        self._limits_due = False
        logger.info("the vehicle's fence about home: %s", self.limits)
        return self._no_zones_check()

    def _no_zones_check(self) -> Preparation:
        assert self.plan is not None
        if not self.plan.polygons and not self.plan.circles and not self.limits.any:
            return self._fail("the vehicle holds no fence (--fence vehicle): upload one from the ground station",
                              "companion: the vehicle holds no fence")
        return Preparation(False)                      # placed from the next tick

    def _download(self, t_s: float, autopilot: tuple[int, int] | None) -> Preparation:
        if autopilot is None:
            return Preparation(False)
        if self.transfer is None:
            self.transfer = MissionDownload(autopilot, FENCE)
            return Preparation(False, [(mavlink2.MAV_SEVERITY_INFO, "companion: downloading the vehicle's fence")],
                               send=self.transfer.start(t_s))
        send = self.transfer.step(t_s)
        if self.transfer.failed is not None:
            return self._fail(f"the vehicle's fence: {self.transfer.failed}", "companion: fence download failed")
        if not self.transfer.done:
            return Preparation(False, send=send)
        try:
            polygons, circles = zones_from_items(self.transfer.items)
        except ValueError as exc:
            return self._fail(f"the vehicle's fence: {exc}", "companion: vehicle's fence not usable")
        self.plan = MissionPlan(self.source, (), polygons=polygons, circles=circles)
        return Preparation(False, send=send)          # its limits are read from the next tick

    def walls(self, position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The fence's walls about ``position`` (NED m); none before it is placed."""
        if self.fence is None:
            return np.zeros((0, 3)), np.zeros(0)
        return self.fence.walls(position)

    def route_target(self, position: np.ndarray, target: np.ndarray, margin_m: float,
                     goal: np.ndarray | None = None) -> np.ndarray:
        """``target`` (on the way to ``goal``) moved onto the shortest way round the fence's zones
        (:meth:`companion.core.fence.FenceRouter.target`, built once); unchanged before placement."""
        if self.fence is None:
            return target
        if self._router is None:
            self._router = self.fence.router(margin_m)
        return self._router.target(position, target, goal)

    def _fail(self, reason: str, short: str) -> Preparation:
        self.failed = reason
        logger.error("%s", reason)
        return Preparation(False, [(mavlink2.MAV_SEVERITY_WARNING, short)], failed=reason)


def zones_from_items(items: list[MissionItem]) -> tuple[tuple[FencePolygon, ...], tuple[FenceCircle, ...]]:
    """Fence items (mission type FENCE) as polygons and circles: a polygon is ``param1``
    consecutive MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION (or _EXCLUSION) items; a circle one
    MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION (or _EXCLUSION) item with its radius in ``param1``;
    return points are skipped. Raises ValueError on a polygon cut short or an unknown item."""
    polygons, circles = [], []
    i = 0
    while i < len(items):
        item = items[i]
        if item.command in (mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
                            mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION):
            n = int(item.params[0])
            group = items[i:i + n]
            if n < 3 or len(group) < n or any(g.command != item.command for g in group):
                raise ValueError(f"fence item {item.seq}: a polygon of {n} vertices cut short or mixed")
            polygons.append(FencePolygon(item.command == mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
                                         tuple((g.x, g.y) for g in group)))
            i += n
        elif item.command in (mavlink2.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, mavlink2.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION):
            circles.append(FenceCircle(item.command == mavlink2.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, (item.x, item.y),
                                       float(item.params[0])))
            i += 1
        elif item.command == mavlink2.MAV_CMD_NAV_FENCE_RETURN_POINT:
            i += 1
        else:
            raise ValueError(f"fence item {item.seq}: MAV_CMD {item.command} is not a fence item")
    return tuple(polygons), tuple(circles)


def place_fence(plan: MissionPlan, lat0_deg: float, lon0_deg: float, limits: FenceLimits = FenceLimits(),
                home_ned_m: tuple[float, float, float] | None = None) -> Fence:
    """A plan's geodetic fence in the local frame about the origin (lat0, lon0), with the autopilot's
    ``limits`` about home (its local NED position ``home_ned_m``, m): an inclusion circle and a
    ceiling. Raises ValueError on a degenerate zone."""
    polygons = tuple(PolygonZone(np.array([geo.project(lat, lon, lat0_deg, lon0_deg) for lat, lon in p.vertices]),
                                 p.inclusion) for p in plan.polygons)
    circles = tuple(CircleZone(np.array(geo.project(*c.center, lat0_deg, lon0_deg)), c.radius_m, c.inclusion)
                    for c in plan.circles)
    ceiling = None
    if limits.any:
        if home_ned_m is None:
            raise ValueError("the fence's limits about home need HOME_POSITION")
        if limits.max_horizontal_m is not None:
            circles += (CircleZone(np.array(home_ned_m[:2], dtype=float), limits.max_horizontal_m, True),)
        if limits.max_up_m is not None:
            ceiling = -float(home_ned_m[2]) + limits.max_up_m
    return Fence(polygons=polygons, circles=circles, ceiling_up_m=ceiling)


def scenario_fence(mission, reference: VehicleReference, plan: MissionPlan | None = None) -> FenceSource | None:
    """The fence a scenario's ``[mission]`` names: ``fence_file``'s (``"vehicle"``: the autopilot's), else its
    ``plan_file``'s own (``plan``: that file as already read), else None."""
    from companion.loop.mission_file import read_mission_file

    if mission.fence_file == "vehicle":
        return FenceSource.from_vehicle(reference, mission.goal_wait_s)
    if mission.fence_file is not None:
        return FenceSource(read_mission_file(mission.fence_file, fence_only=True), reference, mission.goal_wait_s, mission.fence_file)
    if mission.plan_file is not None:
        plan = plan if plan is not None else read_mission_file(mission.plan_file)
        if plan.polygons or plan.circles:
            return FenceSource(plan, reference, mission.goal_wait_s, mission.plan_file)
    return None
