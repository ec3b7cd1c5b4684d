"""tlog writer: the telemetry-log format pymavlink and MAVProxy read.

No header; each record is an 8-byte big-endian uint64 of microseconds since the Unix
epoch followed by the raw MAVLink packet as on the wire. ``mavutil.mavlink_connection
(path)`` reads it back (``msg._timestamp`` in seconds). In lockstep the stamp is a
fixed epoch plus simulated time, so the same seed gives byte-identical tlogs.
"""

from __future__ import annotations

import logging
import struct
from pathlib import Path
from typing import BinaryIO

logger = logging.getLogger(__name__)

__all__ = ["TlogWriter", "LOCKSTEP_EPOCH_US"]

#: Epoch of lockstep tlogs: 2024-01-01T00:00:00Z in microseconds.
LOCKSTEP_EPOCH_US = 1_704_067_200_000_000
_STAMP = struct.Struct(">Q")


class TlogWriter:
    """Append (timestamp, packet) records to a tlog file.

    Parameters
    ----------
    path : str or Path
        File to create (truncated).
    flush_every : int
        Flush after this many records (and on :meth:`close`).
    """

    def __init__(self, path: str | Path, flush_every: int = 200) -> None:
        self.path = Path(path)
        self._f: BinaryIO | None = self.path.open("wb")
        self._n = 0
        self.flush_every = flush_every

    def write(self, unix_us: int, packet: bytes) -> None:
        """One record: ``unix_us`` microseconds since the Unix epoch, then the packet."""
        if self._f is None:
            return
        self._f.write(_STAMP.pack(int(unix_us)) + packet)
        self._n += 1
        if self._n % self.flush_every == 0:
            self._f.flush()

    def flush(self) -> None:
        if self._f is not None:
            self._f.flush()

    def close(self) -> None:
        if self._f is not None:
            self._f.close()
            self._f = None

    def __enter__(self) -> "TlogWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
