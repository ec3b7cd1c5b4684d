"""Real-time UDP (and serial) endpoint, like PX4 SITL. Sockets, serial devices and the wall
clock live only here (and in the CLI).

Wire layout (PX4 SITL defaults, all configurable)::

    API link (offboard, MAVSDK/pymavlink):  local 127.0.0.1:14580  ->  127.0.0.1:14540
    GCS link (QGroundControl):              local 127.0.0.1:18570  ->  127.0.0.1:14550

Each link is one UDP socket bound to its local port. Packets go unsolicited to the
target address; once a datagram arrives, the link answers the address it came from
(PX4 does the same), so ``udpin:127.0.0.1:14540`` and ``udpout:127.0.0.1:14580``
clients both work. Obstacles go where their ``transport`` puts them (the obstacle link,
``"obstacles"``, when the simulator has one: like a perception process sending to the
companion's obstacle port; ADSB re-streamed on the vehicle links; or the API link).

The API link can instead be a serial device (:class:`SerialAddress`: ``mavsim --serial
DEVICE --baud N``), as PX4 on TELEM2: a byte stream, parsed as such. A serial link has a
byte budget, half the line's rate by default (8N1: ``baud / 20`` bytes a second, PX4's
``MAV_x_RATE`` = 0): what would exceed it is not sent, a whole packet at a time, and
counted (``serial_budget_dropped`` in the summary's link counts), except HEARTBEAT,
COMMAND_ACK and STATUSTEXT, which always go (:data:`ESSENTIAL_MSG_IDS`). PX4 lowers its stream
rates to fit instead; either way the companion sees fewer reports a second.

Simulated time runs ``speed`` times faster than the wall clock; the simulator is
advanced to ``elapsed_wall * speed`` every tick (about one physics step of wall
time, at least 2 ms) and, before they are handled, whenever datagrams arrive, so a
command acts and a TIMESYNC request is answered at the time it came in.
"""

from __future__ import annotations

import logging
import os
import select
import socket
import threading
import time
from dataclasses import dataclass

from mavsim.core import OBSTACLE_LINK, Simulator
from mavsim.errors import SimulationError
from mavsim.tlog import TlogWriter

logger = logging.getLogger(__name__)

__all__ = ["LinkAddress", "SerialAddress", "UdpServer"]


@dataclass(frozen=True)
class LinkAddress:
    """One UDP link: local socket address and the default remote address."""

    name: str
    local_port: int
    remote_port: int
    bind_host: str = "127.0.0.1"
    remote_host: str = "127.0.0.1"


@dataclass(frozen=True)
class SerialAddress:
    """One serial link: a device path (``/dev/ttyUSB0``, a pty) at ``baud`` (8N1).

    ``budget_share``: the share of the line's byte rate mavsim may send, (0, 1].
    """

    name: str
    device: str
    baud: int = 57600
    budget_share: float = 0.5


#: Messages a link over budget still sends (HEARTBEAT, COMMAND_ACK, STATUSTEXT): PX4 lowers its
#: streams' rates, it never stops its HEARTBEAT or leaves a command unanswered.
ESSENTIAL_MSG_IDS = frozenset({0, 77, 253})


def packet_msgid(packet: bytes) -> int | None:
    """The message id of the MAVLink packet (v1 or v2 framing) that ``packet`` starts with, or None."""
    if len(packet) >= 10 and packet[0] == 0xFD:
        return packet[7] | packet[8] << 8 | packet[9] << 16
    if len(packet) >= 6 and packet[0] == 0xFE:
        return packet[5]
    return None


def _essential(packet: bytes) -> bool:
    """Whether a MAVLink packet (v1 or v2) carries one of :data:`ESSENTIAL_MSG_IDS`."""
    return packet_msgid(packet) in ESSENTIAL_MSG_IDS


