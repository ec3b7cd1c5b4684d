"""Kalman filters (filterpy) for the drone and for tracked obstacles, in local NED.

Pure: no sockets, clocks or threads; time enters as message timestamps in seconds.
Imports nothing from ``companion`` or ``mavsim``.

>>> from estimator import DroneFilter, DroneFilterConfig, ObstacleTracker, TrackerConfig
"""

from estimator.config import DroneFilterConfig, TrackerConfig
from estimator.drift import PositionDrift
from estimator.drone import DroneFilter
from estimator.errors import (
    EstimatorConfigError,
    EstimatorError,
    EstimatorInputError,
    NotInitialisedError,
    UnknownTrackError,
)
from estimator.results import FilterStats, GaussianState, Reason, TrackerStats, UpdateResult
from estimator.tracker import ObstacleTracker

__all__ = [
    "DroneFilter",
    "DroneFilterConfig",
    "ObstacleTracker",
    "TrackerConfig",
    "PositionDrift",
    "GaussianState",
    "UpdateResult",
    "Reason",
    "FilterStats",
    "TrackerStats",
    "EstimatorError",
    "EstimatorConfigError",
    "EstimatorInputError",
    "NotInitialisedError",
    "UnknownTrackError",
]
