"""Read named parameters from the autopilot: PARAM_REQUEST_READ, answered by PARAM_VALUE.

A ground station reads one parameter by name (``param_index = -1``); the autopilot answers
with a PARAM_VALUE naming it. :class:`ParamRead` asks for each name once, and again every
``timeout_s`` of link time for the names still unanswered, at most ``retries`` times more;
then it fails naming them (an autopilot that does not know a name never answers it: PX4
logs it, ArduPilot stays silent). Values are kept as they travel (the float field and its
MAV_PARAM_TYPE): how an integer is packed is the autopilot's affair
(:mod:`companion.mavlink.autopilots`).

Pure: link time (s) comes in as an argument; messages go out as return values. Bounded: at
most :data:`MAX_NAMES` names, each request repeated at most ``retries`` times.
"""

from __future__ import annotations

import logging
import math

from pymavlink.dialects.v20 import common as mavlink2

logger = logging.getLogger(__name__)

TIMEOUT_S = 1.0
RETRIES = 4
MAX_NAMES = 16


def _name(raw) -> str:
    text = raw.decode("ascii", "replace") if isinstance(raw, (bytes, bytearray)) else str(raw)
    return text.split("\x00", 1)[0]


class ParamRead:
    """Values of ``names`` from the autopilot ``target`` (system, component); :attr:`values` when :attr:`done`."""

    def __init__(self, target: tuple[int, int], names: tuple[str, ...], *, timeout_s: float = TIMEOUT_S,
                 retries: int = RETRIES) -> None:
        if not 0 < len(names) <= MAX_NAMES or any(not 0 < len(n) <= 16 for n in names):
            raise ValueError(f"read 1 to {MAX_NAMES} parameters of 1 to 16 characters, got {names!r}")
        self.target = target
        self.names = tuple(names)
        self.timeout_s = float(timeout_s)
        self.retries = int(retries)
        #: name -> (value as sent, MAV_PARAM_TYPE)
        self.values: dict[str, tuple[float, int]] = {}
        #: why the read failed (None while running or once done)
        self.failed: str | None = None
        self.resent = 0
        self._tries = 0
        self._last_t = -math.inf

    @property
    def done(self) -> bool:
        return len(self.values) == len(self.names)

    @property
    def over(self) -> bool:
        return self.done or self.failed is not None

    def _requests(self, t_s: float) -> list:
        self._last_t = t_s
        return [mavlink2.MAVLink_param_request_read_message(*self.target, name.encode("ascii"), -1)
                for name in self.names if name not in self.values]

    def start(self, t_s: float) -> list:
        """A PARAM_REQUEST_READ per name, at link time ``t_s``."""
        return self._requests(t_s)

    def step(self, t_s: float) -> list:
        """The requests to repeat at ``t_s`` (the unanswered names after a timeout), or nothing."""
        if self.over or t_s - self._last_t < self.timeout_s - 1e-9:
            return []
        missing = [n for n in self.names if n not in self.values]
        if self._tries >= self.retries:
            self.failed = (f"no PARAM_VALUE for {', '.join(missing)} after {self.retries + 1} requests "
                           f"{self.timeout_s:g} s apart")
            logger.warning("parameter read failed: %s", self.failed)
            return []
        self._tries += 1
        self.resent += len(missing)
        return self._requests(t_s)

    def on_message(self, t_s: float, msg) -> None:
        """Take a PARAM_VALUE from the target naming one of ours (anything else is ignored)."""
        if self.over or msg.get_type() != "PARAM_VALUE":
            return
        if (msg.get_srcSystem(), msg.get_srcComponent()) != self.target:
            return
        name = _name(msg.param_id)
        if name in self.names and math.isfinite(float(msg.param_value)):
            self.values[name] = (float(msg.param_value), int(msg.param_type))
