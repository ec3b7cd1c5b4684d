"""Real-time UDP endpoint, like PX4 SITL. Sockets and the wall clock live only here
(and in the CLI).

Wire layout (PX4 SITL defaults, all configurable)::

    API link (offboard, MAVSDK/pymavlink):  local 127.0.0.1:14580  ->  127.0.0.1:14540
    GCS link (QGroundControl):              local 127.0.0.1:18570  ->  127.0.0.1:14550

Each link is one UDP socket bound to its local port. Packets go unsolicited to the
target address; once a datagram arrives, the link answers the address it came from
(PX4 does the same), so ``udpin:127.0.0.1:14540`` and ``udpout:127.0.0.1:14580``
clients both work. Obstacles go where their ``transport`` puts them (the obstacle link,
``"obstacles"``, when the simulator has one: like a perception process sending to the
companion's obstacle port; ADSB re-streamed on the vehicle links; or the API link).

Simulated time runs ``speed`` times faster than the wall clock; the simulator is
advanced to ``elapsed_wall * speed`` every tick (about one physics step of wall
time, at least 2 ms) and, before they are handled, whenever datagrams arrive, so a
command acts and a TIMESYNC request is answered at the time it came in.
"""

from __future__ import annotations

import logging
import select
import socket
import threading
import time
from dataclasses import dataclass

from mavsim.core import OBSTACLE_LINK, Simulator
from mavsim.errors import SimulationError
from mavsim.tlog import TlogWriter

logger = logging.getLogger(__name__)

__all__ = ["LinkAddress", "UdpServer"]


@dataclass(frozen=True)
class LinkAddress:
    """One UDP link: local socket address and the default remote address."""

    name: str
    local_port: int
    remote_port: int
    bind_host: str = "127.0.0.1"
    remote_host: str = "127.0.0.1"


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
    links : list of LinkAddress
    speed : float
        Simulated seconds per wall second (> 0).
    tlog : path or None
        Record every packet sent and received on the API link (and sent on the obstacle link), stamped with the wall
        clock (microseconds since the Unix epoch).
    """

    def __init__(self, sim: Simulator, links: list[LinkAddress], speed: float = 1.0, tlog=None) -> None:
        if not speed > 0:
            raise SimulationError(f"speed must be > 0, got {speed}")
        if [l.name for l in links] != list(sim.links):
            raise SimulationError(f"link names {[l.name for l in links]} do not match the simulator's {sim.links}")
        self.sim = sim
        self.speed = float(speed)
        self.stop_event = threading.Event()
        self._tlog: TlogWriter | None = None
        self._links: dict[str, _Link] = {}
        try:
            for addr in links:
                self._links[addr.name] = _Link(addr)
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
        """Bound local port of each link (useful with port 0)."""
        return {name: link.local_port for name, link in self._links.items()}

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
        socks = {link.sock: name for name, link in self._links.items()}

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
            link.sock.close()
        self._links.clear()
        if self._tlog is not None:
            self._tlog.close()
            self._tlog = None

    def __enter__(self) -> "UdpServer":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
