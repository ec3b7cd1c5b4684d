"""The parameter store mavsim serves (PARAM_REQUEST_LIST/READ, PARAM_SET).

The parameters themselves, name -> (default, MAV_PARAM_TYPE, min, max), are the autopilot
personality's (:attr:`mavsim.personalities.base.Personality.params`). How integer parameters
travel is the personality's choice too (``ints_bytewise``): with the int32 bits copied into
the float field ("bytewise" encoding, as MAVSDK and QGroundControl expect from PX4), or as
the float of their value (ArduPilot's encoding, whatever their MAV_PARAM_TYPE).
"""

from __future__ import annotations

import logging
import math
import struct

logger = logging.getLogger(__name__)

__all__ = ["ParamTable", "ParamStore", "check_param_value", "PARAM_TYPE_INT8", "PARAM_TYPE_INT16",
           "PARAM_TYPE_INT32", "PARAM_TYPE_REAL32"]

PARAM_TYPE_INT8 = 2
PARAM_TYPE_INT16 = 4
PARAM_TYPE_INT32 = 6
PARAM_TYPE_REAL32 = 9
#: MAV_PARAM_TYPE values of integers (UINT8 1 .. INT64 8).
_INTEGER_TYPES = frozenset(range(1, 9))

#: name -> (default, MAV_PARAM_TYPE, min, max).
ParamTable = dict[str, tuple[float, int, float, float]]

def check_param_value(table: ParamTable, name: str, value: float) -> str | None:
    """Return why ``value`` is not acceptable for ``name`` of ``table``, or None if it is."""
    default, ptype, lo, hi = table[name]
    if not math.isfinite(value):
        return f"must be finite, got {value}"
    if ptype in _INTEGER_TYPES and value != int(value):
        return f"must be an integer, got {value}"
    if not lo <= value <= hi:
        return f"must be in [{lo}, {hi}], got {value}"
    return None


def _int_to_wire(v: int) -> float:
    return struct.unpack("<f", struct.pack("<i", int(v)))[0]


def _wire_to_int(f: float) -> int:
    return struct.unpack("<i", struct.pack("<f", f))[0]


class ParamStore:
    """Current values of the parameters of ``table``, listed by name (the index order).

    ``overrides`` (name -> value) replace defaults; their names and values are checked by
    the caller (the scenario reader). ``ints_bytewise``: integers travel with their int32 bits in
    the float field (PX4); False: as the float of their value (ArduPilot).
    """

    def __init__(self, table: ParamTable, overrides: dict[str, float] | None = None, ints_bytewise: bool = True) -> None:
        self.table = table
        self.ints_bytewise = ints_bytewise
        self._values = {k: float(v[0]) for k, v in table.items()}
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
        ptype = self.table[name][1]
        v = self._values[name]
        if ptype == PARAM_TYPE_INT32 and self.ints_bytewise:
            return _int_to_wire(int(v)), ptype
        return v, ptype

    def set_from_wire(self, name: str, value: float, ptype: int) -> str | None:
        """Apply a PARAM_SET; return a reason if rejected (the value is then unchanged)."""
        if name not in self._values:
            return f"unknown parameter {name!r}"
        want = self.table[name][1]
        if want == PARAM_TYPE_INT32 and self.ints_bytewise:
            # PX4 decodes bytewise; accept a float-typed integral value as a courtesy.
            v = float(_wire_to_int(value)) if ptype == PARAM_TYPE_INT32 else value
        else:
            v = value
        problem = check_param_value(self.table, name, v)
        if problem:
            return f"{name} {problem}"
        self._values[name] = float(v)
        logger.info("param %s set to %g", name, v)
        return None
