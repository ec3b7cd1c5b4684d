"""Autopilot personalities: what makes mavsim's generic core a PX4 or an ArduCopter.

One module per autopilot implements :class:`mavsim.personalities.base.Personality`; this
registry names it. Adding an autopilot is its module plus its line in :data:`PERSONALITIES`.
"""

from __future__ import annotations

from mavsim.errors import SimulationError
from mavsim.personalities.ardupilot import ARDUPILOT
from mavsim.personalities.base import Personality
from mavsim.personalities.px4 import PX4

__all__ = ["PERSONALITIES", "DEFAULT_PERSONALITY", "VEHICLE_PROFILES", "get_personality", "velocity_response"]

#: Registry name -> personality.
PERSONALITIES: dict[str, Personality] = {PX4.name: PX4, ARDUPILOT.name: ARDUPILOT}
#: The personality a simulator has unless told otherwise.
DEFAULT_PERSONALITY = PX4.name

#: ``[sim] vehicle`` profiles: the generic lag, then every personality's responses.
VEHICLE_PROFILES: tuple[str, ...] = ("lag",) + tuple(
    name for p in PERSONALITIES.values() for name in p.response_models)


def get_personality(name: str) -> Personality:
    """The registered personality ``name``; SimulationError naming the known ones otherwise."""
    try:
        return PERSONALITIES[name]
    except KeyError:
        raise SimulationError(f"unknown autopilot {name!r} (known: {', '.join(PERSONALITIES)})") from None


def velocity_response(profile: str):
    """The :class:`mavsim.vehicle.VelocityResponse` of ``[sim] vehicle = profile``; None for ``"lag"``."""
    if profile == "lag":
        return None
    for p in PERSONALITIES.values():
        if profile in p.response_models:
            return p.response_models[profile]
    raise SimulationError(f"unknown vehicle profile {profile!r} (known: {', '.join(VEHICLE_PROFILES)})")
