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
    "companion/loop": ("companion.offline", "companion.plots", "companion.commands", "companion.cli", "mavsim", "matplotlib"),
    "companion/offline": ("companion.commands", "companion.cli", "matplotlib"),
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

#: Where the companion may name PX4 in code: its autopilot module and its registration.
PX4_ALLOWED = ("companion/mavlink/autopilots/px4.py", "companion/mavlink/autopilots/__init__.py")
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
    for path in sorted((root / "companion").rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        if rel not in PX4_ALLOWED:
            bad += [f.replace(str(path), rel) for f in _px4_names(path)]
    return bad


def test_that_no_code_outside_the_px4_autopilot_module_names_px4():
    """Adding an autopilot is one module in companion/mavlink/autopilots/ and its registration."""
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
