"""The layers and their one-way imports (docs/ARCHITECTURE.md), read from the source as text.

Each rule names a folder and the imports its modules may not make, at any depth of
the folder. A violation names the file, the line and the import, so the fix is obvious.
"""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# folder -> module prefixes it must not import
RULES: dict[str, tuple[str, ...]] = {
    "companion/core": (
        "pymavlink", "matplotlib", "socket", "select", "threading", "multiprocessing", "subprocess", "asyncio",
        "companion.mavlink", "companion.loop", "companion.offline", "companion.plots", "companion.commands",
        "companion.cli", "mavsim",
    ),
    "companion/mavlink": (
        "companion.core", "companion.loop", "companion.offline", "companion.plots", "companion.commands",
        "estimator", "mavsim", "matplotlib",
    ),
    "companion/loop": ("companion.realtime", "companion.offline", "companion.view", "companion.plots", "companion.commands", "companion.cli",
                       "mavsim", "matplotlib", "socket", "select", "threading", "multiprocessing", "subprocess", "signal"),
    "companion/realtime": ("companion.offline", "companion.plots", "companion.commands", "companion.cli", "mavsim",
                           "companion.view", "matplotlib"),
    "companion/offline": ("companion.commands", "companion.cli", "companion.view", "matplotlib"),
    "companion/view": ("companion.realtime", "companion.offline", "companion.plots", "companion.commands", "companion.cli",
                       "mavsim", "matplotlib"),
    "companion/plots": ("companion.loop", "companion.mavlink", "companion.offline", "companion.commands", "mavsim"),
    "estimator": ("companion", "mavsim", "pymavlink", "osqp", "matplotlib", "socket", "threading"),
    "mavsim": ("companion", "estimator", "osqp", "filterpy", "matplotlib"),
}


def _imports(path: Path) -> list[tuple[int, str]]:
    tree = ast.parse(path.read_text(), filename=str(path))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append((node.lineno, node.module))
            # `from companion import loop` imports companion.loop
            found += [(node.lineno, f"{node.module}.{alias.name}") for alias in node.names]
    return found


def _violations(root: Path, folder: str, banned: tuple[str, ...]) -> list[str]:
    bad = []
    for path in sorted((root / folder).rglob("*.py")):
        for line, module in _imports(path):
            if any(module == b or module.startswith(b + ".") for b in banned):
                bad.append(f"{path.relative_to(root)}:{line} imports {module}")
    return bad


@pytest.mark.parametrize("folder", sorted(RULES))
def test_that_each_layer_imports_only_downwards(folder):
    assert (ROOT / folder).is_dir(), f"{folder} is named in the layer rules but does not exist"
    assert _violations(ROOT, folder, RULES[folder]) == []


def test_that_the_rule_checker_sees_a_violation(tmp_path):
    core = tmp_path / "companion" / "core"
    core.mkdir(parents=True)
    (core / "x.py").write_text("import numpy\nfrom pymavlink import mavutil\nfrom companion import loop\n")
    assert _violations(tmp_path, "companion/core", RULES["companion/core"]) == [
        "companion/core/x.py:2 imports pymavlink",
        "companion/core/x.py:2 imports pymavlink.mavutil",
        "companion/core/x.py:3 imports companion.loop",
    ]


def test_that_every_package_in_the_tree_is_listed_for_the_wheel():
    """pyproject.toml lists its packages (configs/ is mapped to companion.scenarios): none may be forgotten."""
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {"companion.scenarios"}
    for top in ("companion", "estimator", "mavsim"):
        for init in (ROOT / top).rglob("__init__.py"):
            found.add(".".join(init.parent.relative_to(ROOT).parts))
    assert listed == found


def test_that_the_two_signing_modules_stay_twins():
    """companion and mavsim may not import each other, so each carries MAVLink signing: the same code."""
    def code(path: Path) -> str:
        text = path.read_text()
        return text[text.index('"""', 3) + 3:]  # everything after the module docstring
    assert code(ROOT / "companion/mavlink/signing.py") == code(ROOT / "mavsim/signing.py")


