"""The fleet's shared frame: where this vehicle's local NED sits in it.

Every autopilot has its own local NED frame about its own origin (PX4: where its estimator
first had a position). Drones that announce positions to each other need one frame:
``[fleet] origin = [lat, lon, alt]`` (degrees, metres AMSL) names it, the same for the whole
fleet. A vehicle's local frame is then the fleet frame shifted by the vehicle's origin
(GPS_GLOBAL_ORIGIN) placed about the fleet's origin with the autopilot's own projection
(:func:`companion.core.geo.project`; a translation: over a fleet's few kilometres the two
projections' grids turn against each other by well under a milliradian)::

    fleet NED = local NED + offset,   offset = (north, east of the vehicle's origin, fleet alt - vehicle alt)

Without ``origin`` the fleet shares the vehicles' frame (offset zero: one simulator's world,
or vehicles that share an origin). With it, nothing is announced or taken from the fleet
until the vehicle's origin is known (:meth:`FleetFrame.offset` is None; the origin is asked
for). Pure.
"""

from __future__ import annotations

import numpy as np

from companion.core.geo import project
from companion.loop.vehicle_reference import VehicleReference


class FleetFrame:
    """This vehicle's local NED in the fleet's frame (see the module docstring).

    Parameters
    ----------
    origin : (lat deg, lon deg, alt m AMSL) of the fleet frame, or None (the vehicles' own frame).
    reference : the vehicle's origin as the companion knows it.
    """

    def __init__(self, origin, reference: VehicleReference) -> None:
        self.origin = None if origin is None else tuple(float(x) for x in origin)
        self.reference = reference

    def offset(self) -> np.ndarray | None:
        """``fleet - local`` (3,) NED m; None while the vehicle's origin is needed and not known yet."""
        if self.origin is None:
            return np.zeros(3)
        own = self.reference.origin
        if own is None:
            self.reference.origin_request.wanted = True
            return None
        north, east = project(own.lat_deg, own.lon_deg, self.origin[0], self.origin[1])
        return np.array([north, east, self.origin[2] - own.alt_m])
