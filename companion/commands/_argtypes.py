"""argparse value types shared by the subcommands (bad values exit 2 with a clear message)."""

from __future__ import annotations

import argparse
from typing import Callable


def _number(text: str, kind: type) -> float | int:
    try:
        return kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not {'an integer' if kind is int else 'a number'}: {text!r}") from None


def integer_at_least(low: int) -> Callable[[str], int]:
    """An integer ``>= low``."""

    def parse(text: str) -> int:
        value = _number(text, int)
        if value < low:
            raise argparse.ArgumentTypeError(f"must be >= {low}, got {text}")
        return value

    return parse


def open_unit_interval(text: str) -> float:
    """A float in the open interval (0, 1): a probability, a confidence, an overlap."""
    value = _number(text, float)
    if not 0.0 < value < 1.0:
        raise argparse.ArgumentTypeError(f"must lie in the open interval (0, 1), got {text}")
    return value


def positive_seconds(text: str) -> float:
    """A duration in seconds, > 0."""
    value = _number(text, float)
    if not value > 0.0:
        raise argparse.ArgumentTypeError(f"must be > 0 s, got {text}")
    return value


def non_negative_seconds(text: str) -> float:
    """A duration in seconds, >= 0 and finite (0: none)."""
    value = _number(text, float)
    if not 0.0 <= value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be >= 0 s and finite, got {text}")
    return value
