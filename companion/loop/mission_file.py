"""Missions from files: a QGroundControl ``.plan`` (JSON) or a ``QGC WPL 110`` waypoint list.

A ``.plan`` file (QGroundControl's "Plan" format) is JSON: ``fileType`` ``"Plan"``,
``version`` 1, and ``mission`` with ``items`` (each a ``SimpleItem`` with ``command``
(MAV_CMD), ``frame`` (MAV_FRAME), ``params`` (seven numbers or null: param1..4, latitude,
longitude, altitude), ``autoContinue``) and ``plannedHomePosition`` [lat, lon, alt AMSL];
``geoFence`` (``polygons``: ``inclusion`` and ``polygon`` [[lat, lon], ...]; ``circles``:
``inclusion`` and ``circle`` {``center`` [lat, lon], ``radius`` m}) and ``rallyPoints``
(``points`` [[lat, lon, alt], ...]) are read too (kept for the fence work to come).
A ``QGC WPL 110`` file is one item per line, tab separated: ``seq current frame command
p1 p2 p3 p4 lat lon alt autocontinue``; its item 0 is the home position (as QGroundControl,
ArduPilot and MAVProxy write it), not a mission item.

Items in a frame the companion cannot place (local frames, terrain-relative altitude) and
ComplexItems (QGroundControl's surveys and corridor scans, which it expands itself into
simple items only when it uploads them) are refused; so is an empty mission. Every error
is one :class:`~companion.errors.ConfigError` line naming the file and the field.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from companion.errors import ConfigError
from companion.loop.goal_frames import GeoPoint
from companion.mavlink.mission_protocol import GLOBAL_FRAMES, MissionItem

#: Largest mission file read (bytes).
MAX_MISSION_BYTES = 4 << 20
#: Frames a mission item may be in: global (AMSL or relative to home), or MAV_FRAME_MISSION for non-navigation items.
SUPPORTED_FRAMES = GLOBAL_FRAMES | {mavlink2.MAV_FRAME_MISSION}
#: Commands with a position (latitude, longitude, altitude) the companion must place.
NAV_WITH_POSITION = frozenset({
    mavlink2.MAV_CMD_NAV_WAYPOINT, mavlink2.MAV_CMD_NAV_TAKEOFF, mavlink2.MAV_CMD_NAV_LAND,
    mavlink2.MAV_CMD_NAV_LOITER_UNLIM, mavlink2.MAV_CMD_NAV_LOITER_TURNS, mavlink2.MAV_CMD_NAV_LOITER_TIME,
    mavlink2.MAV_CMD_NAV_LOITER_TO_ALT,
})


@dataclass(frozen=True)
class FencePolygon:
    inclusion: bool
    vertices: tuple[tuple[float, float], ...]   # (lat, lon) degrees


@dataclass(frozen=True)
class FenceCircle:
    inclusion: bool
    center: tuple[float, float]                 # (lat, lon) degrees
    radius_m: float


@dataclass(frozen=True)
class MissionPlan:
    """A mission as read from a file (or downloaded): its items, the planned home, fence and rally points."""

    source: str
    items: tuple[MissionItem, ...]
    planned_home: GeoPoint | None = None
    polygons: tuple[FencePolygon, ...] = ()
    circles: tuple[FenceCircle, ...] = ()
    rally: tuple[GeoPoint, ...] = ()
    notes: tuple[str, ...] = field(default=())


def _number(where: str, value: Any, *, allow_null: bool = False) -> float:
    if value is None and allow_null:
        return math.nan
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{where}: {value!r} is not a finite number")
    return float(value)


def check_items(source: str, items: list[MissionItem]) -> None:
    """Refuse an empty mission and items the companion cannot place (naming file, item and field)."""
    if not items:
        raise ConfigError(f"{source}: mission.items: the mission is empty")
    for item in items:
        where = f"{source}: mission item {item.seq + 1} (MAV_CMD {item.command})"
        if item.frame not in SUPPORTED_FRAMES:
            frame = mavlink2.enums["MAV_FRAME"].get(item.frame)
            raise ConfigError(f"{where}: frame {item.frame} ({frame.name if frame else 'unknown'}) is not supported "
                              f"(global frames with AMSL or home-relative altitude only)")
        if item.command in NAV_WITH_POSITION and item.frame in GLOBAL_FRAMES:
            if not (-90.0 <= item.x <= 90.0 and -180.0 <= item.y <= 180.0) or not math.isfinite(item.z):
                raise ConfigError(f"{where}: latitude/longitude/altitude {item.x}, {item.y}, {item.z} out of range")
            if item.command == mavlink2.MAV_CMD_NAV_WAYPOINT and item.x == 0.0 and item.y == 0.0:
                raise ConfigError(f"{where}: a waypoint at latitude 0, longitude 0 (no position given)")
        if item.command == mavlink2.MAV_CMD_DO_JUMP:
            target, repeat = item.params[0], item.params[1]
            if not (math.isfinite(target) and target == int(target) and 0 <= target < len(items)):
                raise ConfigError(f"{where}: DO_JUMP to item {target:g}: no such item (the mission has items "
                                  f"1 to {len(items)})")
            if int(target) == item.seq:
                raise ConfigError(f"{where}: DO_JUMP to itself")
            if not (math.isfinite(repeat) and repeat == int(repeat) and repeat >= -1):
                raise ConfigError(f"{where}: DO_JUMP repeat {repeat:g}: a whole number of times, or -1 for ever")


def _read_text(path: Path) -> str:
    try:
        with path.open("rb") as f:
            raw = f.read(MAX_MISSION_BYTES + 1)
    except FileNotFoundError:
        raise ConfigError(f"{path}: mission file not found") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a directory, not a mission file") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read mission file: {exc.strerror or exc}") from None
    if len(raw) > MAX_MISSION_BYTES:
        raise ConfigError(f"{path}: mission file larger than {MAX_MISSION_BYTES} bytes")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not a UTF-8 text file (byte offset {exc.start})") from None


def read_mission_file(path: str | Path, *, fence_only: bool = False) -> MissionPlan:
    """A ``.plan`` or ``QGC WPL 110`` file (told apart by its first line), checked (see the module docstring).

    ``fence_only``: the file is read for its geofence; a ``.plan`` without mission items is accepted.
    """
    path = Path(path)
    text = _read_text(path)
    if text.lstrip().startswith("QGC WPL"):
        if fence_only:
            raise ConfigError(f"{path}: a QGC WPL file holds no geofence (a QGroundControl .plan does)")
        return parse_wpl(text, str(path))
    return parse_plan(text, str(path), fence_only=fence_only)


def parse_plan(text: str, source: str = "<plan>", *, fence_only: bool = False) -> MissionPlan:
    """A QGroundControl ``.plan`` file's text."""
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{source}: not valid JSON (line {exc.lineno} column {exc.colno}: {exc.msg}); "
                          f"a truncated .plan file?") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: not a .plan file (a JSON object is expected)")
    if data.get("fileType") != "Plan":
        raise ConfigError(f"{source}: fileType: {data.get('fileType')!r}, expected 'Plan' (a QGroundControl .plan file)")
    if data.get("version") != 1:
        raise ConfigError(f"{source}: version: {data.get('version')!r}, only version 1 is supported")
    mission = data.get("mission")
    if not isinstance(mission, dict):
        raise ConfigError(f"{source}: mission: missing, or not an object")
    raw_items = mission.get("items")
    if not isinstance(raw_items, list):
        raise ConfigError(f"{source}: mission.items: missing, or not a list")
    items: list[MissionItem] = []
    for i, raw in enumerate(raw_items):
        where = f"{source}: mission.items[{i}]"
        if not isinstance(raw, dict):
            raise ConfigError(f"{where}: not an object")
        if raw.get("type") != "SimpleItem":
            raise ConfigError(f"{where}: type {raw.get('type')!r}: only SimpleItem is supported (a survey or "
                              f"corridor scan: upload it from QGroundControl, then use --mission vehicle)")
        command, frame = raw.get("command"), raw.get("frame")
        if not isinstance(command, int) or isinstance(command, bool) or not isinstance(frame, int) or isinstance(frame, bool):
            raise ConfigError(f"{where}: command and frame must be integers (MAV_CMD, MAV_FRAME)")
        params = raw.get("params")
        if not isinstance(params, list) or len(params) != 7:
            raise ConfigError(f"{where}.params: seven values expected (param1..4, latitude, longitude, altitude)")
        p = [_number(f"{where}.params[{k}]", v, allow_null=True) for k, v in enumerate(params)]
        items.append(MissionItem(seq=len(items), frame=frame, command=command, params=(p[0], p[1], p[2], p[3]),
                                 x=0.0 if math.isnan(p[4]) else p[4], y=0.0 if math.isnan(p[5]) else p[5],
                                 z=0.0 if math.isnan(p[6]) else p[6],
                                 autocontinue=1 if raw.get("autoContinue", True) else 0))
    items = _jumps_to_seq(source, items, [raw.get("doJumpId", i + 1) for i, raw in enumerate(raw_items)])
    if items or not fence_only:
        check_items(source, items)
    home = None
    planned = mission.get("plannedHomePosition")
    if planned is not None:
        if not isinstance(planned, list) or len(planned) != 3:
            raise ConfigError(f"{source}: mission.plannedHomePosition: [latitude, longitude, altitude] expected")
        home = GeoPoint(*(_number(f"{source}: mission.plannedHomePosition", v) for v in planned))
    polygons, circles = _fence(data.get("geoFence"), source)
    rally = []
    for k, point in enumerate((data.get("rallyPoints") or {}).get("points", []) or []):
        if not isinstance(point, list) or len(point) != 3:
            raise ConfigError(f"{source}: rallyPoints.points[{k}]: [latitude, longitude, altitude] expected")
        rally.append(GeoPoint(*(_number(f"{source}: rallyPoints.points[{k}]", v) for v in point)))
    return MissionPlan(source, tuple(items), home, polygons, circles, tuple(rally))


