"""MAVLink telemetry logs (tlog) in the format pymavlink's ``mavutil`` reads and MAVProxy writes.

A tlog has no header. Each record is an 8-byte big-endian unsigned integer of
microseconds since the Unix epoch, followed by one raw MAVLink packet exactly as
on the wire (MAVLink 1 or 2, signed or not). MAVProxy stores the link number in
the low 2 bits of the stamp; readers ignore it (0.3 microseconds at most).

Writing is plain file I/O (no clock: the caller passes the time of each record).
In lockstep runs the harness passes mavsim's lockstep epoch
(:data:`companion.offline.harness.LOCKSTEP_EPOCH_S`) plus simulated time, so the
same seed writes a byte-identical log. Reading is record by record (bounded: one
record at a time, at most :data:`MAX_PACKET_BYTES` after its stamp) and decodes
with pymavlink's parser; a damaged record stops the read naming its byte offset.
"""

from __future__ import annotations

import glob
import logging
import math
import os
import struct
from collections.abc import Iterator
from pathlib import Path
from types import TracebackType

from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink.autopilots import DIALECT

from companion.errors import CompanionError

logger = logging.getLogger(__name__)

_STAMP = struct.Struct(">Q")
_MAGICS = (0xFE, 0xFD)
_MIN_PACKET = 8  # MAVLink 1 header (6) + CRC (2), empty payload
#: Largest MAVLink packet (MAVLink 2: 10-byte header, 255-byte payload, CRC, 13-byte signature).
MAX_PACKET_BYTES = 10 + 255 + 2 + 13
_LAST_PLAUSIBLE_US = 4_102_444_800 * 1_000_000  # 2100-01-01: a later stamp is damage
_MAX_STAMP_JUMP_US = 86_400 * 1_000_000         # one day between consecutive records


class TlogError(CompanionError, ValueError):
    """A tlog could not be read: missing, empty, or not a tlog (the message names the file)."""


#: Segments kept of a tlog with a size bound: the first and the latest ``TLOG_SEGMENTS - 1``.
TLOG_SEGMENTS = 8


def segment_path(path: Path, index: int) -> Path:
    """Segment ``index`` of the tlog ``path``: the path itself for 0, else ``STEM.NNNN.SUFFIX``
    (``flight.tlog`` -> ``flight.0001.tlog``: the segments sort in the order they were written)."""
    return path if index == 0 else path.with_name(f"{path.stem}.{index:04d}{path.suffix}")


def segment_files(path: Path) -> list[Path]:
    """The segments of the tlog ``path`` on disk after the first (``STEM.NNNN.SUFFIX``), in the
    order they were written; the path itself is not among them."""
    path = Path(path)
    if not path.parent.is_dir():
        return []
    pattern = f"{glob.escape(path.stem)}.[0-9][0-9][0-9][0-9]{glob.escape(path.suffix)}"
    return sorted(p for p in path.parent.glob(pattern) if p.is_file())


class TlogWriter:
    """Append records to a tlog, flushing often enough that a killed process loses little.

    With ``max_bytes`` the tlog takes at most that much disk: it is written in
    :data:`TLOG_SEGMENTS` segments of ``max_bytes / TLOG_SEGMENTS`` each (split at record
    boundaries, so every segment is a tlog of its own and ``cat`` joins them; see
    :func:`segment_path` for their names), and once there are more, the oldest but the first
    is deleted: the start of the flight (arming, engagement) and its latest stretch stay.

    Parameters
    ----------
    path : str or Path
        File to create (truncated if it exists; with ``max_bytes``, stale segments of an
        earlier tlog of that name are removed).
    flush_period_s : float
        The file is flushed (and ``os.fsync``-free ``flush`` called) whenever
        this much log time has passed since the last flush, and on close.
    max_bytes : int, optional
        The bound on the segments kept, in bytes (None: one file, unbounded).

    Examples
    --------
    >>> with TlogWriter("flight.tlog") as log:          # doctest: +SKIP
    ...     log.write(time.time(), packet_bytes)
    """

    def __init__(self, path: str | os.PathLike, flush_period_s: float = 0.2, max_bytes: int | None = None) -> None:
        if not (math.isfinite(flush_period_s) and flush_period_s >= 0.0):
            raise TlogError(f"flush_period_s must be finite and >= 0, got {flush_period_s!r}")
        if max_bytes is not None and max_bytes < TLOG_SEGMENTS * MAX_PACKET_BYTES * 16:
            raise TlogError(f"tlog {path}: max_bytes {max_bytes} is too small (at least "
                            f"{TLOG_SEGMENTS * MAX_PACKET_BYTES * 16} bytes)")
        self.path = Path(path)
        self.flush_period_s = float(flush_period_s)
        self.max_bytes = max_bytes
        self.segment_bytes = None if max_bytes is None else max_bytes // TLOG_SEGMENTS
        if max_bytes is not None:
            for stale in segment_files(self.path):
                stale.unlink(missing_ok=True)   # an earlier flight's segments would read as this one's
        self._file = open(self.path, "wb")  # noqa: SIM115 (closed in close())
        self._last_flush_s: float | None = None
        self.records = 0
        self.bytes_written = 0          #: every byte written, in all segments (kept or not)
        self.segment = 0                #: the segment being written
        self.segments_deleted = 0       #: segments deleted to keep the bound
        self._segment_size = 0

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
        record = _STAMP.pack(int(round(t_s * 1e6))) + bytes(packet)
        if self.segment_bytes is not None and self._segment_size + len(record) > self.segment_bytes:
            self._next_segment()
        self._file.write(record)
        self._segment_size += len(record)
        self.bytes_written += len(record)
        self.records += 1
        if self._last_flush_s is None:
            self._last_flush_s = t_s
        elif t_s - self._last_flush_s >= self.flush_period_s:
            self.flush()
            self._last_flush_s = t_s

    def _next_segment(self) -> None:
        """Close the segment being written, open the next, and delete the oldest but the first beyond the bound."""
        self._file.close()
        self.segment += 1
        self._file = open(segment_path(self.path, self.segment), "wb")  # noqa: SIM115 (closed in close())
        self._segment_size = 0
        oldest = self.segment - (TLOG_SEGMENTS - 1)
        if oldest >= 1:
            segment_path(self.path, oldest).unlink(missing_ok=True)
            self.segments_deleted += 1
            if self.segments_deleted == 1:
                logger.warning("tlog %s: more than %d bytes; keeping the first segment and the latest %d "
                               "(older ones deleted from now on)", self.path, self.max_bytes, TLOG_SEGMENTS - 1)

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
    if head.startswith(b"ULog"):
        raise TlogError(f"{path} is a PX4 ULog, not a tlog: `companion identify` reads ULogs, this command needs a tlog")
    if len(head) < _STAMP.size + 1 or head[_STAMP.size] not in _MAGICS:
        raise TlogError(
            f"{path} is not a tlog: expected an 8-byte timestamp then a MAVLink packet "
            f"(0xFE or 0xFD), found {head[:16].hex()}"
        )


