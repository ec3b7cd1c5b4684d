"""Goals in the frames people use (local NED, relative to home, geodetic) placed in the local frame.

A :class:`GoalSpec` is one point as given: ``ned`` (north, east, down metres in the
autopilot's local frame, as ``[mission] goal_ned_m``), ``home`` (north, east, up metres
from the vehicle's home, HOME_POSITION) or ``geo`` (latitude, longitude in degrees and an
altitude in metres, AMSL or relative to home's altitude). :func:`place` turns it into
local NED once the references it needs are known: the local origin (GPS_GLOBAL_ORIGIN)
for latitude and longitude, with PX4's own map (:mod:`companion.core.geo`), and home for
``home`` goals and relative altitudes; without them it answers None (the caller waits,
and says so), never a guess. :func:`parse_goal` reads the command line's ``FRAME:A,B,C``.

Pure: no clock, no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.core import geo
from companion.errors import ConfigError

FRAMES = ("ned", "home", "geo")
ALTITUDES = ("amsl", "rel")
#: The command line's syntax, for help texts and errors.
GOAL_SYNTAX = "ned:N,E,D | home:N,E,U | geo:LAT,LON,ALTamsl | geo:LAT,LON,ALTrel"
#: Largest distance of a goal from the local origin (m): beyond it, PX4's own map (and a
#: battery) give out long before; a larger value is a typing error (degrees for metres).
MAX_GOAL_DISTANCE_M = 100_000.0


@dataclass(frozen=True)
class GeoPoint:
    """A geodetic point: latitude and longitude (degrees, WGS-84) and altitude (metres AMSL)."""

    lat_deg: float
    lon_deg: float
    alt_m: float


@dataclass(frozen=True)
class Home:
    """The vehicle's home: where it is on the earth and in the local frame (NED, m)."""

    point: GeoPoint
    local_ned_m: tuple[float, float, float]


@dataclass(frozen=True)
class GoalSpec:
    """One goal as given (see the module docstring); ``altitude`` says what a ``geo`` altitude is."""

    frame: str
    values: tuple[float, float, float]
    altitude: str = "amsl"

    def __post_init__(self) -> None:
        if self.frame not in FRAMES:
            raise ConfigError(f"goal frame {self.frame!r}: must be one of {', '.join(FRAMES)}")
        if self.altitude not in ALTITUDES:
            raise ConfigError(f"goal altitude {self.altitude!r}: must be amsl or rel")
        vals = tuple(float(v) for v in self.values)
        if len(vals) != 3 or not all(math.isfinite(v) for v in vals):
            raise ConfigError(f"goal {self.values!r}: three finite numbers")
        if self.frame == "geo":
            lat, lon, alt = vals
            if not -90.0 <= lat <= 90.0 or not -180.0 <= lon <= 180.0:
                raise ConfigError(f"goal latitude {lat:g}, longitude {lon:g}: out of range (degrees)")
            if not -500.0 <= alt <= 20_000.0:
                raise ConfigError(f"goal altitude {alt:g} m: out of range")
        elif max(abs(v) for v in vals) > MAX_GOAL_DISTANCE_M:
            raise ConfigError(f"goal {list(vals)!r}: more than {MAX_GOAL_DISTANCE_M:g} m away")
        object.__setattr__(self, "values", vals)

    @property
    def needs_origin(self) -> bool:
        """Whether placing it needs the local origin (GPS_GLOBAL_ORIGIN)."""
        return self.frame == "geo"

    @property
    def needs_home(self) -> bool:
        """Whether placing it needs home (HOME_POSITION)."""
        return self.frame == "home" or (self.frame == "geo" and self.altitude == "rel")

    def describe(self) -> str:
        """The goal as the command line writes it."""
        a, b, c = self.values
        if self.frame == "geo":
            return f"geo:{a:.7f},{b:.7f},{c:g}{self.altitude}"
        return f"{self.frame}:{a:g},{b:g},{c:g}"


def parse_goal(text: str) -> GoalSpec:
    """A goal from ``FRAME:A,B,C`` (:data:`GOAL_SYNTAX`); ConfigError says what is wrong."""
    frame, sep, rest = str(text).strip().partition(":")
    frame = frame.lower()
    if not sep or frame not in FRAMES:
        raise ConfigError(f"goal {text!r}: expected {GOAL_SYNTAX}")
    parts = [p.strip() for p in rest.split(",")]
    if len(parts) != 3:
        raise ConfigError(f"goal {text!r}: three comma-separated numbers after {frame}: ({GOAL_SYNTAX})")
    altitude = "amsl"
    if frame == "geo":
        last = parts[2].lower()
        for suffix in ALTITUDES:
            if last.endswith(suffix):
                altitude, parts[2] = suffix, last[: -len(suffix)].strip()
                break
        else:
            raise ConfigError(f"goal {text!r}: say what the altitude is: {parts[2]}amsl or {parts[2]}rel")
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        raise ConfigError(f"goal {text!r}: not numbers ({GOAL_SYNTAX})") from None
    return GoalSpec(frame, values, altitude)  # type: ignore[arg-type]


def place(spec: GoalSpec, origin: GeoPoint | None, home: Home | None) -> np.ndarray | None:
    """The goal in the local frame (NED, m), or None while a reference it needs is unknown."""
    a, b, c = spec.values
    if spec.frame == "ned":
        return np.array([a, b, c], dtype=float)
    if spec.needs_home and home is None:
        return None
    if spec.frame == "home":
        assert home is not None
        hn, he, hd = home.local_ned_m
        return np.array([hn + a, he + b, hd - c], dtype=float)
    if origin is None:
        return None
    north, east = geo.project(a, b, origin.lat_deg, origin.lon_deg)
    alt_amsl = c if spec.altitude == "amsl" else home.point.alt_m + c  # type: ignore[union-attr]
    return np.array([north, east, origin.alt_m - alt_amsl], dtype=float)


def to_geodetic(ned: np.ndarray, origin: GeoPoint) -> GeoPoint:
    """A local NED point on the earth about ``origin`` (PX4's map inverted; altitude AMSL)."""
    lat, lon = geo.reproject(float(ned[0]), float(ned[1]), origin.lat_deg, origin.lon_deg)
    return GeoPoint(lat, lon, origin.alt_m - float(ned[2]))
