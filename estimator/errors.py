"""Exception hierarchy of the estimator. Messages say what was wrong and where.

Filter *updates* never raise for bad measurements: they return an
:class:`~estimator.results.UpdateResult` with ``accepted=False`` and a reason. These
exceptions are for programming and configuration errors (bad config values, asking
for a track that does not exist, bad arguments to a prediction).
"""

from __future__ import annotations


class EstimatorError(Exception):
    """Base of every error the estimator raises on purpose."""


class EstimatorConfigError(EstimatorError, ValueError):
    """A configuration value is invalid (the message names the field and the value)."""


class EstimatorInputError(EstimatorError, ValueError):
    """An argument has the wrong shape, is not finite, or is not a valid covariance."""


class UnknownTrackError(EstimatorError, LookupError):
    """A track key was asked for that the tracker does not hold (never seen, or dropped)."""


class NotInitialisedError(EstimatorError, RuntimeError):
    """A filter was asked for an estimate before its first accepted measurement."""