class _SerialLink:
    """A serial device opened raw, non-blocking, with a token bucket of ``baud / 10 * budget_share`` bytes/s."""

    def __init__(self, addr: SerialAddress, stats: dict) -> None:
        import termios
        import tty

        if not (addr.baud > 0 and 0.0 < addr.budget_share <= 1.0):
            raise SimulationError(f"{addr.name} link: baud must be > 0 and budget_share in (0, 1], got {addr!r}")
        self.addr = addr
        try:
            self.fd = os.open(addr.device, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        except OSError as exc:
            raise SimulationError(f"{addr.name} link: cannot open serial device {addr.device}: {exc}") from None
        try:
            tty.setraw(self.fd)
            speed = getattr(termios, f"B{addr.baud}", None)
            if speed is not None:
                attrs = termios.tcgetattr(self.fd)
                attrs[4] = attrs[5] = speed
                termios.tcsetattr(self.fd, termios.TCSANOW, attrs)
        except termios.error:
            pass  # not a terminal (a FIFO in a test): bytes still flow
        self.rate_bps = addr.baud / 10.0 * addr.budget_share
        self._tokens = self.rate_bps * 0.1           # at most 0.1 s of burst
        self._last = time.monotonic()
        self.stats = stats
        self.local_port = None

    def fileno(self) -> int:
        return self.fd

    def send(self, data: bytes) -> None:
        now = time.monotonic()
        self._tokens = min(self.rate_bps * 0.1, self._tokens + (now - self._last) * self.rate_bps)
        self._last = now
        if len(data) > self._tokens and not _essential(data):
            self.stats["serial_budget_dropped"] = self.stats.get("serial_budget_dropped", 0) + 1
            return
        self._tokens -= len(data)          # an essential packet over budget is paid for by the next ones
        try:
            os.write(self.fd, data)
        except (BlockingIOError, OSError) as exc:    # the device's buffer is full: the line loses it
            self.stats["serial_write_failed"] = self.stats.get("serial_write_failed", 0) + 1
            logger.debug("%s: write failed: %s", self.addr.name, exc)

    def read(self) -> bytes:
        try:
            return os.read(self.fd, 65536)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError as exc:
            logger.debug("%s: read error: %s", self.addr.name, exc)
            return b""

    def close(self) -> None:
        try:
            os.close(self.fd)
        except OSError:
            pass


class _Link:
    def __init__(self, addr: LinkAddress) -> None:
        self.addr = addr
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind((addr.bind_host, addr.local_port))
        except OSError as exc:
            self.sock.close()
            raise SimulationError(f"{addr.name} link: cannot bind {addr.bind_host}:{addr.local_port}: {exc}") from None
        self.sock.setblocking(False)
        self.remote = (addr.remote_host, addr.remote_port)
        self.local_port = self.sock.getsockname()[1]

    def send(self, data: bytes) -> None:
        try:
            self.sock.sendto(data, self.remote)
        except OSError as exc:  # nobody listening yet (ICMP unreachable), buffer full...
            logger.debug("%s: send failed: %s", self.addr.name, exc)


class UdpServer:
    """Runs a :class:`~mavsim.core.Simulator` against UDP sockets in (scaled) real time.

    Parameters
    ----------
    sim : Simulator
        Built with ``links`` named like ``links`` here (first is the API link).
    links : list of LinkAddress or SerialAddress
    speed : float
        Simulated seconds per wall second (> 0).
    tlog : path or None
        Record every packet sent and received on the API link (and sent on the obstacle link), stamped with the wall
        clock (microseconds since the Unix epoch).
    """

    def __init__(self, sim: Simulator, links: list[LinkAddress | SerialAddress], speed: float = 1.0, tlog=None) -> None:
        if not speed > 0:
            raise SimulationError(f"speed must be > 0, got {speed}")
        if [l.name for l in links] != list(sim.links):
            raise SimulationError(f"link names {[l.name for l in links]} do not match the simulator's {sim.links}")
        self.sim = sim
        self.speed = float(speed)
        self.stop_event = threading.Event()
        self._tlog: TlogWriter | None = None
        self._links: dict[str, _Link | _SerialLink] = {}
        try:
            for addr in links:
                self._links[addr.name] = (_SerialLink(addr, sim.stats) if isinstance(addr, SerialAddress)
                                          else _Link(addr))
        except SimulationError:
            self.close()
            raise
        self._api = links[0].name
        self._tlog = TlogWriter(tlog) if tlog is not None else None
        if self._tlog is not None:
            sim.taps.append(self._tap)
        self._tick_s = max(0.002, sim.step_us * 1e-6 / self.speed)

    @property
    def local_ports(self) -> dict[str, int]:
        """Bound local port of each UDP link (useful with port 0)."""
        return {name: link.local_port for name, link in self._links.items() if isinstance(link, _Link)}

    def _tap(self, direction: str, link: str, t_us: int, data: bytes) -> None:
        if direction == "in" and link == self._api and self._tlog is not None:
            self._tlog.write(time.time_ns() // 1000, data)

    def _send(self, packets) -> None:
        for _, name, data in packets:
            self._links[name].send(data)
            if name in (self._api, OBSTACLE_LINK) and self._tlog is not None:
                self._tlog.write(time.time_ns() // 1000, data)

    def run(self, duration_s: float | None = None) -> None:
        """Serve until ``duration_s`` simulated seconds have passed or :meth:`stop`."""
        end_us = None if duration_s is None else self.sim.now_us + round(duration_s * 1e6)
        t0 = time.monotonic()
        sim0 = self.sim.now_us
        self._send(self.sim.drain())
        socks = {(link.sock if isinstance(link, _Link) else link): name for name, link in self._links.items()}

        def catch_up() -> None:
            """Advance the simulation to the wall clock (times ``speed``), never past ``end_us``."""
            target = sim0 + round((time.monotonic() - t0) * self.speed * 1e6)
            if end_us is not None:
                target = min(target, end_us)
            if target > self.sim.now_us:
                self._send(self.sim.advance_to(target))

        while not self.stop_event.is_set():
            catch_up()
            if end_us is not None and self.sim.now_us >= end_us:
                break
            readable, _, _ = select.select(list(socks), [], [], self._tick_s)
            if readable:  # handle what arrived at the time it arrived (a TIMESYNC answer carries it)
                catch_up()
            for sock in readable:
                name = socks[sock]
                if isinstance(sock, _SerialLink):   # a byte stream: parsed across reads
                    data = sock.read()
                    if data:
                        self.sim.receive(data, name, datagram=False)
                    continue
                for _ in range(64):  # drain what is queued, bounded
                    try:
                        data, src = sock.recvfrom(65535)
                    except (BlockingIOError, InterruptedError):
                        break
                    except OSError as exc:  # e.g. ICMP port unreachable reported on Linux
                        logger.debug("%s: recv error: %s", name, exc)
                        break
                    self._links[name].remote = src  # answer whoever talks to us, as PX4 does
                    self.sim.receive(data, name, datagram=True)  # each datagram parsed on its own
            self._send(self.sim.drain())
        if self._tlog is not None:
            self._tlog.flush()

    def stop(self) -> None:
        """Ask :meth:`run` to return (thread-safe)."""
        self.stop_event.set()

    def close(self) -> None:
        """Close the sockets and the tlog."""
        for link in self._links.values():
            if isinstance(link, _Link):
                link.sock.close()
            else:
                link.close()
        self._links.clear()
        if self._tlog is not None:
            self._tlog.close()
            self._tlog = None

    def __enter__(self) -> "UdpServer":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