def _fence(fence: Any, source: str) -> tuple[tuple[FencePolygon, ...], tuple[FenceCircle, ...]]:
    if fence is None:
        return (), ()
    if not isinstance(fence, dict):
        raise ConfigError(f"{source}: geoFence: not an object")
    polygons, circles = [], []
    for k, poly in enumerate(fence.get("polygons", []) or []):
        where = f"{source}: geoFence.polygons[{k}]"
        vertices = poly.get("polygon") if isinstance(poly, dict) else None
        if not isinstance(vertices, list) or len(vertices) < 3:
            raise ConfigError(f"{where}.polygon: at least three [latitude, longitude] vertices expected")
        pts = []
        for v in vertices:
            if not isinstance(v, list) or len(v) != 2:
                raise ConfigError(f"{where}.polygon: [latitude, longitude] pairs expected")
            pts.append((_number(f"{where}.polygon", v[0]), _number(f"{where}.polygon", v[1])))
        polygons.append(FencePolygon(bool(poly.get("inclusion", True)), tuple(pts)))
    for k, circ in enumerate(fence.get("circles", []) or []):
        where = f"{source}: geoFence.circles[{k}]"
        c = circ.get("circle") if isinstance(circ, dict) else None
        if not isinstance(c, dict) or not isinstance(c.get("center"), list) or len(c["center"]) != 2:
            raise ConfigError(f"{where}.circle: {{center: [latitude, longitude], radius: m}} expected")
        radius = _number(f"{where}.circle.radius", c.get("radius"))
        if radius <= 0.0:
            raise ConfigError(f"{where}.circle.radius: {radius:g} m, must be positive")
        circles.append(FenceCircle(bool(circ.get("inclusion", True)),
                                   (_number(f"{where}.circle.center", c["center"][0]),
                                    _number(f"{where}.circle.center", c["center"][1])), radius))
    return tuple(polygons), tuple(circles)


