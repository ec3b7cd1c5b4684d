"""The drone's reported position error: white, or time-correlated as an EKF's is.

PX4's EKF does not report a fresh independent error at every message: its position
error wanders slowly (GNSS multipath, bias states), so consecutive reports share most of
it. A first-order Gauss-Markov process models that: with correlation time ``tau`` and
stationary covariance ``P``,

``e(t + dt) = a e(t) + sqrt(1 - a^2) L w``,  ``a = exp(-dt / tau)``,  ``L L' = P``,  ``w ~ N(0, I)``,

the exact discretisation for any ``dt``: ``e`` has covariance ``P`` at every instant (it
starts stationary, ``e(0) = L w``), and the correlation between two instants ``dt``
apart is ``a``. The simulator reports ``P`` in ODOMETRY, so the reported covariance is
the error's true marginal covariance (a consistent report: NEES ~ chi2_3), white or not.
``tau = 0`` is white noise, ``e = L w`` at every instant (the default).
"""

from __future__ import annotations

import logging
import math

import numpy as np

logger = logging.getLogger(__name__)


class GaussMarkovError:
    """A 3-D first-order Gauss-Markov error (metres, NED) driven by standard normal draws.

    Parameters
    ----------
    factor : (3, 3) ``L`` with ``L L' = P``, the stationary covariance (m^2).
    correlation_time_s : ``tau`` >= 0 (s); 0: white.
    """

    def __init__(self, factor: np.ndarray, correlation_time_s: float) -> None:
        if not correlation_time_s >= 0.0 or not math.isfinite(correlation_time_s):
            raise ValueError(f"correlation time must be finite and >= 0 s, got {correlation_time_s!r}")
        self.factor = np.asarray(factor, dtype=float)
        self.tau = float(correlation_time_s)
        self._e: np.ndarray | None = None
        self._t_us: int | None = None

    def sample(self, t_us: int, w: np.ndarray) -> np.ndarray:
        """The error at time ``t_us`` (microseconds, non-decreasing) from the draw ``w`` ~ N(0, I_3)."""
        fresh = self.factor @ w
        if self.tau == 0.0 or self._e is None:
            self._e = fresh
        else:
            a = math.exp(-max(0, t_us - self._t_us) * 1e-6 / self.tau)
            self._e = a * self._e + math.sqrt(1.0 - a * a) * fresh
        self._t_us = t_us
        return self._e
