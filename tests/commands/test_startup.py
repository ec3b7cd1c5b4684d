"""Start-up stays light: building the parser imports nothing heavy, and the parsers' copies of
names and defaults (``companion/commands/_defaults.py``) agree with the modules that define them.

Timing lives in ``python -m tests.benchmarks startup``; this pins what makes start-up short.
"""

from __future__ import annotations

import ast
import importlib
import json
import subprocess
import sys
from pathlib import Path

import pytest

from companion.cli import COMMANDS
from companion.commands import _defaults

COMMANDS_DIR = Path(__file__).resolve().parents[2] / "companion" / "commands"
HEAVY = ("numpy", "scipy", "filterpy", "osqp", "numba", "pymavlink", "matplotlib")

#: _defaults name -> (module, attribute) that defines it
SOURCES = {
    "DEFAULT_URL": ("companion.mavlink.link", "DEFAULT_URL"),
    "FORMULATIONS": ("companion.core.planner.config", "FORMULATIONS"),
    "SOLVERS": ("companion.core.planner.config", "SOLVERS"),
    "TAKEOVER_CHOICES": ("companion.mavlink.offboard", "TAKEOVER_CHOICES"),
    "METHODS": ("companion.offline.campaign.generate", "METHODS"),
    "FAMILIES": ("companion.offline.campaign.generate", "FAMILIES"),
    "VEHICLES": ("companion.offline.campaign.generate", "VEHICLES"),
    "COORDINATION_MODES": ("companion.loop.fleet_config", "COORDINATION_MODES"),
    "DEFAULT_DURATION_S": ("companion.offline.campaign.generate", "DEFAULT_DURATION_S"),
    "EKF_CORRELATION_S": ("companion.offline.campaign.generate", "EKF_CORRELATION_S"),
    "MAX_DURATION_S": ("companion.offline.campaign.generate", "MAX_DURATION_S"),
    "MAX_EPISODES": ("companion.offline.campaign.run", "MAX_EPISODES"),
    "WORKERS_PER_CPU": ("companion.offline.campaign.run", "WORKERS_PER_CPU"),
    "PROGRESS_MODES": ("companion.offline.campaign.progress", "MODES"),
    "MAX_SYSTEMS": ("companion.offline.crowd", "MAX_SYSTEMS"),
    "IDENTIFY_HORIZON_RANGE_S": ("companion.offline.identify", "HORIZON_RANGE_S"),
    "IDENTIFY_REFERENCE_LAG_RANGE_S": ("companion.offline.identify", "REFERENCE_LAG_RANGE_S"),
}


@pytest.mark.parametrize("name", sorted(SOURCES))
def test_that_each_copy_for_the_parsers_equals_its_source(name):
    module, attr = SOURCES[name]
    assert getattr(_defaults, name) == getattr(importlib.import_module(module), attr)


def test_that_every_copy_is_checked():
    copies = {n for n in vars(_defaults) if n.isupper()}
    assert copies == set(SOURCES)


def test_that_every_module_defining_register_is_a_listed_command():
    defining = set()
    for path in COMMANDS_DIR.glob("*.py"):
        tree = ast.parse(path.read_text())
        if any(isinstance(n, ast.FunctionDef) and n.name == "register" for n in tree.body):
            defining.add(path.stem)
    assert defining == set(COMMANDS)


_PROBE = r"""
import json, sys
from companion.cli import main
for argv in (["--version"], ["--help"], ["fly", "--help"], ["campaign", "--help"]):
    try:
        main(argv)
    except SystemExit:
        pass
print(json.dumps(sorted(m for m in sys.modules if m.split(".")[0] in %r)))
"""


def test_that_version_and_help_import_nothing_heavy():
    out = subprocess.run([sys.executable, "-c", _PROBE % (HEAVY,)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert json.loads(out.stdout.strip().splitlines()[-1]) == []
