"""Kalman filter of the drone's own position and velocity (constant velocity, NED).

Fed with what PX4 reports: ``ODOMETRY`` (position and velocity with variances at
indices 0, 6, 11 of its covariance arrays, see :mod:`estimator.covariance`) or
``LOCAL_POSITION_NED`` (no variances: configured noise). Gives the current estimate
and the predicted position covariance at each step of a planning horizon.
"""

from __future__ import annotations

import logging
import math
from collections import Counter

import numpy as np

from estimator.config import DroneFilterConfig
from estimator.cv_filter import ConstantVelocityFilter
from estimator.errors import EstimatorInputError, NotInitialisedError
from estimator.measurement import MeasurementRejected, assemble
from estimator.results import FilterStats, GaussianState, Reason, UpdateResult

logger = logging.getLogger(__name__)


class DroneFilter:
    """Constant-velocity Kalman filter (filterpy) of the drone in local NED.

    Parameters
    ----------
    config : DroneFilterConfig
        Noise settings.

    Examples
    --------
    >>> f = DroneFilter(DroneFilterConfig())
    >>> f.update(0.0, [0.0, 0.0, -5.0], [1.0, 0.0, 0.0], None, None).reason
    'initialised'
    """

    def __init__(self, config: DroneFilterConfig) -> None:
        self.config = config
        self._filter = self._new_filter()
        self._counts: Counter[str] = Counter()
        self.resets = 0  #: times :meth:`reset` forgot the estimate

    def _new_filter(self) -> ConstantVelocityFilter:
        config = self.config
        return ConstantVelocityFilter(
            accel_noise_psd_m2ps3=config.accel_noise_psd_m2ps3,
            initial_velocity_std_mps=config.initial_velocity_std_mps,
            reinit_gap_s=config.reinit_gap_s,
            gate_thresholds=None,  # the autopilot's own estimate is not gated: no lock-out
            label="drone",
            adopt_reports=config.reports == "estimate",
        )

    def reset(self) -> None:
        """Forget the estimate (the autopilot's estimator reset: its reports before and after are
        in frames a jump apart and must not be blended); the next report initialises it."""
        self._filter = self._new_filter()
        self.resets += 1

    @property
    def state(self) -> GaussianState | None:
        """Current estimate ``[p, v]`` at the last accepted measurement time, or ``None``."""
        return self._filter.state

    @property
    def stats(self) -> FilterStats:
        """Counters of update outcomes."""
        return FilterStats(**self._counts)

    def update(
        self,
        t_s: float,
        pos_ned: np.ndarray,
        vel_ned: np.ndarray | None = None,
        pos_var: np.ndarray | None = None,
        vel_var: np.ndarray | None = None,
    ) -> UpdateResult:
        """Fuse one position (and optionally velocity) report.

        Never raises for a bad report: it is rejected, logged and counted.

        Parameters
        ----------
        t_s : float
            Message timestamp, s (vehicle time since boot).
        pos_ned : array_like, shape (3,)
            Position, m, local NED.
        vel_ned : array_like, shape (3,), or None
            Velocity, m/s, local NED.
        pos_var, vel_var : array_like, shape (3,), or None
            Per-axis variances (m^2, m^2/s^2), e.g. from
            :func:`estimator.covariance.position_variances`. NaN entries or ``None``
            use the configured noise; other non-finite or non-positive entries reject
            the report. A full (3, 3) covariance is accepted too.

        Returns
        -------
        UpdateResult
        """
        result = self._update(t_s, pos_ned, vel_ned, pos_var, vel_var)
        self._counts[result.reason] += 1
        return result

    def _update(self, t_s, pos_ned, vel_ned, pos_var, vel_var) -> UpdateResult:
        try:
            if not math.isfinite(t_s):
                raise MeasurementRejected(Reason.NON_FINITE, f"time is not finite: {t_s!r}")
            m = assemble(
                pos_ned, vel_ned, pos_var, vel_var,
                position_std_m=self.config.position_noise_std_m,
                velocity_std_mps=self.config.velocity_noise_std_mps,
            )
        except MeasurementRejected as exc:
            logger.warning("drone: rejected measurement at t=%r (%s): %s", t_s, exc.reason, exc.detail)
            return UpdateResult(False, exc.reason, float(t_s), detail=exc.detail)
        return self._filter.update(float(t_s), m)

    def predict_position_covariances(
        self, t0_s: float, velocities: np.ndarray, step_s: float
    ) -> np.ndarray:
        """Predicted position covariance at each step of a planned velocity sequence.

        Step ``k`` (1..N) is at ``t0_s + k step_s``. The covariance is the position
        block of ``F(tau) P F(tau)' + Q(tau)`` with ``tau`` the time since the current
        estimate, equal to ``F^k P0 F^k' + sum_{j<k} F^j Q F^j'`` with ``P0`` the
        estimate predicted to ``t0_s``, ``F = F(step_s)``, ``Q = Q(step_s)``.

        The planned velocities are a known input (``x_{k+1} = F x_k + B u_k``): they
        move the mean but, the filter being linear, do not change the covariance. They
        are validated and fix ``N`` only.

        Parameters
        ----------
        t0_s : float
            Time the plan starts, s (message time base). A time before the current
            estimate is treated as the estimate's time (covariance is not predicted
            backwards).
        velocities : array_like, shape (N, 3)
            Planned velocity commands, m/s, NED.
        step_s : float
            Planning step, s (> 0).

        Returns
        -------
        numpy.ndarray, shape (N, 3, 3)
            Position covariances, m^2.

        Raises
        ------
        NotInitialisedError
            Before the first accepted measurement.
        EstimatorInputError
            On a non-finite time, a non-positive step or velocities not of shape (N, 3).
        """
        if self._filter.t_s is None:
            raise NotInitialisedError("drone filter has no estimate yet: no measurement accepted")
        v = np.asarray(velocities, dtype=float)
        if v.ndim != 2 or v.shape[1] != 3:
            raise EstimatorInputError(f"velocities must have shape (N, 3), got {v.shape}")
        if not np.all(np.isfinite(v)):
            raise EstimatorInputError("velocities must be finite")
        if not math.isfinite(t0_s):
            raise EstimatorInputError(f"t0_s must be finite, got {t0_s!r}")
        if not (math.isfinite(step_s) and step_s > 0.0):
            raise EstimatorInputError(f"step_s must be finite and > 0, got {step_s!r}")
        lag0 = max(t0_s - self._filter.t_s, 0.0)
        lags = lag0 + step_s * np.arange(1, v.shape[0] + 1)
        _, covs = self._filter.predict_position(lags)
        return covs
