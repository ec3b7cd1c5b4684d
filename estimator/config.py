"""Frozen, validated configuration of the drone filter and the obstacle tracker.

Units are in the field names (``_m``, ``_mps``, ``_s``, ``_m2ps3``). Invalid values
raise :class:`~estimator.errors.EstimatorConfigError` naming the field and the value;
:meth:`DroneFilterConfig.from_mapping` (and the tracker's) reject unknown keys, for
loading the ``[estimator]`` section of a scenario file.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Self

from estimator.errors import EstimatorConfigError

logger = logging.getLogger(__name__)

DRONE_REPORTS = ("measurements", "estimate")
"""What the drone's pose reports can be (:attr:`DroneFilterConfig.reports`)."""


def _require_positive(obj: object, name: str) -> None:
    value = getattr(obj, name)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise EstimatorConfigError(
            f"{type(obj).__name__}.{name} must be a finite number > 0, got {value!r}"
        )


class _FromMapping:
    """Mixin: build a config from a mapping (e.g. a TOML table), rejecting unknown keys."""

    @classmethod
    def from_mapping(cls, mapping: Mapping[str, Any], where: str = "") -> Self:
        """Build from ``mapping``; ``where`` (e.g. ``"scenario.toml [estimator.drone]"``)
        prefixes the error message.

        Raises
        ------
        EstimatorConfigError
            On an unknown key or an invalid value.
        """
        known = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
        unknown = sorted(set(mapping) - known)
        prefix = f"{where}: " if where else ""
        if unknown:
            raise EstimatorConfigError(
                f"{prefix}unknown key(s) {unknown} for {cls.__name__}; known: {sorted(known)}"
            )
        try:
            return cls(**mapping)
        except EstimatorConfigError as exc:
            raise EstimatorConfigError(f"{prefix}{exc}") from None


@dataclass(frozen=True, kw_only=True)
class DroneFilterConfig(_FromMapping):
    """Noise settings of :class:`~estimator.DroneFilter` (constant velocity, NED).

    Parameters
    ----------
    accel_noise_psd_m2ps3 : float
        Power spectral density of the white acceleration noise per axis, m^2/s^3.
        Over ``dt`` the velocity variance grows by ``q dt``.
    position_noise_std_m : float
        Position measurement noise (1 sigma, per axis, m), used where the report gives
        no finite variance (``LOCAL_POSITION_NED``, or NaN in ``ODOMETRY``).
    velocity_noise_std_mps : float
        Velocity measurement noise (1 sigma, per axis, m/s), likewise.
    initial_velocity_std_mps : float
        Velocity prior (1 sigma, per axis, m/s) when a (re)initialising measurement
        carries no velocity.
    reinit_gap_s : float
        A measurement arriving more than this after the last accepted one
        re-initialises the filter from that measurement, s.
    reports : str
        What the pose reports are. ``"measurements"`` (default): independent noisy
        measurements of the vehicle (mavsim's, a raw sensor's), Kalman-filtered.
        ``"estimate"``: the autopilot's own filtered estimate (PX4's EKF2 in
        ``ODOMETRY`` and ``LOCAL_POSITION_NED``); each report is taken as the state
        (mean and covariance) and the filter only predicts between reports. Re-filtering
        an estimate as independent measurements averages its correlated errors and lags
        its corrections: on PX4 SITL the filtered mean was up to 0.76 m off PX4's own
        (docs/PX4.md).
    """

    accel_noise_psd_m2ps3: float = 1.0
    position_noise_std_m: float = 0.15
    velocity_noise_std_mps: float = 0.1
    initial_velocity_std_mps: float = 2.0
    reinit_gap_s: float = 1.0
    reports: str = "measurements"

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            if f.name != "reports":
                _require_positive(self, f.name)
        if self.reports not in DRONE_REPORTS:
            raise EstimatorConfigError(
                f"{type(self).__name__}.reports must be one of {list(DRONE_REPORTS)}, got {self.reports!r}"
            )


@dataclass(frozen=True, kw_only=True)
class TrackerConfig(_FromMapping):
    """Settings of :class:`~estimator.ObstacleTracker` (one constant-velocity filter per track).

    Parameters
    ----------
    accel_noise_psd_m2ps3 : float
        Power spectral density of the obstacles' white acceleration noise per axis,
        m^2/s^3. Sets how fast predicted uncertainty grows with look-ahead.
    position_noise_std_m : float
        Position measurement noise (1 sigma, per axis, m) when a report has no valid
        covariance.
    velocity_noise_std_mps : float
        Velocity measurement noise (1 sigma, per axis, m/s) when a report carries a
        velocity without covariance.
    initial_velocity_std_mps : float
        Wide velocity prior of a new track (1 sigma, per axis, m/s) when its first
        report carries no velocity.
    gate_probability : float
        Probability mass of the innovation gate, in (0, 1): a report whose normalised
        innovation squared exceeds ``chi2.ppf(gate_probability, dim_z)`` is rejected.
    reinit_gap_s : float
        A report more than this after the track's last accepted one re-initialises
        the track, s. This also ends a lock-out by the gate.
    reinit_after_gated : int
        This many reports in a row refused by the gate re-initialise the track from the
        last of them, however soon (>= 1). The gate refuses a lone outlier; a source that
        keeps reporting where the model says it cannot be has changed what it does (an
        aircraft parked, then flying off at 2 m/s, was refused for the whole
        ``reinit_gap_s`` and unseen meanwhile: docs/notes/campaigns.md).
    drop_after_s : float
        :meth:`~estimator.ObstacleTracker.prune` drops tracks silent for longer, s.
    report_correlation_s : float
        Correlation time of the reports' position errors, s (>= 0). 0, the default,
        takes every report's error as independent of the others; a source whose errors
        drift slowly (a GNSS position: about 60 s) makes a filter that fuses its reports as
        independent overconfident, and a value here carries the error in the filter
        instead (:class:`~estimator.cv_filter.ConstantVelocityFilter`).
    """

    accel_noise_psd_m2ps3: float = 0.5
    position_noise_std_m: float = 0.15
    velocity_noise_std_mps: float = 0.2
    initial_velocity_std_mps: float = 3.0
    gate_probability: float = 0.9999
    reinit_gap_s: float = 1.5
    reinit_after_gated: int = 3
    drop_after_s: float = 3.0
    report_correlation_s: float = 0.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            if f.name != "report_correlation_s":
                _require_positive(self, f.name)
        if not isinstance(self.reinit_after_gated, int):
            raise EstimatorConfigError(
                f"TrackerConfig.reinit_after_gated must be a whole number >= 1, got {self.reinit_after_gated!r}"
            )
        if not (math.isfinite(self.report_correlation_s) and self.report_correlation_s >= 0.0):
            raise EstimatorConfigError(
                f"TrackerConfig.report_correlation_s must be finite seconds >= 0, got {self.report_correlation_s!r}"
            )
        if not self.gate_probability < 1.0:
            raise EstimatorConfigError(
                f"TrackerConfig.gate_probability must be in (0, 1), got {self.gate_probability!r}"
            )
