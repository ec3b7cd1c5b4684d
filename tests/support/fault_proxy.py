"""A UDP man-in-the-middle that injects link faults between a companion and its autopilot (tests only).

Topology: the vehicle side (mavsim, PX4 SITL, a router) sends to the proxy's ``listen``
port as if it were the companion; the proxy forwards each datagram to the companion's
``target`` address from a socket of its own, and sends the companion's answers back to
whoever last sent on the vehicle side. *Down* is vehicle -> companion, *up* is companion
-> vehicle.

Faults are :class:`Fault` rules, each with a direction, a time window (seconds since
:meth:`FaultProxy.start`), the MAVLink message names it applies to (None: all) and an
action: ``drop`` (with probability ``p``), ``cut`` (drop everything in the window),
``delay`` (``delay_s`` plus uniform ``jitter_s``), ``duplicate`` (with probability ``p``),
``reorder`` (hold a datagram and send it after the next one, with probability ``p``) and
``corrupt`` (flip one payload byte, with probability ``p``, so the CRC fails). Draws come
from one seeded generator in arrival order, so a schedule is repeatable for the same
traffic. Everything is bounded: at most :data:`MAX_HELD` datagrams wait (delayed or held
for reordering; beyond that they are dropped and counted) and the proxy binds loopback only.
"""

from __future__ import annotations

import heapq
import random
import select
import socket
import threading
import time
from collections import Counter
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink2

from mavsim.udp import packet_msgid

LOOPBACK = "127.0.0.1"
MAX_HELD = 4096               #: datagrams waiting (delayed or held back), at most
ACTIONS = frozenset({"drop", "cut", "delay", "duplicate", "reorder", "corrupt"})
DIRECTIONS = frozenset({"down", "up", "both"})


@dataclass(frozen=True)
class Fault:
    """One rule: ``action`` on datagrams going ``direction`` between ``start_s`` and ``end_s``.

    ``messages``: MAVLink message names it applies to (None: every datagram). ``p``: the
    probability per datagram (``cut`` ignores it). ``delay_s`` and ``jitter_s``: seconds.
    """

    action: str
    direction: str = "both"
    start_s: float = 0.0
    end_s: float = float("inf")
    messages: frozenset[str] | None = None
    p: float = 1.0
    delay_s: float = 0.0
    jitter_s: float = 0.0

    def __post_init__(self) -> None:
        if self.action not in ACTIONS:
            raise ValueError(f"fault action must be one of {sorted(ACTIONS)}, got {self.action!r}")
        if self.direction not in DIRECTIONS:
            raise ValueError(f"fault direction must be one of {sorted(DIRECTIONS)}, got {self.direction!r}")
        if not (0.0 <= self.p <= 1.0) or self.delay_s < 0.0 or self.jitter_s < 0.0 or self.end_s < self.start_s:
            raise ValueError(f"fault {self!r}: p in [0, 1], delays >= 0 s and end_s >= start_s")

    def applies(self, direction: str, t_s: float, name: str | None) -> bool:
        """Whether the rule acts on a datagram going ``direction`` at ``t_s`` carrying message ``name``."""
        return (self.direction in ("both", direction) and self.start_s <= t_s < self.end_s
                and (self.messages is None or name in self.messages))


def message_name(datagram: bytes) -> str | None:
    """The name of the first MAVLink message in ``datagram`` (v1 or v2 framing), or None."""
    msgid = packet_msgid(datagram)
    cls = None if msgid is None else mavlink2.mavlink_map.get(msgid)
    return None if cls is None else cls.msgname


def corrupted(datagram: bytes, rng: random.Random) -> bytes:
    """``datagram`` with one byte after the header flipped (its CRC no longer matches)."""
    if len(datagram) < 12:
        return bytes(b ^ 0xFF for b in datagram)
    i = rng.randrange(10, len(datagram))
    return datagram[:i] + bytes([datagram[i] ^ 0xFF]) + datagram[i + 1:]


