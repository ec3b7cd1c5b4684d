"""PX4's geofence as mavsim's PX4 personality keeps it: the fence about home and the stored zones.

Measured on PX4 SITL (SIH, docs/PX4_FACTS.md, "Geofence"; ``python -m tests.px4.geofence_facts``):
with ``GF_MAX_VER_DIST`` 10 m a climb at 1 m/s in OFFBOARD was taken to Hold at 10.62 and
10.75 m above home; with ``GF_MAX_HOR_DIST`` 15 m a flight north at 2 m/s at 15.95 and 16.29 m
from home: 0.5 to 0.75 s after the crossing. Its texts were "Geofence: exceeding maximum
altitude above Home" (or "... distance to Home"), then "Failsafe activated"; a polygon zone
left in AUTO.MISSION gave "Geofence: approaching or outside geofence" (docs/MISSIONS.md). Left
in Hold outside the fence, PX4 said both again 9.1 and 10.1 s later and returned (AUTO.RTL).

What mavsim does, on the vehicle's position in local NED about home (mavsim's local origin):

- **Breached** when farther than ``GF_MAX_HOR_DIST`` from home horizontally or higher than
  ``GF_MAX_VER_DIST`` above it (each when > 0), outside every inclusion zone when there is
  one, or inside an exclusion zone (the stored fence items: polygons by their vertices,
  circles by their radius; a zone covers every altitude).
- Once breached for :data:`DELAY_S`, the action of ``GF_ACTION``: 0 none; 1 the text only;
  2 Hold (AUTO.LOITER), 3 Return (AUTO.RTL), 5 Land (AUTO.LAND), each with "Failsafe
  activated"; 4 (flight termination, not measured) is taken as 5.
- Still breached :data:`RETURN_AFTER_S` after a Hold it took: the texts again and Return.
- Back inside, the watch starts afresh.

Pure: simulated time and positions in, texts and a mode out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

#: s the vehicle is outside before PX4's action (measured 0.5 to 0.75 s)
DELAY_S = 0.6
#: s in a Hold taken for the fence, still outside, before PX4 returns (measured 9.1 and 10.1 s)
RETURN_AFTER_S = 9.5
FENCE_POLYGON_INCLUSION, FENCE_POLYGON_EXCLUSION = 5001, 5002
FENCE_CIRCLE_INCLUSION, FENCE_CIRCLE_EXCLUSION = 5003, 5004
_ACTION_MODES = {2: "AUTO.LOITER", 3: "AUTO.RTL", 4: "AUTO.LAND", 5: "AUTO.LAND"}
TEXT_DISTANCE = "Geofence: exceeding maximum distance to Home"
TEXT_ALTITUDE = "Geofence: exceeding maximum altitude above Home"
TEXT_ZONE = "Geofence: approaching or outside geofence"
TEXT_FAILSAFE = "Failsafe activated"


@dataclass(frozen=True)
class GeofenceAction:
    """What PX4 does at a breach: its texts, and the mode it enters (None: none)."""

    texts: tuple[str, ...]
    mode: str | None


@dataclass
class FenceZones:
    """Stored fence zones, north/east m about home: ``polygons`` ((V, 2) vertices, inclusion),
    ``circles`` ((2,) centre, radius m, inclusion)."""

    polygons: list[tuple[np.ndarray, bool]] = field(default_factory=list)
    circles: list[tuple[np.ndarray, float, bool]] = field(default_factory=list)

    @classmethod
    def from_items(cls, items) -> FenceZones:
        """Fence items (:class:`mavsim.missions.MissionItem`, local NED) as zones: a polygon is
        ``param1`` consecutive vertex items of one kind; anything else is passed over."""
        zones, i = cls(), 0
        while i < len(items):
            it = items[i]
            if it.command in (FENCE_POLYGON_INCLUSION, FENCE_POLYGON_EXCLUSION):
                n = max(1, int(it.params[0]))
                group = [g for g in items[i:i + n] if g.command == it.command]
                if n >= 3 and len(group) == n:
                    zones.polygons.append((np.array([g.position_ned_m[:2] for g in group]),
                                           it.command == FENCE_POLYGON_INCLUSION))
                i += n
            else:
                if it.command in (FENCE_CIRCLE_INCLUSION, FENCE_CIRCLE_EXCLUSION) and it.params[0] > 0:
                    zones.circles.append((np.array(it.position_ned_m[:2]), float(it.params[0]),
                                          it.command == FENCE_CIRCLE_INCLUSION))
                i += 1
        return zones

    def outside(self, ne: np.ndarray) -> bool:
        """Outside every inclusion zone (when there is one) or inside an exclusion zone."""
        inside = [(_in_polygon(v, ne), inc) for v, inc in self.polygons]
        inside += [(float(np.hypot(*(ne - c))) <= r, inc) for c, r, inc in self.circles]
        inclusions = [hit for hit, inc in inside if inc]
        return (bool(inclusions) and not any(inclusions)) or any(hit for hit, inc in inside if not inc)


def _in_polygon(vertices: np.ndarray, p: np.ndarray) -> bool:
    """Even-odd rule: whether ``p`` (2,) lies inside the polygon ``vertices`` (V, 2)."""
    x, y = float(p[0]), float(p[1])
    inside = False
    for (x0, y0), (x1, y1) in zip(vertices, np.roll(vertices, -1, axis=0)):
        if (y0 > y) != (y1 > y) and x < x0 + (y - y0) * (x1 - x0) / (y1 - y0):
            inside = not inside
    return inside


class GeofenceWatch:
    """PX4's geofence check on the vehicle's position (see the module docstring).

    Parameters
    ----------
    params : the autopilot's parameter store (GF_ACTION, GF_MAX_HOR_DIST, GF_MAX_VER_DIST),
        read at every step (a PARAM_SET applies at once).
    """

    def __init__(self, params) -> None:
        self.params = params
        self.zones = FenceZones()
        self._outside_since: float | None = None
        self._acted: tuple[float, str | None] | None = None   # (when, the mode it entered)
        self._returned = False

    def load(self, zones: FenceZones) -> None:
        """The stored fence zones, after an upload or a clear."""
        self.zones = zones

    def breach(self, position_ned_m: np.ndarray) -> str | None:
        """PX4's text for the fence ``position_ned_m`` (m about home) breaks, or None inside."""
        p = np.asarray(position_ned_m, dtype=float)
        hor, ver = self.params["GF_MAX_HOR_DIST"], self.params["GF_MAX_VER_DIST"]
        if hor > 0.0 and math.hypot(p[0], p[1]) > hor:
            return TEXT_DISTANCE
        if ver > 0.0 and -p[2] > ver:
            return TEXT_ALTITUDE
        if self.zones.outside(p[:2]):
            return TEXT_ZONE
        return None

    def step(self, now_s: float, position_ned_m: np.ndarray, mode: str) -> GeofenceAction | None:
        """The action at simulated time ``now_s`` (s) for the vehicle at ``position_ned_m``, in ``mode``; None: none."""
        text = self.breach(position_ned_m)
        if text is None:
            self._outside_since, self._acted, self._returned = None, None, False
            return None
        if self._outside_since is None:
            self._outside_since = now_s
        if self._acted is None:
            if now_s - self._outside_since < DELAY_S - 1e-9:
                return None
            action = int(self.params["GF_ACTION"])
            target = _ACTION_MODES.get(action)
            self._acted = (now_s, target)
            if action <= 0:
                return None
            return GeofenceAction((text, TEXT_FAILSAFE) if target else (text,), target)
        t_acted, entered = self._acted
        if (entered == "AUTO.LOITER" and mode == "AUTO.LOITER" and not self._returned
                and now_s - t_acted >= RETURN_AFTER_S - 1e-9):
            self._returned = True
            return GeofenceAction((text, TEXT_FAILSAFE), "AUTO.RTL")
        return None
