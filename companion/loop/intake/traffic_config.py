"""``[traffic]``: where obstacles come from, which messages are trusted, and how accurate they are.

Example (every key optional)::

    [traffic]
    obstacle_links = ["udpin:0.0.0.0:14601"]    # receive-only links; `fly --obstacles URL` adds more
    autopilot_link_kinds = ["ADSB_VEHICLE"]     # traffic taken from the autopilot link
    obstacle_link_kinds = ["ODOMETRY", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT",
                           "ADSB_VEHICLE", "UTM_GLOBAL_POSITION", "OPEN_DRONE_ID_LOCATION"]
    position_std_m = 1.0          # accuracy where a message carries none (1 sigma, horizontal)
    vertical_std_m = 1.0
    velocity_std_mps = 1.0
    clock_window_s = 10.0         # see companion.loop.intake.source_clocks
    clock_jump_s = 1.0
    statustext_period_s = 5.0     # at most one rejection STATUSTEXT per period
    geoid_separation_m = 47.0     # geoid above the WGS-84 ellipsoid here (m); only used until the
                                  # autopilot's GPS_RAW_INT (alt_ellipsoid - alt) is heard
    range_m = 30.0                # how far out reported obstacles are planned around (m); default
                                  # [planner] sensing_range_m

    [[traffic.source]]            # per-source overrides, the first match wins
    link = "obstacles"            # "autopilot", "obstacles" (any obstacle link), a link name ("obstacles1")
                                  # or "fleet" (the other drones' announcements)
    system = 101                  # optional: only this MAVLink system id
    icao = 0xABCDEF               # optional: only this ADS-B ICAO address
    kinds = ["ODOMETRY"]
    position_std_m = 0.2
    radius_m = 0.5                # body radius of obstacles from this source (default [companion] obstacle_radius_m;
                                  # ADSB emitter types give their own unless a source sets it)
    range_m = 10.0                # this source's obstacles are planned around within 10 m of the drone

Range. The planner constrains an obstacle only while its predicted mean now lies within a
range of the drone (``[planner] sensing_range_m``, the paper's sensing range ``S_r``, 10 m).
That models what the drone sees itself; a transponder's or a fleet peer's report comes by
radio from much further, and a drone closing with it at 5 m/s has 2 s inside 10 m, which
0.5 m/s^2 turns into 1 m sideways. ``range_m`` sets it for reported obstacles, per source:
about twice the horizon's reach at the speeds met (docs/notes/fleet.md).

Altitude datums. GPS_GLOBAL_ORIGIN, GLOBAL_POSITION_INT and ADSB_VEHICLE carry altitudes
above mean sea level; UTM_GLOBAL_POSITION (``alt``) and OPEN_DRONE_ID_LOCATION
(``altitude_geodetic``) carry heights above the WGS-84 ellipsoid. The two differ by the geoid
separation (-106 to +85 m on Earth), which the companion takes from the autopilot's
GPS_RAW_INT (requested when needed) or, failing that, from ``geoid_separation_m``; with
neither, ellipsoid-height reports are rejected and counted rather than misplaced vertically.

ODOMETRY from other systems on the autopilot link is the old same-socket wiring: allow it
only explicitly (``autopilot_link_kinds = ["ADSB_VEHICLE", "ODOMETRY"]``); it is dangerous
(see docs/OBSTACLES.md) and the companion warns about it either way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

from companion import validation as check
from companion.errors import ConfigError
from companion.mavlink.traffic import TRAFFIC_KINDS

AUTOPILOT_LINK = "autopilot"
OBSTACLE_LINK_PREFIX = "obstacles"
#: The fleet link's name (``companion fly --fleet``): the other drones' announcements, and ours.
FLEET_LINK = "fleet"


def is_fleet_peer(key) -> bool:
    """Whether a track's key is a fleet peer's: ``(system, component, FLEET_LINK)`` with an integer system."""
    return isinstance(key, tuple) and len(key) == 3 and key[2] == FLEET_LINK and isinstance(key[0], int)


def obstacle_link_name(index: int) -> str:
    """Name of the ``index``-th obstacle link (0-based): ``obstacles1``, ``obstacles2``..."""
    return f"{OBSTACLE_LINK_PREFIX}{index + 1}"


@dataclass(frozen=True)
class SourcePolicy:
    """What the companion accepts from one source, and the accuracy it assumes (1 sigma)."""

    kinds: frozenset
    position_std_m: float
    vertical_std_m: float
    velocity_std_mps: float
    radius_m: float | None = None
    range_m: float | None = None


@dataclass(frozen=True)
class SourceRule:
    """A ``[[traffic.source]]`` entry: a match (link, system, icao) and the policy it sets."""

    link: str
    system: int | None
    icao: int | None
    policy: SourcePolicy

    def matches(self, link: str, system: int, icao: int | None) -> bool:
        if self.link not in ("*", link) and not (self.link == OBSTACLE_LINK_PREFIX and link.startswith(OBSTACLE_LINK_PREFIX)):
            return False
        if self.system is not None and self.system != system:
            return False
        return self.icao is None or self.icao == icao


@dataclass(frozen=True)
class TrafficConfig:
    """The ``[traffic]`` section (see the module docstring)."""

    obstacle_links: tuple[str, ...] = ()
    autopilot_link_kinds: frozenset = frozenset({"ADSB_VEHICLE"})
    obstacle_link_kinds: frozenset = frozenset(TRAFFIC_KINDS)
    position_std_m: float = 1.0
    vertical_std_m: float = 1.0
    velocity_std_mps: float = 1.0
    clock_window_s: float = 10.0
    clock_jump_s: float = 1.0
    statustext_period_s: float = 5.0
    geoid_separation_m: float | None = None
    range_m: float | None = None
    sources: tuple[SourceRule, ...] = field(default_factory=tuple)

    def policy(self, link: str, system: int, icao: int | None = None) -> SourcePolicy:
        """The policy of a source: the first matching rule, else the link's defaults."""
        for rule in self.sources:
            if rule.matches(link, system, icao):
                return rule.policy
        kinds = self.autopilot_link_kinds if link == AUTOPILOT_LINK else self.obstacle_link_kinds
        return SourcePolicy(kinds, self.position_std_m, self.vertical_std_m, self.velocity_std_mps, range_m=self.range_m)


