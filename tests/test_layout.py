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
