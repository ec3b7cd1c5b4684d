"""A null-modem serial cable between two pseudo-terminals, at a real link's byte rate (tests only).

Each end is a pty whose path (``/dev/pts/N``) a program opens as its serial device, as it
would ``/dev/ttyUSB0``. Between the two masters, a relay thread moves bytes at the line's
rate: 10 bits a byte (8N1), so ``baud / 10`` bytes per second in each direction, as a
UART or a telemetry radio's air link does (a pty alone passes bytes at memory speed,
whatever baud rate is set on it). What a sender writes faster than that waits in the
direction's buffer, up to ``buffer_bytes`` (a radio's or a UART's FIFO); beyond it, bytes
are lost, counted in :attr:`SerialCable.dropped`. ``sent`` counts the bytes delivered.
Nothing here needs root or a package beyond the standard library.
"""

from __future__ import annotations

import os
import select
import termios
import threading
import time
import tty
from collections import deque

DEFAULT_BUFFER_BYTES = 4096


class SerialCable:
    """Two pty ends (:attr:`a`, :attr:`b`: device paths) joined at ``baud`` (8N1)."""

    def __init__(self, baud: int, *, buffer_bytes: int = DEFAULT_BUFFER_BYTES) -> None:
        if not baud > 0:
            raise ValueError(f"baud must be > 0, got {baud!r}")
        self.baud = int(baud)
        self.bytes_per_s = self.baud / 10.0
        self.buffer_bytes = int(buffer_bytes)
        self._masters: list[int] = []
        self._slaves: list[int] = []
        paths = []
        for _ in range(2):
            master, slave = os.openpty()
            tty.setraw(slave)                       # no echo, no line discipline: bytes in, bytes out
            attrs = termios.tcgetattr(slave)
            termios.tcsetattr(slave, termios.TCSANOW, attrs)
            os.set_blocking(master, False)
            self._masters.append(master)
            self._slaves.append(slave)               # kept open so the pty survives its user closing it
            paths.append(os.ttyname(slave))
        self.a, self.b = paths
        self.sent = {"a->b": 0, "b->a": 0}
        self.dropped = {"a->b": 0, "b->a": 0}
        self._queues = {"a->b": deque(), "b->a": deque()}
        self._queued = {"a->b": 0, "b->a": 0}
        self._credit = {"a->b": 0.0, "b->a": 0.0}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="serial-cable", daemon=True)
        self._thread.start()

    def __enter__(self) -> SerialCable:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Stop the relay (within 0.1 s) and close both ptys."""
        self._stop.set()
        self._thread.join(timeout=2.0)
        for fd in (*self._masters, *self._slaves):
            try:
                os.close(fd)
            except OSError:
                pass

    def _run(self) -> None:
        directions = {self._masters[0]: "a->b", self._masters[1]: "b->a"}
        outlet = {"a->b": self._masters[1], "b->a": self._masters[0]}
        last = time.monotonic()
        while not self._stop.is_set():
            readable, _, _ = select.select(list(directions), [], [], 0.002)
            for fd in readable:
                direction = directions[fd]
                try:
                    data = os.read(fd, 65536)
                except (BlockingIOError, OSError):
                    continue
                room = self.buffer_bytes - self._queued[direction]
                if len(data) > room:
                    self.dropped[direction] += len(data) - max(room, 0)
                    data = data[:max(room, 0)]
                if data:
                    self._queues[direction].append(data)
                    self._queued[direction] += len(data)
            now = time.monotonic()
            elapsed, last = now - last, now
            for direction, queue in self._queues.items():
                if not queue:
                    self._credit[direction] = 0.0            # an idle line saves no credit
                    continue
                self._credit[direction] += elapsed * self.bytes_per_s
                n = int(self._credit[direction])
                chunk = bytearray()
                while queue and len(chunk) < n:
                    head = queue[0]
                    take = head[: n - len(chunk)]
                    chunk += take
                    if len(take) == len(head):
                        queue.popleft()
                    else:
                        queue[0] = head[len(take):]
                if chunk:
                    try:
                        written = os.write(outlet[direction], bytes(chunk))
                    except (BlockingIOError, OSError):
                        written = 0
                    if written < len(chunk):                 # the reader is not reading: the line loses them
                        self.dropped[direction] += len(chunk) - written
                    self._credit[direction] -= len(chunk)
                    self._queued[direction] -= len(chunk)
                    self.sent[direction] += written
