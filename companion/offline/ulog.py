"""PX4 ULogs in: the topics identification needs, read with pyulog (the ``view`` extra).

A ULog is PX4's own log of a flight (uORB topics, written by the autopilot: ``log/`` of the
SD card or of SITL's run directory). :func:`load_ulog_series` reads from it what
:func:`companion.offline.identify.response_log` fits, the same as from a tlog:

- ``vehicle_status``: ``nav_state`` (14, OFFBOARD) and ``arming_state`` (2, armed): the
  OFFBOARD stretches;
- the offboard setpoints: ``trajectory_setpoint`` (the companion's SET_POSITION_TARGET_LOCAL_NED
  as PX4's offboard mode published it; kept at 5 Hz by the logger's default profile, each
  change moved to the middle of its interval, :func:`_change_times`), else
  ``vehicle_local_position_setpoint`` (the position controller's, 10 Hz; its vertical
  setpoint is shaped by the controller and gave a vertical K_p a quarter above the tlog's);
- ``vehicle_local_position``: ``x, y, z, vx, vy, vz`` (NED, about 100 Hz).

Times are the ULog's (microseconds since PX4's boot), as seconds.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from companion.errors import CompanionError

logger = logging.getLogger(__name__)

#: The first bytes of every ULog file (``ULog`` then 0x01 0x12 0x35).
MAGIC = b"ULog"
#: ``vehicle_status.nav_state`` of OFFBOARD and ``arming_state`` of armed (PX4 msg/VehicleStatus.msg).
NAV_STATE_OFFBOARD = 14
ARMING_STATE_ARMED = 2
#: The setpoint topics, in the order they are preferred at equal rate.
SETPOINT_TOPICS = ("trajectory_setpoint", "vehicle_local_position_setpoint")
TOPICS = ("vehicle_status", "vehicle_local_position", *SETPOINT_TOPICS)


class UlogError(CompanionError, ValueError):
    """A ULog cannot be read or lacks a topic identification needs; the message names the file."""


class MissingExtra(CompanionError, RuntimeError):
    """An optional dependency is not installed; the message names the extra (exit 2)."""


def require_view_extra(module: str) -> None:
    """Import ``module`` or raise :class:`MissingExtra` naming the ``view`` extra."""
    try:
        __import__(module)
    except ImportError:
        raise MissingExtra(f"{module} is not installed: install the view extra "
                           f"(pip install 'ogccmpc[view]')") from None


def is_ulog(path: str | Path) -> bool:
    """Whether ``path`` is a file starting with the ULog magic."""
    try:
        with open(path, "rb") as f:
            return f.read(len(MAGIC)) == MAGIC
    except OSError:
        return False


def _columns(data, names: list[str]) -> np.ndarray:
    return np.column_stack([np.asarray(data[n], dtype=float) for n in names])


def _change_times(t: np.ndarray, v: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Sample times with each change moved to the middle of the interval it happened in.

    PX4's logger keeps a topic at a fixed interval (the default profile: the setpoints every
    100 or 200 ms), each sample stamped when it was published; a new setpoint shows at the
    first kept sample after it, up to one interval late. Held from there, the commands would
    lag the vehicle by half an interval on average, which the fit would take as a slower
    response (a vertical K_p of 4.7/s against 3.0/s from the tlog of the same flight). The
    middle of the interval makes that error zero on average.
    """
    t = t.copy()
    if t.size < 2:
        return t
    values = np.column_stack([v, np.nan_to_num(p, nan=1e300)])
    changed = np.any(values[1:] != values[:-1], axis=1)
    t[1:][changed] = 0.5 * (t[:-1][changed] + t[1:][changed])
    return t


def load_ulog_series(path: str | Path):
    """The mode reports, offboard setpoints and vehicle velocity of a ULog, as a
    :class:`~companion.offline.identify.LogSeries` (seconds since PX4's boot).

    Raises
    ------
    UlogError
        Not readable as a ULog, or a topic missing (names it).
    MissingExtra
        pyulog is not installed.
    """
    from companion.offline.identify import LogSeries

    require_view_extra("pyulog")
    from pyulog import ULog

    path = Path(path)
    try:
        ulog = ULog(str(path), list(TOPICS))
    except Exception as exc:  # pyulog raises plain exceptions on corrupt files
        raise UlogError(f"{path}: cannot read as a ULog: {exc}") from None
    topics: dict[str, dict] = {}
    for d in ulog.data_list:
        if d.multi_id == 0:
            topics[d.name] = d.data
    for name in ("vehicle_status", "vehicle_local_position"):
        if name not in topics or len(topics[name]["timestamp"]) == 0:
            raise UlogError(f"{path}: no {name} in the ULog")
    setpoints = [n for n in SETPOINT_TOPICS if n in topics and len(topics[n]["timestamp"]) > 0]
    if not setpoints:
        raise UlogError(f"{path}: no offboard setpoints (trajectory_setpoint or vehicle_local_position_setpoint) in the ULog")
    name = setpoints[0]
    sp = topics[name]
    if name == "trajectory_setpoint":
        sp_v = _columns(sp, [f"velocity[{k}]" for k in range(3)])
        sp_p = _columns(sp, [f"position[{k}]" for k in range(3)])
    else:   # the position controller's setpoint: its velocity is the velocity loop's (position feedback included)
        sp_v = _columns(sp, ["vx", "vy", "vz"])
        sp_p = np.full_like(sp_v, np.nan)
    keep = np.all(np.isfinite(sp_v), axis=1)       # a position-only setpoint is not a velocity command
    sp_t = _change_times(np.asarray(sp["timestamp"], dtype=float)[keep], sp_v[keep], sp_p[keep])
    status = topics["vehicle_status"]
    mode_t = np.asarray(status["timestamp"], dtype=float)
    mode_off = (np.asarray(status["nav_state"]) == NAV_STATE_OFFBOARD) & (np.asarray(status["arming_state"]) == ARMING_STATE_ARMED)
    # the setpoints' kinds in OFFBOARD (PX4 publishes trajectory_setpoint in its own modes too)
    report = np.searchsorted(mode_t, sp_t, side="right") - 1
    in_off = (report >= 0) & mode_off[np.maximum(report, 0)]
    with_pos = np.all(np.isfinite(sp_p[keep]), axis=1)
    kinds = {"velocity": int(np.sum(in_off & ~with_pos)), "position+velocity": int(np.sum(in_off & with_pos)), "topic": name}
    lpos = topics["vehicle_local_position"]
    us = 1e-6
    return LogSeries(
        mode_t=mode_t * us,
        mode_off=mode_off,
        sp_t=sp_t * us,
        sp_v=sp_v[keep],
        sp_p=sp_p[keep],
        vel_t=np.asarray(lpos["timestamp"], dtype=float) * us,
        vel=_columns(lpos, ["vx", "vy", "vz"]),
        pos=_columns(lpos, ["x", "y", "z"]),
        kinds=kinds,
    )
