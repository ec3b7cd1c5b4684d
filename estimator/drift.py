"""How fast an autopilot's position estimate moves against its own velocity estimate.

An EKF corrects its position with GPS and height measurements; the corrections move the
position without showing in the velocity. Over a window of reports the drift is::

    d = ((p_n - p_0) - integral of v over [t_0, t_n]) / (t_n - t_0)      (m/s, NED)

(the velocity integrated by the trapezoid rule over the reports). Zero for a consistent
estimate. Measured on PX4 SITL (SIH quadrotor, 2 s window): up to 0.5 m/s on the east axis through
an encounter and 0.35 m/s up for 8 s near the goal, with PX4's velocity loop holding
its velocity estimate on the setpoint: a planner that predicts positions from velocities
alone then misses where the estimate goes, and near a goal a pull proportional to the
distance stalls against it (docs/PX4.md).

Pure: fed report times (vehicle seconds), no clock. Bounded: at most ``max_reports``
reports are kept, whatever the rate.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from estimator.errors import EstimatorConfigError


class PositionDrift:
    """The drift of a position estimate against its velocity over the last ``window_s`` seconds.

    Parameters
    ----------
    window_s : float
        Length of the window, s (> 0). The drift is zero until the reports span half of it.
    max_mps : float
        Bound on each component of the drift, m/s (> 0): an estimate jumping by metres
        (a reset) is not a drift to fly against.
    max_reports : int
        Most reports kept (the oldest are dropped first).
    """

    def __init__(self, window_s: float, max_mps: float = 1.0, max_reports: int = 1024) -> None:
        if not (math.isfinite(window_s) and window_s > 0.0):
            raise EstimatorConfigError(f"PositionDrift.window_s must be finite and > 0, got {window_s!r}")
        if not (math.isfinite(max_mps) and max_mps > 0.0):
            raise EstimatorConfigError(f"PositionDrift.max_mps must be finite and > 0, got {max_mps!r}")
        self.window_s = float(window_s)
        self.max_mps = float(max_mps)
        # (t, p, velocity integral from the first report kept ever), the integral kept cumulative
        self._reports: deque[tuple[float, np.ndarray, np.ndarray]] = deque(maxlen=int(max_reports))
        self._last_v: np.ndarray | None = None

    def add(self, t_s: float, position_ned: np.ndarray, velocity_ned: np.ndarray) -> None:
        """One report (vehicle time s, position m, velocity m/s); older or repeated times are ignored."""
        p = np.array(position_ned, dtype=float)
        v = np.array(velocity_ned, dtype=float)
        if not (math.isfinite(t_s) and np.all(np.isfinite(p)) and np.all(np.isfinite(v))):
            return
        if self._reports:
            t_last, _, integral = self._reports[-1]
            if t_s <= t_last:
                return
            integral = integral + 0.5 * (self._last_v + v) * (t_s - t_last)
        else:
            integral = np.zeros(3)
        self._reports.append((float(t_s), p, integral))
        self._last_v = v
        while self._reports[-1][0] - self._reports[0][0] > self.window_s:
            self._reports.popleft()

    def value(self) -> np.ndarray:
        """The drift over the window, m/s NED (zeros until the reports span half the window)."""
        if len(self._reports) < 2:
            return np.zeros(3)
        t0, p0, i0 = self._reports[0]
        t1, p1, i1 = self._reports[-1]
        span = t1 - t0
        if span < 0.5 * self.window_s:
            return np.zeros(3)
        return np.clip(((p1 - p0) - (i1 - i0)) / span, -self.max_mps, self.max_mps)

    def clear(self) -> None:
        """Forget every report (after a gap or a reset of the estimate)."""
        self._reports.clear()
        self._last_v = None
