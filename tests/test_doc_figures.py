"""Commands and figures in the docs that go stale without a test saying so.

- docs/SIGNING.md's key command, run as written in bash with a fresh ``HOME``: it failed
  when ``~/.config/ogccmpc`` did not exist. The key it makes must be one the programs read.
- README's ``make test`` line: its test count must stay within 10 % of the default suite as
  collected now (about 7 s to collect), so a README left behind by the suite fails here.
"""

from __future__ import annotations

import os
import re
import stat
import subprocess
import sys
from pathlib import Path


ROOT = Path(__file__).resolve().parent.parent
#: How far (fraction) README's test count may drift from the suite before this test fails.
COUNT_TOLERANCE = 0.10


def _fenced_block_after(text: str, heading: str) -> str:
    """The first fenced code block after ``heading`` (a whole line) in ``text``."""
    after = text.split(f"\n{heading}\n", 1)[1]
    match = re.search(r"^```\w*\n(.*?)^```", after, re.S | re.M)
    assert match, f"no code block after {heading!r}"
    return match.group(1)


def test_that_signings_key_command_works_as_written_in_a_fresh_home(tmp_path):
    from companion.mavlink.signing import load_signing_key

    block = _fenced_block_after((ROOT / "docs" / "SIGNING.md").read_text(), "## The key")
    assert "~/.config/ogccmpc/signing.key" in block
    env = {**os.environ, "HOME": str(tmp_path)}
    run = subprocess.run(["bash", "-e", "-c", block.replace("python3 ", f"{sys.executable} ")], env=env,
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    key = tmp_path / ".config" / "ogccmpc" / "signing.key"
    assert stat.S_IMODE(key.stat().st_mode) == 0o600
    assert stat.S_IMODE(key.parent.stat().st_mode) == 0o700
    assert len(load_signing_key(key)) == 32


def _collected() -> int:
    run = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider"], cwd=ROOT,
                         capture_output=True, text=True, timeout=300, env={**os.environ, "PYTHONPATH": str(ROOT)})
    match = re.search(r"^(\d+)(?:/\d+)? tests? collected", run.stdout, re.M)
    assert match, run.stdout[-2000:] + run.stderr[-2000:]
    return int(match.group(1))


def test_that_the_readmes_test_count_is_the_suites_within_ten_percent():
    line = next(line for line in (ROOT / "README.md").read_text().splitlines() if line.startswith("- `make test`: "))
    shown = int(re.match(r"- `make test`: (\d+) tests", line).group(1))
    collected = _collected()
    assert abs(shown - collected) <= COUNT_TOLERANCE * collected, (
        f"README says {shown} tests, the default suite collects {collected}: measure `make test` again and update it")


def test_that_the_docs_say_goal_ned_ms_frame_and_how_to_fly_over_serial_on_a_pi():
    """Nothing said what frame ``goal_ned_m`` is in, nor how to fly a real vehicle over serial or
    install on a Raspberry Pi: the pages that do, and the README's links to them."""
    config = (ROOT / "docs" / "CONFIGURATION.md").read_text()
    assert "**The frame of `goal_ned_m`**" in config and "5 m above it" in config
    page = (ROOT / "docs" / "REAL_VEHICLE.md").read_text()
    for needle in ("TELEM2", "SER_TEL2_BAUD", "/dev/serial0,921600", "aarch64", "numba", "osqp", "ExecStart="):
        assert needle in page, needle
    assert "(docs/REAL_VEHICLE.md)" in (ROOT / "README.md").read_text()
