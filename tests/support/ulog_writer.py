"""Write small PX4 ULog files (the subset of the format pyulog and PX4 use) for tests and test data.

A ULog (https://docs.px4.io/main/en/dev_log/ulog_file_format.html): a 16-byte header
(``ULog``, 0x01 0x12 0x35, version 1, start time in microseconds), a flag-bits message, one
format message per topic, then for each topic an add-subscription message and its data
messages, every message ``uint16 size, uint8 type`` then its body, little endian. Each topic
here is a flat list of fields, the first one ``uint64_t timestamp``.

:func:`flight_excerpt` cuts the topics identification reads out of a PX4 ULog (and the
same flight's tlog) into small files: the committed test data ``tests/data/px4_steps.*``.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

_TYPES = {"uint64_t": "Q", "uint8_t": "B", "float": "f", "double": "d", "int32_t": "i", "bool": "?"}


def write_ulog(path: str | Path, topics: dict[str, tuple[list[tuple[str, str]], dict[str, np.ndarray]]],
               start_us: int = 0) -> Path:
    """Write ``topics`` (name -> (fields [(type, name)], columns name -> (M,) or (M, k) array)) as a ULog.

    A field type ``"float[3]"`` takes an (M, 3) column. Data messages are written in
    timestamp order across topics, as PX4's logger does.
    """
    path = Path(path)
    out = bytearray(b"ULog\x01\x12\x35\x01" + struct.pack("<Q", start_us))
    out += struct.pack("<HB", 40, ord("B")) + bytes(40)       # flag bits: no compat/incompat flags, no appended data

    def message(kind: str, body: bytes) -> bytes:
        return struct.pack("<HB", len(body), ord(kind)) + body

    packers = {}
    for name, (fields, _) in topics.items():
        if fields[0] != ("uint64_t", "timestamp"):
            raise ValueError(f"{name}: the first field must be uint64_t timestamp")
        out += message("F", (name + ":" + "".join(f"{t} {n};" for t, n in fields)).encode())
        fmt = "<"
        for t, _ in fields:
            base, _, size = t.partition("[")
            fmt += (size.rstrip("]") if size else "") + _TYPES[base]
        packers[name] = struct.Struct(fmt)
    rows = []
    for msg_id, (name, (fields, columns)) in enumerate(topics.items()):
        out += message("A", struct.pack("<BH", 0, msg_id) + name.encode())
        n = len(columns["timestamp"])
        cols = [np.asarray(columns[f]) for _, f in fields]
        for i in range(n):
            values = []
            for (t, _), col in zip(fields, cols):
                values.extend(col[i].tolist() if "[" in t else [col[i].item()])
            rows.append((int(cols[0][i]), msg_id, message("D", struct.pack("<H", msg_id) + packers[name].pack(*values))))
    rows.sort(key=lambda r: (r[0], r[1]))
    for _, _, body in rows:
        out += body
    path.write_bytes(bytes(out))
    return path


STATUS_FIELDS = [("uint64_t", "timestamp"), ("uint8_t", "nav_state"), ("uint8_t", "arming_state")]
POSITION_FIELDS = [("uint64_t", "timestamp")] + [("float", n) for n in ("x", "y", "z", "vx", "vy", "vz")]
SETPOINT_FIELDS = [("uint64_t", "timestamp"), ("float[3]", "position"), ("float[3]", "velocity")]


def flight_excerpt(ulog_in: str | Path, tlog_in: str | Path, ulog_out: str | Path, tlog_out: str | Path,
                   *, margin_s: float = 2.0, position_every: int = 3) -> tuple[Path, Path]:
    """The OFFBOARD part (with ``margin_s`` either side) of a flight's ULog and tlog, small.

    The ULog keeps ``vehicle_status`` (nav and arming state), ``trajectory_setpoint``
    (position, velocity) and every ``position_every``-th ``vehicle_local_position`` (x..vz);
    the tlog keeps the autopilot's HEARTBEATs and LOCAL_POSITION_NED and the companion's
    SET_POSITION_TARGET_LOCAL_NED of the same stretch (its own clock: the stretch is cut by
    the OFFBOARD HEARTBEATs).
    """
    from pyulog import ULog

    from companion.mavlink import messages
    from companion.mavlink.tlog import read_tlog

    ulog = ULog(str(ulog_in), ["vehicle_status", "vehicle_local_position", "trajectory_setpoint"])
    data = {d.name: d.data for d in ulog.data_list if d.multi_id == 0}
    st = data["vehicle_status"]
    off = (st["nav_state"] == 14) & (st["arming_state"] == 2)
    t_off = st["timestamp"][off]
    lo, hi = t_off[0] - margin_s * 1e6, t_off[-1] + margin_s * 1e6

    def cut(d: dict, names: list[str], every: int = 1) -> dict:
        keep = np.flatnonzero((d["timestamp"] >= lo) & (d["timestamp"] <= hi))[::every]
        return {n: d[n][keep] for n in names}

    sp = data["trajectory_setpoint"]
    sp_cols = cut(sp, ["timestamp", *(f"{f}[{k}]" for f in ("position", "velocity") for k in range(3))])
    setpoints = {"timestamp": sp_cols["timestamp"],
                 "position": np.column_stack([sp_cols[f"position[{k}]"] for k in range(3)]),
                 "velocity": np.column_stack([sp_cols[f"velocity[{k}]"] for k in range(3)])}
    write_ulog(ulog_out, {
        "vehicle_status": (STATUS_FIELDS, cut(st, ["timestamp", "nav_state", "arming_state"])),
        "vehicle_local_position": (POSITION_FIELDS, cut(data["vehicle_local_position"],
                                                        [n for _, n in POSITION_FIELDS], position_every)),
        "trajectory_setpoint": (SETPOINT_FIELDS, setpoints),
    }, start_us=int(lo))
    # the tlog: the OFFBOARD stretch by its HEARTBEATs, with the margin
    records = list(read_tlog(tlog_in))
    times = [t for t, msg in records
             if msg.get_type() == "HEARTBEAT" and messages.decode_heartbeat(msg).offboard]
    t0, t1 = times[0] - margin_s, times[-1] + margin_s
    wanted = {"HEARTBEAT", "LOCAL_POSITION_NED", "SET_POSITION_TARGET_LOCAL_NED"}
    with open(tlog_out, "wb") as f:
        for t, msg in records:
            if t0 <= t <= t1 and msg.get_type() in wanted:
                f.write(struct.pack(">Q", int(round(t * 1e6))) + bytes(msg.get_msgbuf()))
    return Path(ulog_out), Path(tlog_out)
