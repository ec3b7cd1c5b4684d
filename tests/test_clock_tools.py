"""The tools that reproduce and measure the vehicle clock's lag: ``tests.support.clock_age`` and ``cpu_steal``."""

from __future__ import annotations

import struct
import subprocess
import sys

from pymavlink.dialects.v20 import common as mavlink2

from tests.support import clock_age

EPOCH = 1_764_633_600.0


def _tlog(path, rate: float, seconds: float = 12.0) -> None:
    """ODOMETRY from component 1 every 32 ms of a clock running at ``rate`` of link time, arriving 1 ms after."""
    autopilot = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    with open(path, "wb") as f:
        t_v = 100.0
        while t_v < 100.0 + seconds * rate:
            t_rx = EPOCH + (t_v - 100.0) / rate + 1e-3
            msg = mavlink2.MAVLink_odometry_message(int(t_v * 1e6), 1, 1, 0.0, 0.0, -5.0, [1, 0, 0, 0], 0.0, 0.0, 0.0,
                                                    0.0, 0.0, 0.0, [float("nan")] * 21, [float("nan")] * 21, 0, 0, 0)
            f.write(struct.pack(">Q", int(round(t_rx * 1e6))) + bytes(msg.pack(autopilot)))
            t_v += 0.032


def test_that_clock_age_measures_the_rate_and_a_lag_within_the_window(tmp_path, capsys):
    _tlog(tmp_path / "slow.tlog", rate=0.8)
    assert clock_age.main([str(tmp_path / "slow.tlog")]) == 0
    line = capsys.readouterr().out
    assert "clock rate 0.8000" in line, line
    excess = clock_age.age_excess_ms(clock_age.events(str(tmp_path / "slow.tlog")), clock_age.VehicleClock())
    # 20 % slow: the bound over the 0.5 s window lags by up to 0.2 * 0.5 s, plus the 1 ms latency
    assert 50.0 < excess.max() <= 101.5, excess.max()


def test_that_clock_age_refuses_a_log_without_poses(tmp_path, capsys):
    (tmp_path / "empty.tlog").write_bytes(b"")
    assert clock_age.main([str(tmp_path / "empty.tlog")]) == 2
    assert "fewer than two ODOMETRY" in capsys.readouterr().err


def test_that_cpu_steal_wants_a_command_and_sane_bursts():
    for args in ([], ["--burst-ms", "5000", "--", "true"], ["--period-s", "0", "--", "true"]):
        run = subprocess.run([sys.executable, "-m", "tests.support.cpu_steal", *args], capture_output=True, text=True,
                             timeout=60)
        assert run.returncode == 2 and "give a command" in run.stderr, (args, run.stderr)
