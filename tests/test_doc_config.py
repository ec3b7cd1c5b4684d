"""docs/CONFIGURATION.md lists every key the scenario loaders accept, and no key they refuse.

The accepted keys come from the code, never from a list kept here: the dataclass fields
of the sections built with ``companion.validation.build_section`` (and the estimator's
``from_mapping``), the key sets the loaders check unknown keys against (mavsim's
``SIM_KEYS``/``WORLD_KEYS``/``OBSTACLE_KEYS``, ``traffic_config``'s), and, for the few
sections whose set is written inline in ``scenario_from_dict``, the ``allowed:`` list
of the error the loader itself gives for an unknown key.

The page: each ``##``/``###`` heading names its section(s) in backticks (`` `[planner]` ``,
`` `[[world.obstacles]]` ``); the first column of the tables below it holds the keys. An
array-of-tables or sub-table heading (`` `[[map.walls]]` ``) documents the key ``walls``
of its parent.
"""

from __future__ import annotations

import copy
import re
from pathlib import Path

import pytest

from companion.core.planner.config import PlannerConfig
from companion.core.planner.vehicle_model import AxisResponse
from companion.errors import ConfigError
from companion.loop.intake import traffic_config
from companion.loop.config import LoopConfig, MissionConfig, scenario_from_dict
from companion.loop.fleet_config import FleetConfig
from companion.mavlink.offboard import OffboardConfig
from companion.validation import field_names
from estimator import DroneFilterConfig, TrackerConfig
from mavsim import scenario as mavsim_scenario

PAGE = Path(__file__).resolve().parent.parent / "docs" / "CONFIGURATION.md"
HEADING = re.compile(r"^#{2,3}\s+(.*)$")
SECTION = re.compile(r"`\[\[?([A-Za-z0-9_.]+)\]\]?`")
TICKED = re.compile(r"`([^`]+)`")

#: The smallest file the companion loads; a probe key is added to one section of it.
MINIMAL = {"mission": {"goal_ned_m": [1.0, 0.0, -1.0], "goal_tolerance_m": 0.3}}
PROBE = "zz_not_a_key"


def _allowed_by_loader(section: str) -> frozenset[str]:
    """The keys ``scenario_from_dict`` allows in ``section``, from its unknown-key error."""
    data = copy.deepcopy(MINIMAL)
    if section in ("map.walls", "map.static_obstacles"):
        data["map"] = {section.split(".")[1]: [{PROBE: 1}]}
    else:
        data.setdefault(section, {})[PROBE] = 1
    with pytest.raises(ConfigError) as info:
        scenario_from_dict(data, "probe.toml")
    match = re.search(r"\(allowed: ([^)]*)\)", str(info.value))
    assert match, f"[{section}]: the loader's unknown-key error no longer lists the allowed keys: {info.value}"
    return frozenset(k.strip() for k in match.group(1).split(",") if k.strip())


def accepted_keys() -> dict[str, frozenset[str]]:
    """Every section the loaders read, with the keys they accept in it."""
    return {
        "scenario": _allowed_by_loader("scenario"),
        "vehicle": _allowed_by_loader("vehicle"),
        "mission": field_names(MissionConfig),
        "planner": field_names(PlannerConfig),
        "planner.vehicle_response.horizontal": frozenset(AxisResponse.FIELDS),
        "planner.vehicle_response.vertical": frozenset(AxisResponse.FIELDS),
        "estimator": _allowed_by_loader("estimator"),
        "estimator.drone": field_names(DroneFilterConfig),
        "estimator.tracker": field_names(TrackerConfig),
        "companion": field_names(LoopConfig),
        "offboard": field_names(OffboardConfig),
        "traffic": frozenset(traffic_config._KEYS),
        "traffic.source": frozenset(traffic_config._SOURCE_KEYS),
        "fleet": field_names(FleetConfig),
        "map": _allowed_by_loader("map") | {"walls", "static_obstacles"},
        "map.walls": _allowed_by_loader("map.walls"),
        "map.static_obstacles": _allowed_by_loader("map.static_obstacles"),
        "sim": frozenset(mavsim_scenario.SIM_KEYS),
        "world": frozenset(mavsim_scenario.WORLD_KEYS),
        "world.obstacles": frozenset(mavsim_scenario.OBSTACLE_KEYS),
    }


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def documented_keys() -> dict[str, set[str]]:
    """Section -> the keys the page documents for it (first column of its tables)."""
    documented: dict[str, set[str]] = {}
    sections: list[str] = []
    header: list[str] | None = None
    for line in PAGE.read_text(encoding="utf-8").splitlines():
        heading = HEADING.match(line)
        if heading:
            sections = SECTION.findall(heading.group(1))
            for name in sections:
                documented.setdefault(name, set())
                parent, _, child = name.rpartition(".")
                if parent:
                    documented.setdefault(parent, set()).add(child)
            header = None
            continue
        if not line.startswith("|") or not sections:
            header = None if not line.startswith("|") else header
            continue
        cells = _cells(line)
        if header is None:
            header = cells
            continue
        if set(line) <= set("|-: "):
            continue
        keys = TICKED.findall(cells[0])
        for name in sections:
            # A table shared by several sections ("drone default", "tracker default") says
            # per column which section has the key: "–" means it does not.
            column = f"{name.rpartition('.')[2]} default"
            if column in header and cells[header.index(column)] in ("–", "-", ""):
                continue
            documented[name].update(keys)
    return documented


def test_every_section_the_loaders_read_has_a_heading() -> None:
    missing = sorted(set(accepted_keys()) - set(documented_keys()))
    assert not missing, f"docs/CONFIGURATION.md has no heading for {missing}"


@pytest.mark.parametrize("section", sorted(accepted_keys()))
def test_every_accepted_key_is_documented(section: str) -> None:
    missing = sorted(accepted_keys()[section] - documented_keys().get(section, set()))
    assert not missing, f"docs/CONFIGURATION.md [{section}] lacks {missing}"


@pytest.mark.parametrize("section", sorted(accepted_keys()))
def test_no_documented_key_is_refused(section: str) -> None:
    invented = sorted(documented_keys().get(section, set()) - accepted_keys()[section])
    assert not invented, f"docs/CONFIGURATION.md [{section}] documents keys the loaders refuse: {invented}"


def test_every_top_level_section_is_known_to_the_loaders() -> None:
    top = {name.split(".")[0] for name in documented_keys()}
    unknown = sorted(top - set(accepted_keys()))
    assert not unknown, f"docs/CONFIGURATION.md documents sections no loader reads: {unknown}"
