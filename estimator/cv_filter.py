"""One timed constant-velocity Kalman filter on filterpy, shared by the drone filter and each track.

It owns the time bookkeeping (out-of-order, duplicate, re-initialisation after a
gap), the optional innovation gate and the filterpy :class:`KalmanFilter` that does
the arithmetic. filterpy's ``update`` is the Joseph form::

    K = P H' S^-1,  S = H P H' + R
    P = (I - K H) P (I - K H)' + K R K'

which keeps ``P`` symmetric positive semi-definite for any gain, even with rounding;
the result is then symmetrised to remove the last bit of asymmetry.

Time-correlated report errors (``report_correlation_s`` > 0). A source whose position
error is a first-order Gauss-Markov process (a GNSS position: errors correlated over
about a minute) is not a source of independent measurements: fusing ten reports a
second as if independent shrinks the covariance while the error stays. The filter then
carries the error as three more states, ``e`` (m, NED), the classic shaping filter
(Bryson and Henrikson; Gelb, *Applied Optimal Estimation*, section 4.5)::

    x = [p, v, e],   z_p = p + e,   e(t + dt) = phi e(t) + w,   phi = exp(-dt / tau),
    Cov(w) = (1 - phi^2) R_p

with ``R_p`` the report's own position covariance (the error's stationary covariance).
A report's velocity part, if any, stays white. What the filter publishes
(:attr:`state`, the predictions) is the ``[p, v]`` part: its position covariance no
longer falls below what a correlated error allows.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from filterpy.kalman import KalmanFilter

from estimator.covariance import symmetrise
from estimator.linalg import inverse
from estimator.models import STATE_DIM, process_noise, propagate, propagate_position, transition_matrix
from estimator.results import GaussianState, Reason, UpdateResult
from estimator.measurement import Measurement

logger = logging.getLogger(__name__)


class ConstantVelocityFilter:
    """A filterpy constant-velocity filter that knows the time of its estimate.

    Parameters
    ----------
    accel_noise_psd_m2ps3 : float
        White acceleration noise PSD, m^2/s^3.
    initial_velocity_std_mps : float
        Velocity prior (1 sigma per axis, m/s) when initialising without velocity.
    reinit_gap_s : float
        Gap after the last accepted measurement beyond which a measurement
        re-initialises the filter, s.
    gate_thresholds : dict of int to float, or None
        NIS threshold per measurement dimension (3, 6); ``None`` disables gating.
    label : str
        Name used in log messages (``"drone"``, ``"track (101, 1)"``).
    adopt_reports : bool
        Reports are estimates already filtered upstream (an autopilot's EKF): each one
        in time order is taken as the state, mean and covariance, instead of being
        fused with the prediction (Reason ``ADOPTED``). Between reports the filter
        predicts as usual. Fusing such reports as independent measurements makes the
        mean an average over their correlated errors that lags the autopilot's
        corrections (measured against PX4 SITL: up to 0.76 m off PX4's own estimate).
    report_correlation_s : float
        Correlation time ``tau`` (s) of the reports' position errors; 0 (the default):
        white, the six-state filter. Above 0, the error is carried as states (module
        docstring).
    reinit_after_gated : int or None
        This many measurements in a row refused by the gate re-initialise the filter from
        the last of them (Reason ``REINITIALISED``); None: only ``reinit_gap_s`` ends a
        lock-out.
    """

    def __init__(
        self,
        *,
        accel_noise_psd_m2ps3: float,
        initial_velocity_std_mps: float,
        reinit_gap_s: float,
        gate_thresholds: dict[int, float] | None = None,
        label: str = "filter",
        adopt_reports: bool = False,
        report_correlation_s: float = 0.0,
        reinit_after_gated: int | None = None,
    ) -> None:
        self._q = accel_noise_psd_m2ps3
        self._v0_var = initial_velocity_std_mps**2
        self._reinit_gap_s = reinit_gap_s
        self._gate = gate_thresholds
        self._label = label
        self._adopt = adopt_reports
        self._reinit_after_gated = reinit_after_gated
        self._gated_in_row = 0   # measurements refused by the gate since the last accepted one
        if not (math.isfinite(report_correlation_s) and report_correlation_s >= 0.0):
            raise ValueError(f"report_correlation_s must be finite seconds >= 0, got {report_correlation_s!r}")
        self._tau = float(report_correlation_s)
        self._dim = STATE_DIM + (3 if self._tau > 0.0 else 0)
        self._kf = KalmanFilter(dim_x=self._dim, dim_z=3)
        self._kf.inv = inverse    # filterpy's S^-1: np.linalg.inv's bits without its Python layer
        self._kf.x = np.zeros(self._dim)
        self._fq: tuple[float, np.ndarray | None, np.ndarray | None] = (math.nan, None, None)
        self.t_s: float | None = None
        """Time of the current estimate, s (``None`` before the first measurement)."""

    @property
    def kf(self) -> KalmanFilter:
        """The underlying filterpy filter (``x`` is 1-D, shape (6,))."""
        return self._kf

    @property
    def state(self) -> GaussianState | None:
        """Current estimate, or ``None`` before the first accepted measurement."""
        if self.t_s is None:
            return None
        if self._tau > 0.0:
            return GaussianState(self.t_s, self._kf.x[:STATE_DIM], self._kf.P[:STATE_DIM, :STATE_DIM])
        return GaussianState(self.t_s, self._kf.x, self._kf.P)

    def update(self, t_s: float, m: Measurement) -> UpdateResult:
        """Predict to ``t_s`` and correct with ``m`` (or initialise from it).

        Parameters
        ----------
        t_s : float
            Measurement time, s. Must be finite (checked by the caller).
        m : Measurement
            Validated measurement.

        Returns
        -------
        UpdateResult
        """
        if self.t_s is None:
            self._initialise(t_s, m)
            return UpdateResult(True, Reason.INITIALISED, t_s)
        dt = t_s - self.t_s
        if dt < 0.0:
            return self._reject(t_s, Reason.OUT_OF_ORDER, f"t={t_s:.6f} s is {-dt:.6f} s before the estimate")
        if dt == 0.0:
            return self._reject(t_s, Reason.DUPLICATE, f"t={t_s:.6f} s repeats the last accepted time")
        if dt > self._reinit_gap_s:
            logger.info("%s: %.3f s since last accepted measurement, re-initialising", self._label, dt)
            self._initialise(t_s, m)
            return UpdateResult(True, Reason.REINITIALISED, t_s)
        if self._adopt:
            self._initialise(t_s, m)
            return UpdateResult(True, Reason.ADOPTED, t_s)

        kf = self._kf
        x0, P0 = kf.x, kf.P  # filterpy replaces x and P with new arrays: these stay the estimate at self.t_s
        if self._tau > 0.0:
            kf.F, kf.Q, kf.R, H = self._shaped(dt, m)
        else:
            F, Q = self._model(dt)
            # F, Q and R are set on the filter rather than passed: filterpy then skips its
            # isscalar() checks of Q and R (same arithmetic, a few microseconds a report)
            kf.F, kf.Q, kf.R, H = F, Q, m.R, m.H
        kf.predict()  # x = F x;  P = F P F' + Q
        kf.update(m.z, H=H)  # Joseph form, see module docstring; keeps y = z - H x and S^-1
        nis = float(kf.y @ kf.SI @ kf.y)  # NIS = y' S^-1 y, S = H P H' + R of the prediction
        dof = m.z.size
        if self._gate is not None and not nis <= self._gate[dof]:
            kf.x, kf.P = x0, P0  # undo the prediction and the update: the estimate stays at self.t_s
            self._gated_in_row += 1
            if self._reinit_after_gated is not None and self._gated_in_row >= self._reinit_after_gated:
                logger.info("%s: %d measurements in a row gated (NIS %.3g), re-initialising",
                            self._label, self._gated_in_row, nis)
                self._initialise(t_s, m)
                return UpdateResult(True, Reason.REINITIALISED, t_s, nis, dof)
            return self._reject(
                t_s, Reason.GATED, f"NIS {nis:.3g} > gate {self._gate[dof]:.3g} ({dof} dof)", nis, dof,
                level=logging.INFO,
            )
        kf.P = symmetrise(kf.P)
        self.t_s = t_s
        self._gated_in_row = 0
        return UpdateResult(True, Reason.UPDATED, t_s, nis, dof)

    def _model(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """``F(dt)`` and ``Q(dt)``, kept for the last ``dt`` (reports at a fixed rate repeat it; filterpy only reads them)."""
        if self._fq[0] != dt:
            self._fq = (dt, transition_matrix(dt), process_noise(dt, self._q))
        return self._fq[1], self._fq[2]

    def _shaped(self, dt: float, m: Measurement) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``F``, ``Q``, ``R`` and ``H`` of the filter with the report error as states (module docstring).

        The position part of ``R`` moves into the error's process noise; a residual
        white part of ``1e-6 R_p`` keeps ``S`` invertible when ``P`` is nearly singular.
        """
        F6, Q6 = self._model(dt)
        phi = math.exp(-dt / self._tau)
        Rp = m.R[:3, :3]
        F = np.zeros((9, 9))
        F[:6, :6] = F6
        F[6:, 6:] = phi * np.eye(3)
        Q = np.zeros((9, 9))
        Q[:6, :6] = Q6
        Q[6:, 6:] = (1.0 - phi * phi) * Rp
        H = np.zeros((m.z.size, 9))
        H[:, :6] = m.H
        H[:3, 6:] = np.eye(3)
        R = m.R.copy()
        R[:3, :3] = 1e-6 * Rp
        R[:3, 3:] = R[3:, :3] = 0.0
        return F, Q, R, H

    def predict_position(self, lags_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Position mean (N, 3) and covariance (N, 3, 3) at ``lags_s`` after the estimate."""
        x, P = self.published()
        return propagate_position(x, P, lags_s, self._q)

    def predict_state(self, lags_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Full state mean (N, 6) and covariance (N, 6, 6) at ``lags_s`` after the estimate."""
        x, P = self.published()
        return propagate(x, P, lags_s, self._q)

    def published(self) -> tuple[np.ndarray, np.ndarray]:
        """The ``[p, v]`` mean (6,) and covariance (6, 6): the whole filter, or its first six states."""
        if self._tau > 0.0:
            return self._kf.x[:STATE_DIM], self._kf.P[:STATE_DIM, :STATE_DIM]
        return self._kf.x, self._kf.P

    def _initialise(self, t_s: float, m: Measurement) -> None:
        # x0 = measured p (and v); P0 = R on measured parts, velocity prior otherwise
        x = np.zeros(self._dim)
        P = np.zeros((self._dim, self._dim))
        x[: m.z.size] = m.z
        P[: m.z.size, : m.z.size] = m.R
        if not m.has_velocity:
            P[3:6, 3:6] = self._v0_var * np.eye(3)
        if self._tau > 0.0:   # p + e is the report: e ~ N(0, R_p) a priori, so Cov(p, e) = -R_p
            Rp = m.R[:3, :3]
            P[6:, 6:] = Rp
            P[:3, 6:] = P[6:, :3] = -Rp
        self._kf.x, self._kf.P = x, P
        self.t_s = t_s
        self._gated_in_row = 0

    def _reject(
        self, t_s: float, reason: Reason, detail: str, nis: float = math.nan, dof: int = 0,
        level: int = logging.DEBUG,
    ) -> UpdateResult:
        logger.log(level, "%s: rejected measurement (%s): %s", self._label, reason, detail)
        return UpdateResult(False, reason, t_s, nis, dof, detail)
