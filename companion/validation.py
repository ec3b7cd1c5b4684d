"""One way to validate configuration: value checks for dataclass fields and one section builder.

Every section the companion reads from a scenario file (``[planner]``, ``[companion]``,
``[offboard]``, ``[mission]``, ``[map]``) is a frozen dataclass whose ``__post_init__``
checks each field with the functions here; they raise :class:`companion.errors.ConfigError`
with ``key = value must be ...``. :func:`build_section` turns one parsed TOML table into
such a dataclass: it rejects a value that is not a table and unknown keys, and prefixes
every error with where the table came from (``"file.toml [section]"``), so the message
names the file, the section and the key.

(The ``[estimator]`` sections are read by the stand-alone ``estimator`` package, which may
not import the companion; it follows the same rules with its own checks.)
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Mapping
from typing import Any, TypeVar

import numpy as np

from companion.errors import ConfigError

logger = logging.getLogger(__name__)

T = TypeVar("T")


def number(key: str, value: Any, *, positive: bool = False, lo: float | None = None, hi: float | None = None,
           below: float | None = None, allow_inf: bool = False) -> float:
    """A real number (not a bool, not NaN; ``inf`` only with ``allow_inf``) within the given bounds.

    ``positive`` asks for > 0, ``lo``/``hi`` are inclusive bounds, ``below`` an exclusive upper bound.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ConfigError(f"{key} = {value!r} is not a number")
    v = float(value)
    if math.isnan(v) or (math.isinf(v) and not allow_inf):
        raise ConfigError(f"{key} = {value!r} must be a finite number")
    if positive and not v > 0.0:
        raise ConfigError(f"{key} = {value!r} must be positive")
    if lo is not None and v < lo:
        raise ConfigError(f"{key} = {value!r} must be >= {lo:g}")
    if hi is not None and v > hi:
        raise ConfigError(f"{key} = {value!r} must be <= {hi:g}")
    if below is not None and not v < below:
        raise ConfigError(f"{key} = {value!r} must be < {below:g}")
    return v


def integer(key: str, value: Any, *, lo: int, hi: int) -> int:
    """An integer (not a bool) in ``[lo, hi]``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ConfigError(f"{key} = {value!r} must be an integer")
    if not lo <= value <= hi:
        raise ConfigError(f"{key} = {value!r} must be >= {lo} and <= {hi}")
    return int(value)


def boolean(key: str, value: Any) -> bool:
    """``true`` or ``false`` (no truthy strings or numbers)."""
    if not isinstance(value, bool):
        raise ConfigError(f"{key} = {value!r} must be true or false")
    return value


def choice(key: str, value: Any, options: tuple[str, ...]) -> str:
    """One of ``options``."""
    if value not in options:
        raise ConfigError(f"{key} = {value!r} is not one of {', '.join(options)}")
    return value


def vector3(key: str, value: Any, *, positive: bool = False) -> np.ndarray:
    """Three finite numbers (NED); with ``positive`` each > 0."""
    arr = None
    if isinstance(value, (list, tuple, np.ndarray)) and not any(isinstance(x, bool) for x in np.ravel(value)):
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            arr = None
    if arr is None or arr.shape != (3,) or not np.all(np.isfinite(arr)) or (positive and np.any(arr <= 0.0)):
        what = "three positive finite numbers" if positive else "three finite numbers"
        raise ConfigError(f"{key} = {value!r} must be {what} (north, east, down)")
    return arr


def covariance3(key: str, value: Any) -> np.ndarray:
    """A finite, symmetric, positive definite 3x3 matrix (m^2 or (m/s)^2)."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.shape != (3, 3) or not np.all(np.isfinite(arr)):
        raise ConfigError(f"{key} = {value!r} must be a finite 3x3 matrix")
    if not np.allclose(arr, arr.T, atol=1e-12) or np.any(np.linalg.eigvalsh(arr) <= 0.0):
        raise ConfigError(f"{key} = {value!r} must be symmetric positive definite")
    return arr


def text(key: str, value: Any, *, max_len: int = 1000) -> str:
    """A string of at most ``max_len`` characters."""
    if not isinstance(value, str) or len(value) > max_len:
        raise ConfigError(f"{key} = {value!r} must be a string of at most {max_len} characters")
    return value


def table(where: str, value: Any) -> Mapping[str, Any]:
    """``value`` as a TOML table, or an error naming ``where``."""
    if not isinstance(value, Mapping):
        raise ConfigError(f"{where}: must be a table, got {type(value).__name__} {value!r}")
    return value


def array_of_tables(where: str, value: Any, *, max_len: int) -> list[Mapping[str, Any]]:
    """``value`` as an array of at most ``max_len`` tables (``[[...]]``)."""
    if not isinstance(value, list):
        raise ConfigError(f"{where}: must be an array of tables, got {type(value).__name__}")
    if len(value) > max_len:
        raise ConfigError(f"{where}: {len(value)} entries, at most {max_len} allowed")
    for i, item in enumerate(value):
        table(f"{where} #{i + 1}", item)
    return value


def check_keys(where: str, tbl: Mapping[str, Any], allowed: set[str] | frozenset[str]) -> None:
    """Reject keys of ``tbl`` outside ``allowed``, naming ``where`` and the key."""
    unknown = sorted(set(tbl) - set(allowed))
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)} (allowed: {', '.join(sorted(allowed))})")


def field_names(cls: type) -> frozenset[str]:
    """The keys a dataclass section accepts."""
    return frozenset(f.name for f in dataclasses.fields(cls))


def build_section(cls: type[T], raw: Any, where: str, **overrides: Any) -> T:
    """The dataclass ``cls`` from one TOML table, every error prefixed with ``where``.

    Parameters
    ----------
    cls : a frozen dataclass that validates its fields in ``__post_init__``.
    raw : the parsed table (``{}`` when the section is absent).
    where : e.g. ``"configs/x.toml [companion]"``.
    **overrides : values that replace keys of the table (checked like them).

    Raises
    ------
    ConfigError
        ``raw`` is not a table, a key is unknown, or a value is bad; the message starts
        with ``where`` and names the key.
    """
    merged = {**dict(table(where, raw)), **overrides}
    check_keys(where, merged, field_names(cls))
    try:
        return cls(**merged)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None
