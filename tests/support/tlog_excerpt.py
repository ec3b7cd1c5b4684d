"""Cut an identification flight's tlog to what ``companion identify`` reads: small committed test data.

:func:`tlog_excerpt` keeps the autopilot's HEARTBEATs, LOCAL_POSITION_NED (every
``position_every``-th) and the companion's SET_POSITION_TARGET_LOCAL_NED, from ``margin_s``
before the first setpoint to ``margin_s`` after the last HEARTBEAT in the offboard role
(GUIDED for ArduCopter), each with its tlog time. ``tests/data/ardupilot_steps.tlog`` was cut so.
"""

from __future__ import annotations

import struct
from pathlib import Path

from companion.mavlink import messages
from companion.mavlink.tlog import read_tlog


def tlog_excerpt(tlog_in: str | Path, tlog_out: str | Path, *, margin_s: float = 2.0,
                 position_every: int = 1) -> Path:
    """Write the identification stretch of ``tlog_in`` to ``tlog_out`` (see the module docstring)."""
    records = list(read_tlog(tlog_in))
    off = [t for t, msg in records if msg.get_type() == "HEARTBEAT" and messages.decode_heartbeat(msg).offboard]
    setpoints = [t for t, msg in records if msg.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]
    if not off or not setpoints:
        raise ValueError(f"{tlog_in}: no offboard HEARTBEAT or no setpoint")
    t0, t1 = max(off[0], setpoints[0]) - margin_s, off[-1] + margin_s
    wanted = {"HEARTBEAT", "LOCAL_POSITION_NED", "SET_POSITION_TARGET_LOCAL_NED"}
    n_pos = 0
    with open(tlog_out, "wb") as f:
        for t, msg in records:
            kind = msg.get_type()
            if not (t0 <= t <= t1 and kind in wanted):
                continue
            if kind == "HEARTBEAT" and not messages.decode_heartbeat(msg).is_autopilot:
                continue
            if kind == "LOCAL_POSITION_NED":
                n_pos += 1
                if (n_pos - 1) % position_every:
                    continue
            f.write(struct.pack(">Q", int(round(t * 1e6))) + bytes(msg.get_msgbuf()))
    return Path(tlog_out)
