"""systemd's notify protocol and journald's priorities (companion.realtime.service), on a real
AF_UNIX datagram socket standing in for systemd's."""

from __future__ import annotations

import logging
import os
import socket
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from companion.loop.records import LoopMode
from companion.realtime.service import STATUS_MAX_CHARS, JournalPrefixFormatter, ServiceNotifier, stderr_is_journal


@pytest.fixture
def notify_socket(tmp_path):
    """A datagram socket where systemd's would be: (its path, a function returning every datagram so far)."""
    path = str(tmp_path / "notify")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.setblocking(False)

    def received() -> list[str]:
        out = []
        while True:
            try:
                out.append(sock.recv(4096).decode())
            except BlockingIOError:
                return out

    yield path, received
    sock.close()


def test_that_outside_systemd_nothing_is_sent_and_nothing_fails():
    notifier = ServiceNotifier.from_environment({}, pid=10)
    assert not notifier.enabled and notifier.watchdog_s is None
    notifier.ready("up")
    notifier.watchdog(1.0)
    notifier.stopping("down")
    assert (notifier.sent, notifier.failed) == (0, 0)


def test_that_ready_status_and_stopping_reach_the_socket(notify_socket):
    path, received = notify_socket
    notifier = ServiceNotifier.from_environment({"NOTIFY_SOCKET": path}, pid=10)
    notifier.ready("waiting for an autopilot on udpin:127.0.0.1:14540")
    notifier.status("OFFBOARD: ENGAGED")
    notifier.status("OFFBOARD: ENGAGED")     # unchanged: not sent again
    notifier.status("line one\nline two")    # a newline would start a new assignment
    notifier.stopping("SIGTERM: handing the vehicle back")
    assert received() == [
        "READY=1\nSTATUS=waiting for an autopilot on udpin:127.0.0.1:14540",
        "STATUS=OFFBOARD: ENGAGED",
        "STATUS=line one line two",
        "STOPPING=1\nSTATUS=SIGTERM: handing the vehicle back",
    ]
    notifier.status("x" * 1000)
    (long,) = received()
    assert len(long) == len("STATUS=") + STATUS_MAX_CHARS and long.endswith("...")


def test_that_the_watchdog_is_pinged_at_half_its_period_on_the_streams_clock(notify_socket):
    path, received = notify_socket
    notifier = ServiceNotifier.from_environment({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "2000000",
                                                 "WATCHDOG_PID": "10"}, pid=10)
    assert notifier.watchdog_s == pytest.approx(2.0)
    for i in range(101):  # 5 s of ticks at 20 Hz
        notifier.watchdog(100.0 + 0.05 * i)
    pings = received()
    assert pings == ["WATCHDOG=1"] * 6 and notifier.watchdog_pings == 6  # at 0, 1, 2, 3, 4, 5 s
    notifier.watchdog(50.0)  # the clock stepped back: ping at once rather than wait for 100.9 s
    assert received() == ["WATCHDOG=1"]


def test_that_another_processs_watchdog_is_left_alone():
    env = {"NOTIFY_SOCKET": "/nonexistent", "WATCHDOG_USEC": "2000000", "WATCHDOG_PID": "11"}
    assert ServiceNotifier.from_environment(env, pid=10).watchdog_s is None
    assert ServiceNotifier.from_environment({**env, "WATCHDOG_USEC": "junk", "WATCHDOG_PID": "10"}, pid=10).watchdog_s is None


def test_that_a_missing_socket_is_counted_never_raised(tmp_path):
    notifier = ServiceNotifier(str(tmp_path / "gone"), watchdog_s=1.0)
    notifier.ready("up")
    notifier.watchdog(0.0)
    assert (notifier.sent, notifier.failed, notifier.watchdog_pings) == (0, 2, 0)


def test_that_an_abstract_socket_is_addressed_by_its_at_sign():
    name = f"ogccmpc-test-{os.getpid()}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    sock.settimeout(2.0)
    try:
        ServiceNotifier(f"@{name}").ready("up")
        assert sock.recv(4096) == b"READY=1\nSTATUS=up"
    finally:
        sock.close()


def test_that_the_tick_hook_pings_and_reports_the_mode_and_newest_event(notify_socket):
    path, received = notify_socket
    notifier = ServiceNotifier(path, watchdog_s=1.0)
    state = SimpleNamespace(mode=LoopMode.WAITING, events=[])
    companion = SimpleNamespace(state=state)
    notifier.after_tick(companion, 10.0, [])
    state.mode = LoopMode.TRACKING
    state.events.append((10.1, "ENGAGED: OFFBOARD confirmed"))
    notifier.after_tick(companion, 10.1, [])
    notifier.after_tick(companion, 10.2, [])   # nothing new, and within half the watchdog's period
    assert received() == ["WATCHDOG=1", "STATUS=WAITING", "STATUS=TRACKING: ENGAGED: OFFBOARD confirmed"]


def test_that_journald_is_recognised_by_the_device_and_inode_of_stderr(tmp_path):
    with open(tmp_path / "stream", "w") as f:
        st = os.fstat(f.fileno())
        assert stderr_is_journal({"JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino}"}, fd=f.fileno())
        assert not stderr_is_journal({"JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino + 1}"}, fd=f.fileno())
        assert not stderr_is_journal({}, fd=f.fileno())
        assert not stderr_is_journal({"JOURNAL_STREAM": "junk"}, fd=f.fileno())


def test_that_each_log_record_carries_its_syslog_priority():
    formatter = JournalPrefixFormatter("%(levelname)s %(name)s: %(message)s")

    def line(level: int) -> str:
        return formatter.format(logging.LogRecord("companion.x", level, __file__, 1, "msg", None, None))

    assert line(logging.ERROR) == "<3>ERROR companion.x: msg"
    assert line(logging.WARNING) == "<4>WARNING companion.x: msg"
    assert line(logging.INFO).startswith("<6>") and line(logging.DEBUG).startswith("<7>")
    assert line(logging.WARNING + 5).startswith("<4>")  # a custom level: the standard one below it


def test_that_under_journald_an_error_line_of_fly_carries_priority_3(tmp_path):
    """``$JOURNAL_STREAM`` naming stderr (as systemd sets it): the one-line error starts with ``<3>``."""
    url = "udpin:127.0.0.1:14540"
    scenario = Path(__file__).resolve().parents[2] / "configs" / "antipodal.toml"
    command = [sys.executable, "-m", "companion.cli", "fly", "--connect", url, "--fleet", url, "--scenario", str(scenario)]
    with open(tmp_path / "stderr", "w+") as err:
        st = os.fstat(err.fileno())
        env = {**os.environ, "JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino}"}
        done = subprocess.run(command, stdout=subprocess.DEVNULL, stderr=err, env=env, timeout=60)
        err.seek(0)
        lines = err.read().splitlines()
    assert done.returncode == 2
    assert len(lines) == 1 and lines[0].startswith(f"<3>companion fly: error: --fleet {url}: that is the autopilot's link"), lines
    plain = subprocess.run(command, capture_output=True, text=True, timeout=60)  # not the journal: no prefix
    assert plain.returncode == 2 and plain.stderr.startswith("companion fly: error: --fleet"), plain.stderr
