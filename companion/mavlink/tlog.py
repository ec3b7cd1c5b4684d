"""MAVLink telemetry logs (tlog) in the format pymavlink's ``mavutil`` reads and MAVProxy writes.

A tlog has no header. Each record is an 8-byte big-endian unsigned integer of
microseconds since the Unix epoch, followed by one raw MAVLink packet exactly as
on the wire (MAVLink 1 or 2, signed or not). MAVProxy stores the link number in
the low 2 bits of the stamp; readers ignore it (0.3 microseconds at most).

Writing is plain file I/O (no clock: the caller passes the time of each record).
In lockstep runs the harness passes :data:`LOCKSTEP_EPOCH_S` plus simulated
time, so the same seed writes a byte-identical log. Reading goes through
pymavlink itself, so whatever ``mavutil`` reads, :func:`read_tlog` reads.
"""

from __future__ import annotations

import logging
import math
import os
import struct
from collections.abc import Iterator
from pathlib import Path
from types import TracebackType

from companion.errors import CompanionError

logger = logging.getLogger(__name__)

#: Fixed epoch (2024-01-01T00:00:00Z, seconds since the Unix epoch) added to
#: simulated time when a lockstep run records a tlog, for reproducible logs.
LOCKSTEP_EPOCH_S = 1_704_067_200.0

_STAMP = struct.Struct(">Q")
_MAGICS = (0xFE, 0xFD)
_MIN_PACKET = 8  # MAVLink 1 header (6) + CRC (2), empty payload


class TlogError(CompanionError, ValueError):
    """A tlog could not be read: missing, empty, or not a tlog (the message names the file)."""


class TlogWriter:
    """Append records to a tlog, flushing often enough that a killed process loses little.

    Parameters
    ----------
    path : str or Path
        File to create (truncated if it exists).
    flush_period_s : float
        The file is flushed (and ``os.fsync``-free ``flush`` called) whenever
        this much log time has passed since the last flush, and on close.

    Examples
    --------
    >>> with TlogWriter("flight.tlog") as log:          # doctest: +SKIP
    ...     log.write(time.time(), packet_bytes)
    """

    def __init__(self, path: str | os.PathLike, flush_period_s: float = 0.2) -> None:
        if not (math.isfinite(flush_period_s) and flush_period_s >= 0.0):
            raise TlogError(f"flush_period_s must be finite and >= 0, got {flush_period_s!r}")
        self.path = Path(path)
        self.flush_period_s = float(flush_period_s)
        self._file = open(self.path, "wb")  # noqa: SIM115 (closed in close())
        self._last_flush_s: float | None = None
        self.records = 0

    def write(self, t_s: float, packet: bytes) -> None:
        """Write one record: ``t_s`` seconds since the Unix epoch, then the packet bytes.

        Raises
        ------
        TlogError
            If the writer is closed or ``t_s`` is not a finite non-negative time.
        """
        if self._file.closed:
            raise TlogError(f"tlog {self.path} is closed")
        if not (math.isfinite(t_s) and t_s >= 0.0):
            raise TlogError(f"tlog {self.path}: record time must be finite seconds since the epoch, got {t_s!r}")
        self._file.write(_STAMP.pack(int(round(t_s * 1e6))) + bytes(packet))
        self.records += 1
        if self._last_flush_s is None:
            self._last_flush_s = t_s
        elif t_s - self._last_flush_s >= self.flush_period_s:
            self.flush()
            self._last_flush_s = t_s

    def flush(self) -> None:
        """Push buffered records to the operating system."""
        if not self._file.closed:
            self._file.flush()

    def close(self) -> None:
        """Flush and close; further writes raise :class:`TlogError`. Idempotent."""
        if not self._file.closed:
            self._file.flush()
            self._file.close()

    @property
    def closed(self) -> bool:
        return self._file.closed

    def __enter__(self) -> "TlogWriter":
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def _check_tlog(path: Path) -> None:
    """Raise :class:`TlogError` unless ``path`` looks like a tlog (first record well formed)."""
    if not path.exists():
        raise TlogError(f"tlog {path} does not exist")
    if not path.is_file():
        raise TlogError(f"tlog {path} is not a file")
    size = path.stat().st_size
    if size == 0:
        raise TlogError(f"tlog {path} is empty")
    with open(path, "rb") as f:
        head = f.read(_STAMP.size + 1)
    if len(head) < _STAMP.size + 1 or head[_STAMP.size] not in _MAGICS:
        raise TlogError(
            f"{path} is not a tlog: expected an 8-byte timestamp then a MAVLink packet "
            f"(0xFE or 0xFD), found {head[:16].hex()}"
        )


def read_tlog(path: str | os.PathLike, *, include_bad: bool = False) -> Iterator[tuple[float, object]]:
    """Iterate over ``(t_s, msg)`` of a tlog, read with pymavlink's own tlog reader (``mavutil.mavlogfile``).

    Parameters
    ----------
    path : str or Path
        The tlog.
    include_bad : bool
        Also yield pymavlink's ``BAD_DATA`` pseudo messages (corrupt bytes).

    Yields
    ------
    t_s : float
        Record time, seconds since the Unix epoch (``msg._timestamp``).
    msg : pymavlink message
        Parsed message; ``msg.get_msgbuf()`` gives the packet bytes.
        Signed MAVLink 2 packets are read (the signature is not checked).

    Raises
    ------
    TlogError
        Missing file, empty file, a file that is not a tlog, or a log holding
        no valid MAVLink message. A truncated final record is tolerated
        (logged, skipped).
    """
    from pymavlink import mavutil

    path = Path(path)
    _check_tlog(path)
    try:
        # mavutil.mavlink_connection(path) would pick mavmmaplog, whose index
        # building crashes on a truncated final record (pymavlink 2.4.x); its
        # base class mavlogfile reads the same records sequentially and copes.
        conn = mavutil.mavlogfile(str(path), robust_parsing=True)
    except (OSError, ValueError) as exc:
        raise TlogError(f"cannot open tlog {path}: {exc}") from exc
    good = 0
    bad = 0
    try:
        while True:
            try:
                msg = conn.recv_msg()
            except (struct.error, IndexError, ValueError) as exc:  # defensive: truncated tail
                logger.warning("tlog %s: stopped at a damaged record: %s", path, exc)
                break
            if msg is None:
                break
            if msg.get_type() == "BAD_DATA":
                bad += 1
                if include_bad:
                    yield float(msg._timestamp), msg
                continue
            good += 1
            yield float(msg._timestamp), msg
    finally:
        conn.close()
    if bad:
        logger.info("tlog %s: %d valid messages, %d corrupt or truncated records skipped", path, good, bad)
    if good == 0:
        raise TlogError(f"tlog {path} holds no valid MAVLink message")