# ---------------------------------------------------------------- the autopilot boundary

#: Where code may name PX4: the companion's PX4 autopilot module and mavsim's PX4 personality
#: (with its response model), and their registrations.
PX4_ALLOWED = ("companion/mavlink/autopilots/px4.py", "companion/mavlink/autopilots/__init__.py",
               "mavsim/personalities/px4.py", "mavsim/personalities/px4_response.py", "mavsim/personalities/px4_mission.py",
               "mavsim/personalities/px4_geofence.py",
               "mavsim/personalities/__init__.py")
#: The folders the check covers.
PX4_CHECKED = ("companion", "mavsim")
#: PX4's own mode names as strings: generic code asks an autopilot for a mode's role instead.
PX4_MODE_STRINGS = frozenset({"OFFBOARD", "POSCTL", "ALTCTL", "AUTO.LOITER", "AUTO.TAKEOFF", "AUTO.LAND", "AUTO.RTL",
                              "AUTO.MISSION"})


def _px4_names(path: Path) -> list[str]:
    """Every identifier, import or attribute of ``path`` that names PX4, and every PX4 mode name
    as a whole string (comments and docstrings are prose, not code, and may say PX4)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    found = []
    for node in ast.walk(tree):
        names: list[str] = []
        if isinstance(node, ast.Name):
            names = [node.id]
        elif isinstance(node, ast.Attribute):
            names = [node.attr]
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names = [node.name]
        elif isinstance(node, ast.arg):
            names = [node.arg]
        elif isinstance(node, ast.alias):
            names = [node.name, node.asname or ""]
        elif isinstance(node, ast.ImportFrom):
            names = [node.module or ""]
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value in PX4_MODE_STRINGS:
            found.append(f"{path}:{node.lineno} string {node.value!r}")
        found += [f"{path}:{node.lineno} {name}" for name in names if "px4" in name.lower()]
    return found


def _px4_violations(root: Path) -> list[str]:
    bad = []
    for path in sorted(p for folder in PX4_CHECKED for p in (root / folder).rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        if rel not in PX4_ALLOWED:
            bad += [f.replace(str(path), rel) for f in _px4_names(path)]
    return bad


def test_that_no_code_outside_the_px4_autopilot_module_names_px4():
    """Adding an autopilot is one module in companion/mavlink/autopilots/ and its registration,
    and mavsim's personality of it one module in mavsim/personalities/ and its registration."""
    assert _px4_violations(ROOT) == []


def test_that_the_px4_name_checker_sees_names_imports_and_mode_strings(tmp_path):
    loop = tmp_path / "companion" / "loop"
    loop.mkdir(parents=True)
    (loop / "x.py").write_text('"""PX4 in prose is fine."""\nfrom companion.mavlink.autopilots import px4\n'
                               'def f(hb):  # PX4 in a comment too\n    return hb.mode == "AUTO.LOITER" or px4.OFFBOARD\n')
    assert sorted(_px4_violations(tmp_path)) == [
        "companion/loop/x.py:2 px4",
        "companion/loop/x.py:4 px4",
        "companion/loop/x.py:4 string 'AUTO.LOITER'",
    ]


def test_that_the_px4_name_checker_covers_mavsim_but_its_px4_personality(tmp_path):
    core = tmp_path / "mavsim"
    (core / "personalities").mkdir(parents=True)
    (core / "core.py").write_text('"""A PX4-like simulator."""\nfrom mavsim.personalities.px4 import Commander\n'
                                  'def engaged(c):\n    return c.armed and c.mode == "OFFBOARD"\n'
                                  'MAV_AUTOPILOT_PX4 = 12\n')
    (core / "personalities" / "px4.py").write_text('MODES = {"OFFBOARD": (6, 0)}\nMAV_AUTOPILOT_PX4 = 12\n')
    (core / "personalities" / "__init__.py").write_text("from mavsim.personalities.px4 import PX4\n")
    assert sorted(_px4_violations(tmp_path)) == [
        "mavsim/core.py:2 mavsim.personalities.px4",
        "mavsim/core.py:4 string 'OFFBOARD'",
        "mavsim/core.py:5 MAV_AUTOPILOT_PX4",
    ]


