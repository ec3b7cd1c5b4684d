"""The README's fly recipes, extracted and run as written (bash, this checkout's commands).

A recipe is the fenced ``sh`` block that follows a ``<!-- fly-recipe: NAME ...`` comment
in README.md. :func:`run_recipe` writes it verbatim into a bash script (``bash -e``), with
``companion`` and ``mavsim`` on PATH as this checkout's modules run by this interpreter,
in a scratch directory where ``configs`` links to the repository's. The recipes use the
ports PX4 SITL uses (14540, 14550, 18570, 14601), which other flights on the same machine
use too: where ``unshare -n`` works (root, Linux) the script runs in a network namespace
of its own with only loopback (``RECIPE_NETNS=0`` turns that off).
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
_MARK = re.compile(r"<!--\s*fly-recipe:\s*(\S+)[^>]*-->\s*\n```sh\n(.*?)\n```", re.S)


def readme_recipes(path: Path = REPO / "README.md") -> dict[str, str]:
    """Every fly recipe of ``path``: name -> the block's text, verbatim."""
    return {m.group(1): m.group(2) for m in _MARK.finditer(path.read_text(encoding="utf-8"))}


def private_network() -> bool:
    """True when scripts can run in a network namespace of their own (``unshare -n``)."""
    if os.environ.get("RECIPE_NETNS", "1") == "0":
        return False
    try:
        return subprocess.run(["unshare", "-n", "true"], capture_output=True, timeout=10).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


def _bin(work: Path) -> Path:
    bin_dir = work / "bin"
    bin_dir.mkdir(exist_ok=True)
    for name, module in (("companion", "companion.cli"), ("mavsim", "mavsim")):
        exe = bin_dir / name
        exe.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m {module} "$@"\n')
        exe.chmod(0o755)
    return bin_dir


def run_recipe(recipe: str, work: Path, timeout_s: float, prelude: str = "") -> subprocess.CompletedProcess:
    """Run ``recipe`` as written in ``work`` (after ``prelude``, the harness's own lines);
    returns the finished process (stdout and stderr as text). Whatever it left running is
    killed (its process group)."""
    work.mkdir(parents=True, exist_ok=True)
    if not (work / "configs").exists():
        (work / "configs").symlink_to(REPO / "configs")
    netns = private_network()
    script = work / "recipe.sh"
    script.write_text(("ip link set lo up\n" if netns else "") + prelude + recipe + "\n")
    env = {**os.environ, "PATH": f"{_bin(work)}{os.pathsep}{os.environ.get('PATH', '')}",
           "PYTHONPATH": str(REPO) + (os.pathsep + os.environ["PYTHONPATH"] if os.environ.get("PYTHONPATH") else "")}
    cmd = (["unshare", "-n"] if netns else []) + ["bash", "-e", str(script)]
    proc = subprocess.Popen(cmd, cwd=work, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
        err += f"\nrecipe killed after {timeout_s:.0f} s"
    finally:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
    return subprocess.CompletedProcess(cmd, proc.returncode, out, err)