_KEYS = frozenset({"obstacle_links", "autopilot_link_kinds", "obstacle_link_kinds", "position_std_m", "vertical_std_m",
                   "velocity_std_mps", "clock_window_s", "clock_jump_s", "statustext_period_s", "geoid_separation_m",
                   "range_m", "source"})
_SOURCE_KEYS = frozenset({"link", "system", "icao", "kinds", "position_std_m", "vertical_std_m", "velocity_std_mps",
                          "radius_m", "range_m"})
#: Bounds on what a scenario file may ask for (every list read from the file is bounded).
MAX_OBSTACLE_LINKS = 16
MAX_SOURCES = 64
_MAX_STD = 1e4          # m, m/s: a 1-sigma accuracy worse than 10 km is a typo
_MAX_PERIOD_S = 3600.0
_MAX_RANGE_M = 1e5      # m: beyond 100 km is a typo (inf is allowed: every report planned around)


def _std(key: str, value: Any) -> float:
    return check.number(key, value, positive=True, hi=_MAX_STD)


def _kinds(key: str, value: Any) -> frozenset:
    if not isinstance(value, list) or len(value) > len(TRAFFIC_KINDS) or not all(isinstance(k, str) for k in value):
        raise ConfigError(f"{key} = {value!r} must be a list of message names")
    unknown = sorted(set(value) - set(TRAFFIC_KINDS))
    if unknown:
        raise ConfigError(f"{key} = {value!r}: unknown kind(s) {', '.join(unknown)} (known: {', '.join(TRAFFIC_KINDS)})")
    return frozenset(value)


def _range(key: str, value: Any) -> float:
    v = check.number(key, value, positive=True, allow_inf=True)
    if math.isfinite(v) and v > _MAX_RANGE_M:
        raise ConfigError(f"{key} = {value!r} must be <= {_MAX_RANGE_M:g} m (or inf)")
    return v