#: Folders whose every module docs/ARCHITECTURE.md's module map lists.
MAPPED = ("companion", "mavsim/personalities")


#: Where the companion may name ArduPilot in code: its autopilot module and its registration.
ARDUPILOT_ALLOWED = ("companion/mavlink/autopilots/ardupilot.py", "companion/mavlink/autopilots/__init__.py")
#: ArduCopter's mode names as strings that no other autopilot shares (LOITER, BRAKE, GUIDED...).
ARDUPILOT_MODE_STRINGS = frozenset({"GUIDED", "LOITER", "BRAKE", "STABILIZE", "ALT_HOLD", "POSHOLD", "SMART_RTL",
                                    "AVOID_ADSB", "GUIDED_NOGPS"})


def _ardupilot_names(path: Path) -> list[str]:
    """Every identifier, import or attribute of ``path`` that names ArduPilot (or ArduCopter, or its
    dialect ``ardupilotmega``), and every ArduCopter mode name as a whole string."""
    tree = ast.parse(path.read_text(), filename=str(path))
    found = []
    for node in ast.walk(tree):
        names: list[str] = []
        if isinstance(node, ast.Name):
            names = [node.id]
        elif isinstance(node, ast.Attribute):
            names = [node.attr]
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names = [node.name]
        elif isinstance(node, ast.arg):
            names = [node.arg]
        elif isinstance(node, ast.alias):
            names = [node.name, node.asname or ""]
        elif isinstance(node, ast.ImportFrom):
            names = [node.module or ""]
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value in ARDUPILOT_MODE_STRINGS:
            found.append(f"{path}:{node.lineno} string {node.value!r}")
        found += [f"{path}:{node.lineno} {name}" for name in names
                  if any(w in name.lower() for w in ("ardupilot", "arducopter"))]
    return found


