"""Exceptions raised by :mod:`mavsim`.

All errors subclass a built-in so callers may catch ``ValueError`` or
``RuntimeError`` without importing this module.
"""

from __future__ import annotations

__all__ = ["MavsimError", "ScenarioError", "SimulationError"]


class MavsimError(Exception):
    """Base class of every error raised on purpose by mavsim."""


class ScenarioError(MavsimError, ValueError):
    """A scenario file is missing, unreadable or has a bad section, key or value.

    The message names the file, the section and the key.
    """


class SimulationError(MavsimError, RuntimeError):
    """The simulator was used wrongly (e.g. advancing by a negative time)."""
