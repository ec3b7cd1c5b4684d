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
    clock_window_s = 10.0         # see companion.loop.clocks
    clock_jump_s = 1.0
    statustext_period_s = 5.0     # at most one rejection STATUSTEXT per period

    [[traffic.source]]            # per-source overrides, the first match wins
    link = "obstacles"            # "autopilot", "obstacles" (any obstacle link) or a link name ("obstacles1")
    system = 101                  # optional: only this MAVLink system id
    icao = 0xABCDEF               # optional: only this ADS-B ICAO address
    kinds = ["ODOMETRY"]
    position_std_m = 0.2
    radius_m = 0.5                # body radius of obstacles from this source (default [companion] obstacle_radius_m;
                                  # ADSB emitter types give their own unless a source sets it)

ODOMETRY from other systems on the autopilot link is the old same-socket wiring: allow it
only explicitly (``autopilot_link_kinds = ["ADSB_VEHICLE", "ODOMETRY"]``); it is dangerous
(see docs/OBSTACLES.md) and the companion warns about it either way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

from companion.errors import ConfigError
from companion.mavlink.traffic import TRAFFIC_KINDS

AUTOPILOT_LINK = "autopilot"
OBSTACLE_LINK_PREFIX = "obstacles"


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
    sources: tuple[SourceRule, ...] = field(default_factory=tuple)

    def policy(self, link: str, system: int, icao: int | None = None) -> SourcePolicy:
        """The policy of a source: the first matching rule, else the link's defaults."""
        for rule in self.sources:
            if rule.matches(link, system, icao):
                return rule.policy
        kinds = self.autopilot_link_kinds if link == AUTOPILOT_LINK else self.obstacle_link_kinds
        return SourcePolicy(kinds, self.position_std_m, self.vertical_std_m, self.velocity_std_mps)


_KEYS = {"obstacle_links", "autopilot_link_kinds", "obstacle_link_kinds", "position_std_m", "vertical_std_m",
         "velocity_std_mps", "clock_window_s", "clock_jump_s", "statustext_period_s", "source"}
_SOURCE_KEYS = {"link", "system", "icao", "kinds", "position_std_m", "vertical_std_m", "velocity_std_mps", "radius_m"}


def _positive(table: Mapping[str, Any], key: str, default: float, where: str) -> float:
    value = table.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise ConfigError(f"{where} {key}: expected a finite number > 0, got {value!r}")
    return float(value)


def _kinds(table: Mapping[str, Any], key: str, default: frozenset, where: str) -> frozenset:
    value = table.get(key)
    if value is None:
        return default
    if not isinstance(value, list) or not all(isinstance(k, str) for k in value):
        raise ConfigError(f"{where} {key}: expected a list of message names, got {value!r}")
    unknown = sorted(set(value) - set(TRAFFIC_KINDS))
    if unknown:
        raise ConfigError(f"{where} {key}: unknown kind(s) {', '.join(unknown)} (known: {', '.join(TRAFFIC_KINDS)})")
    return frozenset(value)


def _optional_int(table: Mapping[str, Any], key: str, lo: int, hi: int, where: str) -> int | None:
    value = table.get(key)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise ConfigError(f"{where} {key}: expected an integer in {lo}..{hi}, got {value!r}")
    return value


def traffic_from_toml(table: Mapping[str, Any], where: str) -> TrafficConfig:
    """Validate a ``[traffic]`` table; errors name ``where`` (file and section) and the key."""
    if not isinstance(table, Mapping):
        raise ConfigError(f"{where}: must be a table")
    unknown = sorted(set(table) - _KEYS)
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)} (allowed: {', '.join(sorted(_KEYS))})")
    links = table.get("obstacle_links", [])
    if not isinstance(links, list) or not all(isinstance(u, str) and u for u in links):
        raise ConfigError(f"{where} obstacle_links: expected a list of pymavlink connection strings, got {links!r}")
    base = TrafficConfig()
    std = {k: _positive(table, k, getattr(base, k), where) for k in ("position_std_m", "vertical_std_m", "velocity_std_mps")}
    raw_sources = table.get("source", [])
    if not isinstance(raw_sources, list):
        raise ConfigError(f"{where} source: expected an array of tables [[traffic.source]]")
    rules = []
    for i, src in enumerate(raw_sources):
        w = f"{where} [[traffic.source]] #{i + 1}"
        if not isinstance(src, Mapping):
            raise ConfigError(f"{w}: must be a table")
        bad = sorted(set(src) - _SOURCE_KEYS)
        if bad:
            raise ConfigError(f"{w}: unknown key(s) {', '.join(bad)} (allowed: {', '.join(sorted(_SOURCE_KEYS))})")
        link = src.get("link", "*")
        if not isinstance(link, str) or not (link in ("*", AUTOPILOT_LINK) or link.startswith(OBSTACLE_LINK_PREFIX)):
            raise ConfigError(f"{w} link: expected \"autopilot\", \"obstacles\", \"obstaclesN\" or \"*\", got {link!r}")
        default_kinds = _kinds(table, "autopilot_link_kinds" if link == AUTOPILOT_LINK else "obstacle_link_kinds",
                               base.autopilot_link_kinds if link == AUTOPILOT_LINK else base.obstacle_link_kinds, where)
        radius = src.get("radius_m")
        policy = SourcePolicy(
            kinds=_kinds(src, "kinds", default_kinds, w),
            position_std_m=_positive(src, "position_std_m", std["position_std_m"], w),
            vertical_std_m=_positive(src, "vertical_std_m", std["vertical_std_m"], w),
            velocity_std_mps=_positive(src, "velocity_std_mps", std["velocity_std_mps"], w),
            radius_m=None if radius is None else _positive(src, "radius_m", 1.0, w),
        )
        rules.append(SourceRule(link, _optional_int(src, "system", 1, 255, w), _optional_int(src, "icao", 0, 0xFFFFFF, w), policy))
    return TrafficConfig(
        obstacle_links=tuple(links),
        autopilot_link_kinds=_kinds(table, "autopilot_link_kinds", base.autopilot_link_kinds, where),
        obstacle_link_kinds=_kinds(table, "obstacle_link_kinds", base.obstacle_link_kinds, where),
        clock_window_s=_positive(table, "clock_window_s", base.clock_window_s, where),
        clock_jump_s=_positive(table, "clock_jump_s", base.clock_jump_s, where),
        statustext_period_s=_positive(table, "statustext_period_s", base.statustext_period_s, where),
        sources=tuple(rules),
        **std,
    )
