"""The small PX4 parameter set mavsim serves (PARAM_REQUEST_LIST/READ, PARAM_SET).

Integer parameters travel as PX4 sends them: ``MAV_PARAM_TYPE_INT32`` with the
int32 bits copied into the float field ("bytewise" encoding, as MAVSDK and
QGroundControl expect from PX4).
"""

from __future__ import annotations

import logging
import math
import struct

logger = logging.getLogger(__name__)

__all__ = ["DEFAULT_PARAMS", "ParamStore", "check_param_value", "PARAM_TYPE_INT32", "PARAM_TYPE_REAL32"]

PARAM_TYPE_INT32 = 6
PARAM_TYPE_REAL32 = 9

#: name -> (default, type, min, max). Defaults as in PX4 main.
DEFAULT_PARAMS: dict[str, tuple[float, int, float, float]] = {
    "COM_OF_LOSS_T": (1.0, PARAM_TYPE_REAL32, 0.0, 60.0),
    "COM_OBL_RC_ACT": (0, PARAM_TYPE_INT32, 0, 7),
    "COM_DISARM_LAND": (2.0, PARAM_TYPE_REAL32, -1.0, 20.0),
    "COM_DISARM_PRFLT": (10.0, PARAM_TYPE_REAL32, -1.0, 20.0),
    "COM_RCL_EXCEPT": (0, PARAM_TYPE_INT32, 0, 31),
    "COM_RC_IN_MODE": (3, PARAM_TYPE_INT32, 0, 4),
    "MIS_TAKEOFF_ALT": (2.5, PARAM_TYPE_REAL32, 0.0, 100.0),
    "MPC_XY_VEL_MAX": (12.0, PARAM_TYPE_REAL32, 0.0, 20.0),
    "MPC_XY_CRUISE": (5.0, PARAM_TYPE_REAL32, 3.0, 20.0),
    "MPC_Z_VEL_MAX_UP": (3.0, PARAM_TYPE_REAL32, 0.5, 8.0),
    "MPC_Z_VEL_MAX_DN": (1.5, PARAM_TYPE_REAL32, 0.5, 4.0),
    "MPC_TKO_SPEED": (1.5, PARAM_TYPE_REAL32, 1.0, 5.0),
    "MPC_LAND_SPEED": (0.7, PARAM_TYPE_REAL32, 0.6, 2.0),
    "MAV_SYS_ID": (1, PARAM_TYPE_INT32, 1, 250),
    "NAV_DLL_ACT": (0, PARAM_TYPE_INT32, 0, 6),
}


def check_param_value(name: str, value: float) -> str | None:
    """Return why ``value`` is not acceptable for ``name``, or None if it is."""
    default, ptype, lo, hi = DEFAULT_PARAMS[name]
    if not math.isfinite(value):
        return f"must be finite, got {value}"
    if ptype == PARAM_TYPE_INT32 and value != int(value):
        return f"must be an integer, got {value}"
    if not lo <= value <= hi:
        return f"must be in [{lo}, {hi}], got {value}"
    return None


def _int_to_wire(v: int) -> float:
    return struct.unpack("<f", struct.pack("<i", int(v)))[0]


def _wire_to_int(f: float) -> int:
    return struct.unpack("<i", struct.pack("<f", f))[0]


class ParamStore:
    """Current parameter values, ordered as PX4 lists them (by index)."""

    def __init__(self, overrides: dict[str, float] | None = None) -> None:
        self._values = {k: float(v[0]) for k, v in DEFAULT_PARAMS.items()}
        for k, v in (overrides or {}).items():
            self._values[k] = float(v)
        self.names = sorted(self._values)

    def __getitem__(self, name: str) -> float:
        return self._values[name]

    def __len__(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        return self.names.index(name)

    def wire(self, name: str) -> tuple[float, int]:
        """``(param_value, param_type)`` as sent in PARAM_VALUE."""
        ptype = DEFAULT_PARAMS[name][1]
        v = self._values[name]
        return (_int_to_wire(int(v)) if ptype == PARAM_TYPE_INT32 else v), ptype

    def set_from_wire(self, name: str, value: float, ptype: int) -> str | None:
        """Apply a PARAM_SET; return a reason if rejected (the value is then unchanged)."""
        if name not in self._values:
            return f"unknown parameter {name!r}"
        want = DEFAULT_PARAMS[name][1]
        if want == PARAM_TYPE_INT32:
            # PX4 decodes bytewise; accept a float-typed integral value as a courtesy.
            v = float(_wire_to_int(value)) if ptype == PARAM_TYPE_INT32 else value
        else:
            v = value
        problem = check_param_value(name, v)
        if problem:
            return f"{name} {problem}"
        self._values[name] = float(v)
        logger.info("param %s set to %g", name, v)
        return None
