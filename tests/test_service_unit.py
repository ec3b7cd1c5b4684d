"""docs/companion.service, the systemd unit docs/REAL_VEHICLE.md tells operators to install:
systemd accepts it, its command is one ``fly`` accepts, and its settings agree with fly's
exit codes, timeouts and notifications."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from companion.cli import build_parser
from companion.commands import fly
from companion.realtime.run_end import Outcome
from tests.test_doc_commands import _problems

ROOT = Path(__file__).resolve().parent.parent
UNIT = ROOT / "docs" / "companion.service"
#: Where the unit says the companion is installed (docs/REAL_VEHICLE.md's install steps).
INSTALLED = "/home/pi/ogccmpc/.venv/bin/companion"


def unit_settings(text: str) -> dict[tuple[str, str], list[str]]:
    """``(section, key) -> values`` of a unit file: comments dropped, ``\\`` continuations joined."""
    settings: dict[tuple[str, str], list[str]] = {}
    section, pending = "", ""
    for raw in text.splitlines():
        line = raw.strip()
        if not pending and (not line or line.startswith(("#", ";"))):
            continue
        line = pending + line
        if line.endswith("\\"):
            pending = line[:-1].rstrip() + " "
            continue
        pending = ""
        if line.startswith("[") and line.endswith("]"):
            section = line[1:-1]
            continue
        key, _, value = line.partition("=")
        settings.setdefault((section, key.strip()), []).append(value.strip())
    return settings


SETTINGS = unit_settings(UNIT.read_text(encoding="utf-8"))


def setting(key: str, section: str = "Service") -> str:
    (value,) = SETTINGS[(section, key)]
    return value


def seconds(value: str) -> float:
    """A systemd time span as plain seconds or with one unit (``15``, ``15s``, ``500ms``, ``2min``)."""
    for suffix, scale in (("ms", 1e-3), ("min", 60.0), ("s", 1.0)):
        if value.endswith(suffix):
            return float(value[: -len(suffix)]) * scale
    return float(value)


def test_that_systemd_accepts_the_unit(tmp_path):
    """``systemd-analyze verify``, with the command pointed at this machine's companion (it must exist)."""
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        pytest.skip("systemd-analyze is not installed (Debian's package systemd)")
    companion = Path(sys.executable).parent / "companion"
    assert companion.exists(), f"{companion}: the companion entry point, installed by `make venv`"
    unit = tmp_path / "companion.service"
    text = UNIT.read_text(encoding="utf-8")
    assert INSTALLED in text
    unit.write_text(text.replace(INSTALLED, str(companion)), encoding="utf-8")
    done = subprocess.run([analyze, "verify", str(unit)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and not done.stdout and not done.stderr, done.stdout + done.stderr


def test_that_the_units_command_is_one_fly_accepts():
    program, _, rest = setting("ExecStart").partition(" ")
    assert program == INSTALLED
    assert rest.split()[0] == "fly"
    assert _problems("companion", rest) == []


def test_that_the_unit_agrees_with_fly():
    assert setting("Type") == "notify" and setting("NotifyAccess") == "main"  # fly itself says READY=1 and pings
    assert int(setting("SuccessExitStatus")) == Outcome.STOPPED.code      # stopped and handed back: not a failure
    assert setting("Restart") == "no"                                      # docs/REAL_VEHICLE.md says why
    assert setting("KillMode") == "mixed" and setting("KillSignal") == "SIGTERM"
    fly_parser = next(a for a in build_parser()._actions if a.dest == "command").choices["fly"]
    hand_back_s = fly_parser.get_default("hand_back_timeout")
    assert seconds(setting("TimeoutStopSec")) >= hand_back_s + 5.0        # the hand-back, then the planner's join
    assert seconds(setting("TimeoutStartSec")) > fly._PLANNER_START_S      # READY=1 comes once the planner is up
    watchdog_s = seconds(setting("WatchdogSec"))
    # far above the stream's gaps (tens of ms; 150 ms is its own alarm), short enough to name a hang
    assert 1.0 <= watchdog_s <= 5.0


def test_that_real_vehicle_md_shows_the_units_command_as_shipped():
    page = (ROOT / "docs" / "REAL_VEHICLE.md").read_text(encoding="utf-8")
    block = page.split("```ini\n", 1)[1].split("```", 1)[0]
    assert unit_settings("[Service]\n" + block)[("Service", "ExecStart")] == [setting("ExecStart")]