def _ardupilot_violations(root: Path) -> list[str]:
    bad = []
    for path in sorted((root / "companion").rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        if rel not in ARDUPILOT_ALLOWED:
            bad += [f.replace(str(path), rel) for f in _ardupilot_names(path)]
    return bad


def test_that_no_code_outside_the_ardupilot_autopilot_module_names_ardupilot():
    """ArduPilot is one module in companion/mavlink/autopilots/ and its registration, as PX4 is."""
    assert _ardupilot_violations(ROOT) == []


def test_that_the_ardupilot_name_checker_sees_names_imports_and_mode_strings(tmp_path):
    loop = tmp_path / "companion" / "loop"
    loop.mkdir(parents=True)
    (loop / "x.py").write_text('"""ArduPilot in prose is fine."""\nfrom companion.mavlink.autopilots import ardupilot\n'
                               'def f(hb):  # ArduCopter in a comment too\n    return hb.mode == "LOITER" or ardupilot.GUIDED\n')
    assert sorted(_ardupilot_violations(tmp_path)) == [
        "companion/loop/x.py:2 ardupilot",
        "companion/loop/x.py:4 ardupilot",
        "companion/loop/x.py:4 string 'LOITER'",
    ]


def test_that_every_module_is_in_the_architecture_module_map():
    """docs/ARCHITECTURE.md lists every module of companion/ and mavsim/personalities/ with its
    one job, under its folder."""
    text = (ROOT / "docs" / "ARCHITECTURE.md").read_text()
    section = text[text.index("## Module map"):text.index("## Where a change lands")]
    missing = []
    folder = None
    listed: set[str] = set()
    for line in section.splitlines():
        if line.startswith(tuple("`" + m for m in MAPPED)) and line.rstrip().endswith("/`"):
            folder = line.strip("`").rstrip("/")
        elif line.startswith("| `") and folder is not None:
            listed.add(f"{folder}/{line.split('`')[1]}")
    for path in sorted(p for m in MAPPED for p in (ROOT / m).rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        if path.name == "__init__.py" and path.parent.name not in ("autopilots", "personalities"):
            continue
        if rel not in listed:
            missing.append(rel)
    assert missing == [], f"not in docs/ARCHITECTURE.md's module map: {missing}"


# ---------------------------------------------------------------- mavsim's ArduPilot personality

#: Where mavsim may name ArduPilot in code: its ArduPilot personality (with its response model)
#: and the registry.
MAVSIM_ARDUPILOT_ALLOWED = ("mavsim/personalities/ardupilot.py", "mavsim/personalities/ardupilot_response.py",
                            "mavsim/personalities/__init__.py")
#: ArduCopter's own mode names as strings (no other personality has them).
MAVSIM_ARDUPILOT_MODE_STRINGS = frozenset({"GUIDED", "LOITER", "BRAKE", "STABILIZE", "ALT_HOLD", "POSHOLD",
                                           "SMART_RTL", "AVOID_ADSB", "GUIDED_NOGPS"})


def _mavsim_ardupilot_names(path: Path) -> list[str]:
    """Identifiers, imports and attributes of ``path`` that name ArduPilot, ArduCopter or its dialect
    (``ardupilotmega``), and ArduCopter mode names as whole strings; prose may name them."""
    tree = ast.parse(path.read_text(), filename=str(path))
    found = []
    for node in ast.walk(tree):
        names: list[str] = []
        if isinstance(node, ast.Name):
            names = [node.id]
        elif isinstance(node, ast.Attribute):
            names = [node.attr]
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names = [node.name]
        elif isinstance(node, ast.arg):
            names = [node.arg]
        elif isinstance(node, ast.alias):
            names = [node.name, node.asname or ""]
        elif isinstance(node, ast.ImportFrom):
            names = [node.module or ""]
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) \
                and node.value in MAVSIM_ARDUPILOT_MODE_STRINGS:
            found.append(f"{path}:{node.lineno} string {node.value!r}")
        found += [f"{path}:{node.lineno} {name}" for name in names
                  if any(w in name.lower() for w in ("ardupilot", "arducopter"))]
    return found


def _mavsim_ardupilot_violations(root: Path) -> list[str]:
    bad = []
    for path in sorted((root / "mavsim").rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        if rel not in MAVSIM_ARDUPILOT_ALLOWED:
            bad += [f.replace(str(path), rel) for f in _mavsim_ardupilot_names(path)]
    return bad


def test_that_no_mavsim_code_outside_its_ardupilot_personality_names_ardupilot():
    """mavsim's ArduPilot is one personality module (and its response model), as its PX4 is."""
    assert _mavsim_ardupilot_violations(ROOT) == []


def test_that_the_mavsim_ardupilot_name_checker_sees_names_imports_and_mode_strings(tmp_path):
    core = tmp_path / "mavsim"
    (core / "personalities").mkdir(parents=True)
    (core / "core.py").write_text('"""ArduPilot in prose is fine."""\nfrom pymavlink.dialects.v20 import ardupilotmega\n'
                                  'MODE = "GUIDED"  # ArduCopter in a comment too\n')
    (core / "personalities" / "ardupilot.py").write_text('MODES = {"GUIDED": 4}\nARDUPILOT = 1\n')
    assert sorted(_mavsim_ardupilot_violations(tmp_path)) == [
        "mavsim/core.py:2 ardupilotmega",
        "mavsim/core.py:3 string 'GUIDED'",
    ]
