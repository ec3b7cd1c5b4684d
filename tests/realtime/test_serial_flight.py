"""``companion fly`` through a serial cable at a real link's byte rate, against ``mavsim --serial``.

A pty pair joined at 57600 and at 921600 baud (8N1, :mod:`tests.support.serial_cable`),
mavsim on one end as PX4 on TELEM2, the companion on the other (``--connect DEVICE,BAUD``),
the obstacles on their own UDP link. Checked: the goal, no collision in mavsim's truth,
the stream at its rate, and the bytes each way per second against the line's rate: the
companion's own traffic fits the slow line with room to spare; mavsim's is held to its
budget (half the line) and what did not fit is counted, not queued.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.support.ports import free_udp_port
from tests.support.serial_cable import SerialCable

pytestmark = pytest.mark.realtime   # in .ci/run: 20 of 20 in make flake-check (docs/TESTING.md)

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "configs" / "antipodal.toml"


@pytest.mark.parametrize("baud", [57600, 921600])
def test_that_fly_reaches_the_goal_over_a_serial_line(baud, tmp_path):
    obstacle_port = free_udp_port()
    with SerialCable(baud) as cable:
        sim = subprocess.Popen(
            [sys.executable, "-m", "mavsim", "--scenario", str(SCENARIO), "--serial", cable.a, "--baud", str(baud),
             "--no-gcs", "--obstacle-port", str(obstacle_port), "--obstacle-local-port", "0", "--duration", "60", "--json"],
            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            started = time.monotonic()
            fly = subprocess.run(
                [sys.executable, "-m", "companion.cli", "fly", "--connect", f"{cable.b},{baud}", "--scenario", str(SCENARIO),
                 "--obstacles", f"udpin:127.0.0.1:{obstacle_port}", "--duration", "45", "--exit-after-goal", "1", "--json"],
                cwd=ROOT, capture_output=True, text=True, timeout=120)
            flown_s = time.monotonic() - started
        finally:
            sim.terminate()
            sim_out, sim_err = sim.communicate(timeout=20)
        up_bps = cable.sent["b->a"] / flown_s
    report = json.loads(fly.stdout)
    truth = json.loads(sim_out)
    print(f"{baud} baud: {flown_s:.1f} s, companion -> vehicle {up_bps:.0f} B/s of {baud / 10:.0f}; "
          f"mavsim over budget {truth['link'].get('serial_budget_dropped', 0)} packets; "
          f"setpoints {report['setpoint_rate_hz']} Hz, gap {report['setpoint_gap_max_ms']} ms, "
          f"closest {min(truth['min_distance_m'].values()):.2f} m")
    assert fly.returncode == 0, fly.stderr[-2000:]
    assert report["outcome"] == "goal reached"
    assert truth["goal_reached"] and not truth["collided"], truth["min_distance_m"]
    assert report["setpoint_rate_hz"] >= 19.5 and report["setpoint_gap_max_ms"] < 150
    assert up_bps < 0.5 * baud / 10     # the companion's traffic leaves half of even the slow line free
    if baud == 57600:   # ODOMETRY at 30 Hz alone does not fit half of 5760 B/s: mavsim drops, and counts
        assert truth["link"]["serial_budget_dropped"] > 0
