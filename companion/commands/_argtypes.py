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


def integer_between(low: int, high: int, why: str = "") -> Callable[[str], int]:
    """An integer in ``[low, high]``; ``why`` (e.g. ``"the documented maximum"``) is said beside the bound."""

    def parse(text: str) -> int:
        value = _number(text, int)
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be an integer from {low} to {high}{f' ({why})' if why else ''}, "
                                             f"got {text}")
        return value

    return parse


def seconds_up_to(high: float, why: str = "") -> Callable[[str], float]:
    """A duration in seconds, > 0 and at most ``high`` (finite)."""

    def parse(text: str) -> float:
        value = _number(text, float)
        if not 0.0 < value <= high:
            raise argparse.ArgumentTypeError(f"must be > 0 s and at most {high:g} s{f' ({why})' if why else ''}, "
                                             f"got {text}")
        return value

    parse.__doc__ = f"A duration in seconds, in (0, {high:g}]."
    return parse


def seconds_between(low: float, high: float) -> Callable[[str], float]:
    """A duration in seconds in ``[low, high]`` (finite)."""

    def parse(text: str) -> float:
        value = _number(text, float)
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be from {low:g} to {high:g} s, got {text}")
        return value

    parse.__doc__ = f"A duration in seconds, in [{low:g}, {high:g}]."
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
tlog_megabytes = _float_type(lambda v: v == 0.0 or v >= 0.1, "be 0 (no bound) or at least 0.1 MB",
                             "A tlog's disk bound in MB (10^6 bytes): 0 for none, else at least 0.1.")


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


def connection_string(text: str) -> str:
    """A MAVLink connection string, checked where it can be before any work starts: a serial
    device (``/dev/ttyACM0``, ``/dev/ttyUSB0,921600``, ``serial:DEVICE:BAUD``) must exist and
    its baud rate be an integer (:func:`companion.mavlink.connection.serial_device`)."""
    from companion.errors import LinkError
    from companion.mavlink.connection import serial_device

    try:
        serial_device(text)
    except LinkError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def shipped_scenarios() -> list[str]:
    """The names of the scenarios shipped with the package (``configs/*.toml``, installed as ``companion.scenarios``)."""
    from importlib import resources

    return sorted(p.name[:-5] for p in resources.files("companion.scenarios").iterdir() if p.name.endswith(".toml"))


def scenario_file(text: str) -> str:
    """A scenario: a TOML file's path, or the name of a shipped one (``antipodal``, ``corridor.toml``),
    resolved the same way by every command; from a wheel in any directory too."""
    from importlib import resources

    path = Path(text)
    if path.is_file():
        return str(path)
    name = text[:-5] if text.endswith(".toml") else text
    if "/" not in text and name in shipped_scenarios():
        return str(resources.files("companion.scenarios") / f"{name}.toml")
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a directory, not a scenario file")
    raise argparse.ArgumentTypeError(f"{text}: no such scenario file, and not a shipped scenario "
                                     f"({', '.join(shipped_scenarios())})")


def goal_spec(text: str):
    """A goal ``FRAME:A,B,C`` (``companion.loop.goal_frames.GOAL_SYNTAX``) as a ``GoalSpec``."""
    from companion.errors import ConfigError
    from companion.loop.goal_frames import parse_goal

    try:
        return parse_goal(text)
    except ConfigError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def mission_source(text: str):
    """``vehicle`` (download the autopilot's mission), or a ``.plan`` / ``QGC WPL 110`` file read and checked now."""
    if text == "vehicle":
        return text
    from companion.errors import ConfigError
    from companion.loop.mission_file import read_mission_file

    try:
        return read_mission_file(text)
    except ConfigError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def fence_file(text: str):
    """``vehicle`` (download the autopilot's fence), or a ``.plan`` file with a geofence (``geoFence``
    polygons or circles), read and checked now."""
    if text == "vehicle":
        return text
    from companion.errors import ConfigError
    from companion.loop.mission_file import read_mission_file

    try:
        plan = read_mission_file(text, fence_only=True)
    except ConfigError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    if not plan.polygons and not plan.circles:
        raise argparse.ArgumentTypeError(f"{text}: no geofence in it (geoFence polygons or circles)")
    return plan