def parse_wpl(text: str, source: str = "<wpl>") -> MissionPlan:
    """A ``QGC WPL 110`` file's text (item 0 is home)."""
    lines = [ln for ln in text.splitlines() if ln.strip()]
    header = lines[0].split() if lines else []
    if header[:2] != ["QGC", "WPL"] or len(header) != 3:
        raise ConfigError(f"{source}: line 1: 'QGC WPL 110' expected")
    if header[2] != "110":
        raise ConfigError(f"{source}: line 1: version {header[2]}, only QGC WPL 110 is supported")
    home = None
    items: list[MissionItem] = []
    for n, line in enumerate(lines[1:], start=2):
        fields = line.split("\t") if "\t" in line else line.split()
        if len(fields) != 12:
            raise ConfigError(f"{source}: line {n}: 12 fields expected (seq current frame command p1 p2 p3 p4 "
                              f"lat lon alt autocontinue), found {len(fields)}")
        try:
            seq, current, frame, command = (int(f) for f in fields[:4])
            p1, p2, p3, p4, lat, lon, alt = (float(f) for f in fields[4:11])
            autocontinue = int(fields[11])
        except ValueError:
            raise ConfigError(f"{source}: line {n}: not numbers") from None
        if not all(math.isfinite(v) for v in (lat, lon, alt)):
            raise ConfigError(f"{source}: line {n}: latitude, longitude and altitude must be finite")
        if n == 2 and seq == 0:
            home = GeoPoint(lat, lon, alt)   # item 0: home (QGroundControl, ArduPilot, MAVProxy)
            continue
        items.append(MissionItem(seq=len(items), frame=frame, command=command, params=(p1, p2, p3, p4),
                                 x=lat, y=lon, z=alt, current=0, autocontinue=autocontinue))
    if home is not None:    # item numbers count home as item 0, as the file does
        items = _jumps_to_seq(source, items, [i + 1 for i in range(len(items))])
    check_items(source, items)
    return MissionPlan(source, tuple(items), home)


def _jumps_to_seq(source: str, items: list[MissionItem], numbers: list) -> list[MissionItem]:
    """Items whose DO_JUMP targets, given in a file's own item numbers (``numbers[k]`` is item k's:
    QGroundControl's ``doJumpId``, or a WPL line's seq where home is item 0), are the item seqs
    the vehicle numbers them by (0 the first mission item); a number that names no item is an error."""
    seq_of = {n: k for k, n in enumerate(numbers) if isinstance(n, int) and not isinstance(n, bool)}
    out = []
    for item in items:
        if item.command == mavlink2.MAV_CMD_DO_JUMP and math.isfinite(item.params[0]):
            target = item.params[0]
            seq = seq_of.get(int(target)) if target == int(target) else None
            if seq is None:
                raise ConfigError(f"{source}: mission item {item.seq + 1} (MAV_CMD {item.command}): DO_JUMP to "
                                  f"item {target:g}: no item has that number")
            item = dataclasses.replace(item, params=(float(seq), *item.params[1:]))
        out.append(item)
    return out
