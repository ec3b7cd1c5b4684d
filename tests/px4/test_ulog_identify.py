"""``companion identify`` on the ULog PX4 wrote of a ``fly --identify`` flight: the model of its tlog.

Flies PX4 SITL once (about 2 minutes); PX4's logger writes the ULog into the run directory's
``log/`` (from arming on, its default). The committed excerpt ``tests/data/px4_steps.*`` is
one such flight (tests/offline/test_ulog.py checks it without PX4).
"""

from __future__ import annotations

import subprocess
import sys

import pytest

from tests.offline.test_ulog import assert_same_model_as_tlog
from tests.px4.sitl import REPO, Sitl, raise_priority, sitl_dir

pytestmark = [pytest.mark.px4]


def test_identify_on_px4s_ulog_gives_the_model_of_the_same_flights_tlog(tmp_path):
    if sitl_dir() is None:
        pytest.fail("no PX4 SITL build: set PX4_SITL_DIR or put one at ../shared/px4-sitl (start-sih inside)")
    tlog = tmp_path / "steps.tlog"
    with Sitl(tmp_path / "px4") as sitl:
        fly = subprocess.run([sys.executable, "-m", "companion.cli", "fly", "--identify", "--arm", "--takeoff-alt", "5",
                              "--tlog", str(tlog), "--connect", "udpin:127.0.0.1:14540"],
                             capture_output=True, text=True, cwd=REPO, timeout=400, preexec_fn=raise_priority)
        assert fly.returncode == 0, fly.stderr[-2000:]
    ulogs = sorted((sitl.work_dir / "run" / "log").rglob("*.ulg"))
    assert ulogs, "PX4 wrote no ULog"
    assert_same_model_as_tlog(tlog, ulogs[-1])
