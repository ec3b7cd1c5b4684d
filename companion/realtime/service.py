"""Running as a systemd service: readiness, status and the watchdog, and journald's log levels.

systemd's notify protocol (``sd_notify(3)``): a service started with ``Type=notify`` finds
the path of an ``AF_UNIX`` datagram socket in ``$NOTIFY_SOCKET`` (a leading ``@`` names an
abstract socket) and sends it newline-separated ``KEY=VALUE`` lines. ``fly`` says:

- ``READY=1`` once the link is open and the planning process is up, just before the setpoint
  stream starts (``systemctl start`` returns then; a start that hangs fails after
  ``TimeoutStartSec``);
- ``STATUS=...`` whenever the loop's mode or its newest event changes (``systemctl status``
  shows the line: "waiting for an autopilot", "OFFBOARD: ENGAGED ...", the outcome at the end);
- ``WATCHDOG=1`` from the setpoint stream's tick, at half of ``$WATCHDOG_USEC`` (the unit's
  ``WatchdogSec``): a stream that stops ticking for that long is killed by systemd
  (SIGABRT) and the service marked failed with result ``watchdog``;
- ``STOPPING=1`` when a stop is asked (SIGTERM from ``systemctl stop``, SIGINT) or the run ends.

Nothing here waits: the socket does not block, and a datagram that cannot be sent is
counted (:attr:`ServiceNotifier.failed`), never raised into the stream. Without
``$NOTIFY_SOCKET`` (a terminal, a test) every call does nothing. Times are the stream's
clock (s), passed in: this module reads no clock of its own.

journald: a service's stderr goes to the journal, where a line that starts with ``<N>``
(a syslog priority, 0-7) is stored at that priority (systemd's ``SyslogLevelPrefix=``,
on by default). :func:`stderr_is_journal` tells whether stderr is that stream (systemd
sets ``$JOURNAL_STREAM`` to its device and inode), and :class:`JournalPrefixFormatter` adds the
prefix to each log record, so ``journalctl -p warning -u companion`` shows warnings and errors only.
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Mapping

#: Python's logging levels to syslog priorities (``<N>`` in journald's stream).
_SYSLOG_PRIORITY = {logging.CRITICAL: 2, logging.ERROR: 3, logging.WARNING: 4, logging.INFO: 6, logging.DEBUG: 7}
#: Longest STATUS= text sent (characters); longer texts are cut with "...".
STATUS_MAX_CHARS = 200


class ServiceNotifier:
    """``sd_notify`` for one process: readiness, status lines, watchdog pings, stopping.

    Parameters
    ----------
    address : the notify socket's path (``@name`` for an abstract socket); None disables every call.
    watchdog_s : the watchdog's period (s, from ``$WATCHDOG_USEC``); None: no watchdog pings.
    """

    def __init__(self, address: str | None, watchdog_s: float | None = None) -> None:
        self.address = address
        self.watchdog_s = watchdog_s
        self.sent = 0
        self.failed = 0
        self.watchdog_pings = 0
        self._status: str | None = None
        self._last_ping_s: float | None = None
        self._socket: socket.socket | None = None
        if address is not None:
            self._socket = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            self._socket.setblocking(False)
            self._target = "\0" + address[1:] if address.startswith("@") else address

    @classmethod
    def from_environment(cls, environ: Mapping[str, str] | None = None, pid: int | None = None) -> "ServiceNotifier":
        """The notifier systemd asked for through the environment (a disabled one outside systemd).

        ``$WATCHDOG_USEC`` is the watchdog's period in microseconds; if ``$WATCHDOG_PID`` is set
        and is not this process (``pid``), the watchdog is another process's and is left alone.
        """
        environ = os.environ if environ is None else environ
        pid = os.getpid() if pid is None else pid
        address = environ.get("NOTIFY_SOCKET") or None
        watchdog_s = None
        usec = environ.get("WATCHDOG_USEC", "")
        if usec.isdigit() and int(usec) > 0 and environ.get("WATCHDOG_PID", str(pid)) == str(pid):
            watchdog_s = int(usec) * 1e-6
        return cls(address, watchdog_s)

    @property
    def enabled(self) -> bool:
        return self._socket is not None

    def notify(self, *assignments: str) -> bool:
        """Send ``KEY=VALUE`` lines in one datagram; False (counted) if it could not be sent."""
        if self._socket is None:
            return False
        try:
            self._socket.sendto("\n".join(assignments).encode("utf-8", "replace"), self._target)
        except OSError:
            self.failed += 1
            return False
        self.sent += 1
        return True

    def ready(self, status: str) -> None:
        """The service is up: ``READY=1`` with its first status line."""
        self._status = _short(status)
        self.notify("READY=1", f"STATUS={self._status}")

    def status(self, text: str) -> None:
        """``STATUS=text`` if it differs from the last one sent."""
        text = _short(text)
        if text != self._status:
            self._status = text
            self.notify(f"STATUS={text}")

    def watchdog(self, t_s: float) -> None:
        """``WATCHDOG=1`` if half the watchdog's period has passed since the last ping (``t_s``: the stream's clock, s)."""
        if self.watchdog_s is None or self._socket is None:
            return
        if self._last_ping_s is None or t_s - self._last_ping_s >= 0.5 * self.watchdog_s or t_s < self._last_ping_s:
            self._last_ping_s = t_s
            if self.notify("WATCHDOG=1"):
                self.watchdog_pings += 1

    def stopping(self, status: str) -> None:
        """The service is ending: ``STOPPING=1`` with why."""
        self._status = _short(status)
        self.notify("STOPPING=1", f"STATUS={self._status}")

    def after_tick(self, companion, t_s: float, outbox) -> None:
        """The stream's per-tick hook: a watchdog ping, and the loop's mode and newest event as status."""
        self.watchdog(t_s)
        events = companion.state.events
        mode = companion.state.mode
        mode_name = getattr(mode, "name", str(mode))
        self.status(f"{mode_name}: {events[-1][1]}" if events else mode_name)

    def close(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None


def _short(text: str) -> str:
    text = " ".join(str(text).split())  # one line: a newline would start a new assignment
    return text if len(text) <= STATUS_MAX_CHARS else text[: STATUS_MAX_CHARS - 3] + "..."


def stderr_is_journal(environ: Mapping[str, str] | None = None, fd: int = 2) -> bool:
    """Whether ``fd`` is the journal stream systemd connected (``$JOURNAL_STREAM`` = ``device:inode``)."""
    environ = os.environ if environ is None else environ
    value = environ.get("JOURNAL_STREAM", "")
    device, _, inode = value.partition(":")
    if not (device.isdigit() and inode.isdigit()):
        return False
    try:
        st = os.fstat(fd)
    except OSError:
        return False
    return (st.st_dev, st.st_ino) == (int(device), int(inode))


class JournalPrefixFormatter(logging.Formatter):
    """A formatter that starts each record with its syslog priority, ``<N>`` (journald stores it at N)."""

    def format(self, record: logging.LogRecord) -> str:
        priority = _SYSLOG_PRIORITY.get(record.levelno)
        if priority is None:  # a custom level: the nearest standard one below it
            priority = next((p for lvl, p in sorted(_SYSLOG_PRIORITY.items(), reverse=True) if record.levelno >= lvl), 7)
        return f"<{priority}>" + super().format(record)