def _packet_length(head: bytes) -> int:
    """Length of the MAVLink packet whose first three bytes are ``head`` (magic, payload length, flags)."""
    if head[0] == 0xFE:
        return 6 + head[1] + 2
    signed = bool(head[2] & mavlink2.MAVLINK_IFLAG_SIGNED)
    return 10 + head[1] + 2 + (mavlink2.MAVLINK_SIGNATURE_BLOCK_LEN if signed else 0)


def read_tlog(path: str | os.PathLike, *, include_bad: bool = False) -> Iterator[tuple[float, object]]:
    """Iterate over ``(t_s, msg)`` of a tlog, record by record, with bounded memory.

    Each record is read exactly: the 8-byte stamp, then the packet whose length its own
    header gives (at most :data:`MAX_PACKET_BYTES`), decoded by pymavlink. Nothing larger
    than one record is ever held, however the file is damaged. Stamps are converted as
    pymavlink's ``mavlogfile`` does (``t = stamp_us * 1e-6``), so replays see the same times.

    Parameters
    ----------
    path : str or Path
        The tlog.
    include_bad : bool
        Also yield pymavlink's ``BAD_DATA`` pseudo messages (records whose CRC fails).

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
        Missing file, empty file, a file that is not a tlog, a log holding no valid
        MAVLink message, or a damaged record: a stamp after 2100 or more than a day from
        the previous record's, or a record that does not start with a MAVLink magic byte
        (the message names the byte offset). A truncated final record is tolerated
        (logged, skipped).
    """
    path = Path(path)
    _check_tlog(path)
    try:
        f = open(path, "rb")  # noqa: SIM115 (closed in finally)
    except OSError as exc:
        raise TlogError(f"cannot open tlog {path}: {exc.strerror or exc}") from exc
    parser = DIALECT.MAVLink(None)
    parser.robust_parsing = True
    good = bad = 0
    last_us: int | None = None
    try:
        while True:
            offset = f.tell()
            stamp = f.read(_STAMP.size)
            if len(stamp) < _STAMP.size:
                if stamp:
                    logger.warning("tlog %s: truncated record at byte offset %d skipped", path, offset)
                break
            (t_us,) = _STAMP.unpack(stamp)
            if t_us > _LAST_PLAUSIBLE_US or (last_us is not None and abs(t_us - last_us) > _MAX_STAMP_JUMP_US):
                raise TlogError(f"tlog {path}: nonsense timestamp 0x{t_us:016x} at byte offset {offset} "
                                f"(the log is damaged from here)")
            head = f.read(3)
            if len(head) < 3:
                logger.warning("tlog %s: truncated record at byte offset %d skipped", path, offset)
                break
            if head[0] not in _MAGICS:
                raise TlogError(f"tlog {path}: no MAVLink packet at byte offset {offset + _STAMP.size} "
                                f"(found 0x{head[0]:02x}; the log is damaged from here)")
            rest = _packet_length(head) - 3
            body = f.read(rest)
            if len(body) < rest:
                logger.warning("tlog %s: truncated record at byte offset %d skipped", path, offset)
                break
            parser.buf, parser.buf_index, parser.expected_length = bytearray(), 0, mavlink2.HEADER_LEN_V1 + 2
            try:
                msgs = parser.parse_buffer(head + body) or []
            except Exception as exc:  # robust parsing should not raise; a record is never worth a crash
                logger.debug("tlog %s: record at byte offset %d undecodable: %s", path, offset, exc)
                msgs = []
            msg = msgs[0] if msgs else mavlink2.MAVLink_bad_data(bytearray(head + body), "undecodable record")
            msg._timestamp = t_us * 1.0e-6
            if msg.get_type() == "BAD_DATA":
                bad += 1
                if include_bad:
                    yield msg._timestamp, msg
                continue
            last_us = t_us
            good += 1
            yield msg._timestamp, msg
    finally:
        f.close()
    if bad:
        logger.info("tlog %s: %d valid messages, %d corrupt records skipped", path, good, bad)
    if good == 0:
        raise TlogError(f"tlog {path} holds no valid MAVLink message")
