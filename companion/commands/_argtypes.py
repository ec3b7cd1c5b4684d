"""argparse value types shared by the subcommands (bad values exit 2 with a clear message)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Callable


def _number(text: str, kind: type) -> float | int:
    try:
        value = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not {'an integer' if kind is int else 'a number'}: {text!r}") from None
    if kind is float and not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
    return value


def integer_at_least(low: int) -> Callable[[str], int]:
    """An integer ``>= low``."""

    def parse(text: str) -> int:
        value = _number(text, int)
        if value < low:
            raise argparse.ArgumentTypeError(f"must be >= {low}, got {text}")
        return value

    return parse


def _float_type(holds: Callable[[float], bool], requirement: str, doc: str) -> Callable[[str], float]:
    """An argparse type: a finite float for which ``holds`` is true (else ``must be <requirement>``)."""

    def parse(text: str) -> float:
        value = _number(text, float)
        if not holds(value):
            raise argparse.ArgumentTypeError(f"must {requirement}, got {text}")
        return value

    parse.__doc__ = doc
    return parse


open_unit_interval = _float_type(lambda v: 0.0 < v < 1.0, "lie in the open interval (0, 1)",
                                 "A float in the open interval (0, 1): a probability, a confidence, an overlap.")
positive_seconds = _float_type(lambda v: v > 0.0, "be > 0 s", "A duration in seconds, > 0 (finite).")
non_negative_seconds = _float_type(lambda v: v >= 0.0, "be >= 0 s", "A duration in seconds, >= 0 (finite).")
positive_number = _float_type(lambda v: v > 0.0, "be > 0", "A finite number > 0 (metres, a speed factor).")
finite_number = _float_type(lambda v: True, "be finite", "Any finite number.")


#: Seeds are numpy SeedSequence entropy: non-negative; 2**63 - 1 keeps them one machine word.
SEED_MAX = 2**63 - 1


def seed(text: str) -> int:
    """A random seed: an integer in [0, 2**63 - 1]."""
    value = _number(text, int)
    if not 0 <= value <= SEED_MAX:
        raise argparse.ArgumentTypeError(f"must be an integer in [0, 2**63 - 1], got {text}")
    return value


def output_file(text: str) -> Path:
    """A file to write: its directory must exist (checked before any work starts)."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a directory, not a file")
    if not path.parent.is_dir():
        raise argparse.ArgumentTypeError(f"directory {path.parent} does not exist")
    return path
