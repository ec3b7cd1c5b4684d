"""Whether the autopilot reports its own position as uncertain (a GPS outage: its estimator
dead-reckons), said to the operator once when it becomes so and once when it is back.

The planner already takes the autopilot's reported covariance as the drone's (``[companion]
drone_covariance = "reported"``), so its margins widen with it by themselves; what this adds is
that the operator is told, and the run report keeps the largest standard deviation reported.
Measured on PX4 SITL with its GPS off for 5 s (docs/FAULTS.md): the horizontal standard deviation
PX4 reported rose from 0.14-0.17 m to 1.09-1.20 m while its estimate drifted 1.6 to 3.6 m from
SIH's truth, and before this nothing told the operator until the reset after it.

Pure: a function of the reported covariances it is given, tick by tick.
"""

from __future__ import annotations

import math

import numpy as np

#: The position is said certain again once the standard deviation is below this fraction of the
#: bound: a hysteresis, so a deviation hovering at the bound is said once, not every tick.
CERTAIN_AGAIN_FRACTION = 0.7


def largest_sd_m(cov: np.ndarray) -> float:
    """The largest standard deviation (m) of a 3x3 position covariance (NED m^2): along its
    major axis, the square root of its largest eigenvalue (0 for a degenerate one; NaN for a
    covariance with a non-finite entry, which says nothing)."""
    cov = np.asarray(cov, dtype=float)
    if not np.all(np.isfinite(cov)):
        return math.nan
    return math.sqrt(max(0.0, float(np.linalg.eigvalsh(cov)[-1])))


class PositionQuality:
    """The autopilot's reported position uncertainty against ``[companion] position_sd_warn_m``.

    Parameters
    ----------
    warn_sd_m : the bound, m (> 0): a largest standard deviation at or above it is uncertain;
        below :data:`CERTAIN_AGAIN_FRACTION` of it, certain again.
    """

    def __init__(self, warn_sd_m: float) -> None:
        self.warn_sd_m = float(warn_sd_m)
        self.uncertain = False
        #: times the position became uncertain
        self.events = 0
        #: largest standard deviation the autopilot reported (m), None until it reported one
        self.largest_sd_m: float | None = None
        self._last: np.ndarray | None = None

    def update(self, cov: np.ndarray | None) -> str | None:
        """The text due for the autopilot's latest reported position covariance ``cov`` (3x3,
        NED m^2; None: it reports none, and nothing is said), or None."""
        if cov is None or cov is self._last:
            return None
        self._last = cov
        sd = largest_sd_m(cov)
        if not math.isfinite(sd):
            return None
        self.largest_sd_m = sd if self.largest_sd_m is None else max(self.largest_sd_m, sd)
        if not self.uncertain and sd >= self.warn_sd_m:
            self.uncertain = True
            self.events += 1
            return f"companion: position uncertain (sd {sd:.2f} m)"
        if self.uncertain and sd < CERTAIN_AGAIN_FRACTION * self.warn_sd_m:
            self.uncertain = False
            return f"companion: position certain again (sd {sd:.2f} m)"
        return None