class FaultProxy:
    """Forward UDP datagrams between ``listen`` (vehicle side) and ``target`` (the companion), with faults.

    Use as a context manager, or :meth:`start` and :meth:`stop`. ``stats`` counts, per
    ``(direction, what)``: ``forwarded``, ``dropped``, ``cut``, ``delayed``, ``duplicated``,
    ``reordered``, ``corrupted``, ``overflow``.
    """

    def __init__(self, listen_port: int, target_port: int, faults: list[Fault] = (), *, seed: int = 0) -> None:
        self.faults = list(faults)
        self.stats: Counter = Counter()
        self._rng = random.Random(seed)
        self._vehicle_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._vehicle_sock.bind((LOOPBACK, listen_port))
        self._companion_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._companion_sock.bind((LOOPBACK, 0))
        self._target = (LOOPBACK, target_port)
        self._vehicle_addr: tuple[str, int] | None = None
        self._held: list[tuple[float, int, str, bytes]] = []   # (due, order, direction, datagram)
        self._reorder: dict[str, bytes | None] = {"down": None, "up": None}
        self._order = 0
        self._t0 = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="fault-proxy", daemon=True)

    def __enter__(self) -> FaultProxy:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def start(self) -> None:
        """Start forwarding; fault windows count from now."""
        self._t0 = time.monotonic()
        self._thread.start()

    def stop(self) -> None:
        """Stop forwarding (within 0.1 s) and close both sockets."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        self._vehicle_sock.close()
        self._companion_sock.close()

    def elapsed_s(self) -> float:
        """Seconds since :meth:`start`."""
        return time.monotonic() - self._t0

    def _run(self) -> None:
        socks = [self._vehicle_sock, self._companion_sock]
        while not self._stop.is_set():
            now = time.monotonic()
            wait = 0.05 if not self._held else max(0.0, min(0.05, self._held[0][0] - now))
            readable, _, _ = select.select(socks, [], [], wait)
            for sock in readable:
                try:
                    datagram, addr = sock.recvfrom(65535)
                except OSError:
                    continue
                if sock is self._vehicle_sock:
                    self._vehicle_addr = addr
                    self._arrive("down", datagram)
                else:
                    self._arrive("up", datagram)
            now = time.monotonic()
            while self._held and self._held[0][0] <= now:
                _, _, direction, datagram = heapq.heappop(self._held)
                self._send(direction, datagram)

    def _arrive(self, direction: str, datagram: bytes) -> None:
        t_s = self.elapsed_s()
        name = message_name(datagram)
        copies, delay = [datagram], 0.0
        for fault in self.faults:
            if not fault.applies(direction, t_s, name):
                continue
            if fault.action == "cut":
                self.stats[direction, "cut"] += 1
                return
            if fault.action == "delay":
                delay += fault.delay_s + self._rng.uniform(0.0, fault.jitter_s)
                continue
            if self._rng.random() >= fault.p:
                continue
            if fault.action == "drop":
                self.stats[direction, "dropped"] += 1
                return
            if fault.action == "duplicate":
                copies.append(datagram)
                self.stats[direction, "duplicated"] += 1
            elif fault.action == "corrupt":
                copies = [corrupted(c, self._rng) for c in copies]
                self.stats[direction, "corrupted"] += 1
            elif fault.action == "reorder" and self._reorder[direction] is None:
                self._reorder[direction] = datagram      # goes out after the next one
                self.stats[direction, "reordered"] += 1
                return
        if delay > 0.0:
            self.stats[direction, "delayed"] += 1
        for copy in copies:
            self._hold(direction, copy, delay)
        held_back, self._reorder[direction] = self._reorder[direction], None
        if held_back is not None:
            self._hold(direction, held_back, delay)

    def _hold(self, direction: str, datagram: bytes, delay_s: float) -> None:
        if delay_s <= 0.0:
            self._send(direction, datagram)
            return
        if len(self._held) >= MAX_HELD:
            self.stats[direction, "overflow"] += 1
            return
        self._order += 1
        heapq.heappush(self._held, (time.monotonic() + delay_s, self._order, direction, datagram))

    def _send(self, direction: str, datagram: bytes) -> None:
        try:
            if direction == "down":
                self._companion_sock.sendto(datagram, self._target)
            elif self._vehicle_addr is not None:
                self._vehicle_sock.sendto(datagram, self._vehicle_addr)
            else:
                return
        except OSError:
            self.stats[direction, "send_failed"] += 1
            return
        self.stats[direction, "forwarded"] += 1
