"""The drone's reported position error (white, or time-correlated as an EKF's is) and velocity bias.

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

:class:`VelocityBias` is the other way an EKF's estimate is off: a slowly varying error of
the velocity, which PX4's velocity loop flies on (``[sim] velocity_bias_mps``).
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


class VelocityBias:
    """A slowly varying error of the reported velocity that the vehicle's velocity loop flies on (m/s, NED).

    PX4's velocity loop holds its velocity *estimate* on the setpoint. When that estimate is
    off by ``b``, the vehicle truly flies ``setpoint - b`` and reports ``true + b``, while the
    reported position, corrected by GPS and height, follows the truth: the position estimate
    moves against the velocity estimate by ``-b``. Measured on PX4 SITL (SIH): PX4 reported
    0.25 to 0.46 m/s descending for 8 s while SIH's truth climbed at about 0.1 m/s, and the
    position estimate drifted against the velocity by up to 0.6 m/s per axis.

    Here ``b(t) = rate * sin(2 pi t / period_s + phi)`` per axis, the north, east and down axes a
    quarter period apart (``phi`` 0, pi/2, pi). Deterministic: a function of time only.
    """

    def __init__(self, rate_mps: np.ndarray, period_s: float) -> None:
        self.rate = np.asarray(rate_mps, dtype=float)
        if self.rate.shape != (3,) or not np.all(np.isfinite(self.rate)):
            raise ValueError(f"velocity bias must be 3 finite numbers (m/s), got {rate_mps!r}")
        if not (math.isfinite(period_s) and period_s > 0.0):
            raise ValueError(f"velocity bias period must be finite and > 0 s, got {period_s!r}")
        self.period_s = float(period_s)
        self._phase = np.array([0.0, 0.5, 1.0]) * math.pi    # north, east, down: a quarter period apart

    def bias(self, t_s: float) -> np.ndarray:
        """The bias at time ``t_s`` (s), NED m/s."""
        return self.rate * np.sin(2.0 * math.pi * t_s / self.period_s + self._phase)