def _links(key: str, value: Any) -> tuple[str, ...]:
    if not isinstance(value, list) or len(value) > MAX_OBSTACLE_LINKS:
        raise ConfigError(f"{key} = {value!r} must be a list of at most {MAX_OBSTACLE_LINKS} pymavlink connection strings")
    out = tuple(check.text(key, url, max_len=200) for url in value)
    if not all(out):
        raise ConfigError(f"{key} = {value!r}: a connection string is empty")
    return out


def _source(raw: Mapping[str, Any], base: TrafficConfig) -> SourceRule:
    """One ``[[traffic.source]]`` table (errors name the key; the caller adds where)."""
    link = raw.get("link", "*")
    if not isinstance(link, str) or not (link in ("*", AUTOPILOT_LINK, FLEET_LINK) or link.startswith(OBSTACLE_LINK_PREFIX)):
        raise ConfigError(f"link = {link!r} must be \"autopilot\", \"obstacles\", \"obstaclesN\", \"fleet\" or \"*\"")
    default_kinds = base.autopilot_link_kinds if link == AUTOPILOT_LINK else base.obstacle_link_kinds
    policy = SourcePolicy(
        kinds=_kinds("kinds", raw["kinds"]) if "kinds" in raw else default_kinds,
        position_std_m=_std("position_std_m", raw.get("position_std_m", base.position_std_m)),
        vertical_std_m=_std("vertical_std_m", raw.get("vertical_std_m", base.vertical_std_m)),
        velocity_std_mps=_std("velocity_std_mps", raw.get("velocity_std_mps", base.velocity_std_mps)),
        radius_m=check.number("radius_m", raw["radius_m"], positive=True, hi=1000.0) if "radius_m" in raw else None,
        range_m=_range("range_m", raw["range_m"]) if "range_m" in raw else base.range_m,
    )
    system = check.integer("system", raw["system"], lo=1, hi=255) if "system" in raw else None
    icao = check.integer("icao", raw["icao"], lo=0, hi=0xFFFFFF) if "icao" in raw else None
    return SourceRule(link, system, icao, policy)


def traffic_from_toml(table: Any, where: str) -> TrafficConfig:
    """Validate a ``[traffic]`` table with :mod:`companion.validation`'s checks.

    Errors start with ``where`` (file and section, e.g. ``"x.toml [traffic]"``), then the
    ``[[traffic.source]]`` entry if any, then ``key = value must be ...``.
    """
    table = check.table(where, table)
    check.check_keys(where, table, _KEYS)
    try:
        values: dict[str, Any] = {}
        if "obstacle_links" in table:
            values["obstacle_links"] = _links("obstacle_links", table["obstacle_links"])
        for key in ("autopilot_link_kinds", "obstacle_link_kinds"):
            if key in table:
                values[key] = _kinds(key, table[key])
        for key in ("position_std_m", "vertical_std_m", "velocity_std_mps"):
            if key in table:
                values[key] = _std(key, table[key])
        for key in ("clock_window_s", "clock_jump_s", "statustext_period_s"):
            if key in table:
                values[key] = check.number(key, table[key], positive=True, hi=_MAX_PERIOD_S)
        if "geoid_separation_m" in table:
            values["geoid_separation_m"] = check.number("geoid_separation_m", table["geoid_separation_m"], lo=-120.0, hi=120.0)
        if "range_m" in table:
            values["range_m"] = _range("range_m", table["range_m"])
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    base = TrafficConfig(**values)  # the section's own defaults are the sources' defaults
    rules = []
    for i, raw in enumerate(check.array_of_tables(f"{where} source", table.get("source", []), max_len=MAX_SOURCES)):
        w = f"{where} [[traffic.source]] #{i + 1}"
        check.check_keys(w, raw, _SOURCE_KEYS)
        try:
            rules.append(_source(raw, base))
        except ConfigError as exc:
            raise ConfigError(f"{w}: {exc}") from None
    return TrafficConfig(**values, sources=tuple(rules))
