"""``companion fly`` as systemd starts it (``Type=notify``, ``WatchdogSec``), against mavsim over loopback.

A datagram socket in the test stands where systemd's notify socket would be; fly gets its path in
``$NOTIFY_SOCKET`` and a 1 s watchdog in ``$WATCHDOG_USEC``, flies the antipodal encounter and
is stopped with SIGTERM 8 s in, as ``systemctl stop`` does. What systemd would hear: READY=1
once, before anything else; STATUS lines that follow the flight; a watchdog ping at least
every half period all the way through the hand-back; STOPPING=1 at the signal and again with
the outcome. About 15 s of wall time: marked realtime.
"""

from __future__ import annotations

import json
import shutil
import signal
import socket
import subprocess
import tempfile
import threading
import time
from pathlib import Path

import pytest

from tests.support.fly_udp import fly_beside_mavsim
from tests.support.ports import free_udp_port

pytestmark = pytest.mark.realtime

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "configs" / "antipodal.toml"
STOP_AFTER_S = 8.0
WATCHDOG_S = 1.0


class NotifyListener:
    """systemd's side of the notify socket: every datagram with the time it arrived (monotonic s)."""

    def __init__(self) -> None:
        self.dir = tempfile.mkdtemp(prefix="ntf")  # short: an AF_UNIX path has at most 107 bytes
        self.path = str(Path(self.dir) / "notify")
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(self.path)
        self.sock.settimeout(0.1)
        self.heard: list[tuple[float, str]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._listen, daemon=True)
        self._thread.start()

    def _listen(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.sock.recv(4096)
            except (TimeoutError, socket.timeout):
                continue
            self.heard.append((time.monotonic(), data.decode()))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self.sock.close()
        shutil.rmtree(self.dir, ignore_errors=True)


def test_that_fly_tells_systemd_ready_status_watchdog_and_stopping(tmp_path):
    listener = NotifyListener()
    signalled: list[float] = []

    def stop_it(fly: subprocess.Popen, _sim) -> None:
        time.sleep(STOP_AFTER_S)
        signalled.append(time.monotonic())
        fly.send_signal(signal.SIGTERM)

    port = free_udp_port()
    try:
        run = fly_beside_mavsim(SCENARIO, tmp_path, autopilot_port=port, duration_s=60, during=stop_it,
                                env={"NOTIFY_SOCKET": listener.path, "WATCHDOG_USEC": str(int(WATCHDOG_S * 1e6))})
    finally:
        listener.close()
    assert "Traceback" not in run.err, run.err[-3000:]
    assert run.returncode == 3, run.err[-3000:]
    report = json.loads(run.out)
    print(json.dumps({k: report.get(k) for k in ("outcome", "setpoint_rate_hz", "setpoint_gap_max_ms", "cpu_share_in_flight", "cpu_share", "max_rss_mb", "planner_process", "stream_fifo_priority")}))
    assert report["outcome"] == "stopped" and report["phase"] == "HELD"

    heard = listener.heard
    texts = [text for _, text in heard]
    # READY=1 first and once, saying what it waits for
    assert texts[0] == f"READY=1\nSTATUS=waiting for an autopilot on udpin:127.0.0.1:{port}", texts[:3]
    assert sum("READY=1" in t for t in texts) == 1
    # the status followed the flight: engaged and tracking the plan before the signal
    statuses = [t.removeprefix("STATUS=") for t in texts if t.startswith("STATUS=")]
    assert any(s.startswith("TRACKING: ") for s in statuses), statuses
    assert any("ENGAGED" in s for s in statuses), statuses
    # STOPPING=1 at the signal, then with the outcome and exit code, last of all
    stopping = [(t_s, text) for t_s, text in heard if text.startswith("STOPPING=1")]
    assert [text for _, text in stopping] == ["STOPPING=1\nSTATUS=SIGTERM: handing the vehicle back",
                                              "STOPPING=1\nSTATUS=stopped (exit 3)"]
    assert texts[-1] == stopping[-1][1]
    assert 0.0 <= stopping[0][0] - signalled[0] < 0.5
    # the watchdog: pinged every half period from READY until the run's end (hand-back included)
    pings = [t_s for t_s, text in heard if text == "WATCHDOG=1"]
    ready_s, end_s = heard[0][0], stopping[-1][0]
    assert pings and pings[0] - ready_s < 0.5 * WATCHDOG_S + 0.3
    intervals = [b - a for a, b in zip([ready_s, *pings], [*pings, end_s])]
    assert max(intervals) < 0.5 * WATCHDOG_S + 0.3, max(intervals)   # systemd would kill after 1 s
    assert len(pings) >= (end_s - ready_s) / (0.5 * WATCHDOG_S) - 2
