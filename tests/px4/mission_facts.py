"""Measure PX4 SITL (SIH) flying a mission in AUTO.MISSION: the facts mavsim's mission flight imitates.

Usage::

    python -m tests.px4.mission_facts WORK_DIR [--json FILE]

Starts PX4 SITL (``tests.px4.sitl.Sitl``), uploads on its ground-station link, as a ground
station does, the mission of ``tests/mavsim/test_mavsim_mission_flight.py`` (a takeoff to 5 m,
a waypoint 20 m north, DO_CHANGE_SPEED 2 m/s, a waypoint 20 m east of it, one back west at
8 m with a 3 m acceptance radius, a landing at home), arms, starts it with
MAV_CMD_MISSION_START and listens on both links until PX4 disarms (at most 150 s). Prints,
and writes as JSON: the mode changes, MISSION_CURRENT and MISSION_ITEM_REACHED as they
came, the position at each item reached, each leg's largest and median horizontal speed,
and how often each message arrived on the offboard link (the one a companion listens on).
Needs the PX4 SITL build (``PX4_SITL_DIR`` or ``../shared/px4-sitl``); about 2 minutes.
"""

from __future__ import annotations

import argparse
import collections
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from tests.px4.gcs import GroundStation, Item
from tests.px4.sitl import OFFBOARD_URL, Sitl

EARTH_RADIUS_M = 6378137.0


def _latlon(home: tuple[float, float], north: float, east: float) -> tuple[int, int]:
    lat0, lon0 = home
    lat = lat0 + math.degrees(north / EARTH_RADIUS_M)
    lon = lon0 + math.degrees(east / (EARTH_RADIUS_M * math.cos(math.radians(lat0))))
    return round(lat * 1e7), round(lon * 1e7)


def _mission():
    from pymavlink.dialects.v20 import common as m2

    rel, nan = m2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, math.nan
    # (command, frame, params, north, east, alt above home); None: no position (sent as 0, 0).
    # PX4 takes a position literally: a takeoff item at latitude and longitude 0 climbed, then
    # flew off towards (0, 0) at the cruise speed (measured).
    return [
        (m2.MAV_CMD_NAV_TAKEOFF, rel, (0, 0, 0, nan), 0.0, 0.0, 5.0),   # at home, as QGroundControl writes it
        (m2.MAV_CMD_NAV_WAYPOINT, rel, (0, 0, 0, nan), 20.0, 0.0, 5.0),
        (m2.MAV_CMD_DO_CHANGE_SPEED, m2.MAV_FRAME_MISSION, (1, 2.0, -1, 0), None, None, 0.0),
        (m2.MAV_CMD_NAV_WAYPOINT, rel, (0, 0, 0, nan), 20.0, 20.0, 5.0),
        (m2.MAV_CMD_NAV_WAYPOINT, rel, (0, 3.0, 0, nan), 0.0, 20.0, 8.0),
        (m2.MAV_CMD_NAV_LAND, rel, (0, 0, 0, nan), 0.0, 0.0, 0.0),
    ]


def measure(work_dir: Path, timeout_s: float = 150.0) -> dict:
    """Fly the mission on PX4 SITL and return what was seen (see the module docstring)."""
    from pymavlink import mavutil

    out: dict = {"events": [], "positions": [], "offboard_link_counts": {}}
    with Sitl(work_dir), GroundStation() as station:
        gcs = station.conn
        onboard = mavutil.mavlink_connection(OFFBOARD_URL, source_system=245, source_component=191)
        try:
            station.wait_heartbeat()
            home = station.wait_home()[:2]
            items = [Item(command, frame, params, *((0, 0) if north is None else _latlon(home, north, east)), alt)
                     for command, frame, params, north, east, alt in _mission()]
            out["upload_ack"] = station.upload(items)
            for _ in range(20):
                gcs.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
                ack = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=1)
                if ack is not None and ack.command == 400 and ack.result == 0:
                    break
                time.sleep(0.5)
            gcs.mav.command_long_send(1, 1, 300, 0, 0, 0, 0, 0, 0, 0, 0)           # MISSION_START
            start = time.monotonic()
            counts: collections.Counter = collections.Counter()
            last_mode = None
            while time.monotonic() - start < timeout_s:
                t = round(time.monotonic() - start, 3)
                while (m := onboard.recv_match(blocking=False)) is not None:
                    counts[m.get_type()] += 1
                    if m.get_type() in ("MISSION_CURRENT", "MISSION_ITEM_REACHED"):
                        out["events"].append([t, "onboard " + m.get_type(), m.seq, getattr(m, "mission_state", None)])
                msg = gcs.recv_match(blocking=True, timeout=0.05)
                if msg is None:
                    continue
                kind = msg.get_type()
                if kind == "LOCAL_POSITION_NED":
                    out["positions"].append([t, msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz])
                elif kind in ("MISSION_CURRENT", "MISSION_ITEM_REACHED"):
                    out["events"].append([t, kind, msg.seq, getattr(msg, "total", None), getattr(msg, "mission_state", None),
                                          getattr(msg, "mission_mode", None)])
                elif kind == "STATUSTEXT":
                    out["events"].append([t, kind, msg.text])
                elif kind == "COMMAND_ACK":
                    out["events"].append([t, kind, msg.command, msg.result])
                elif kind == "HEARTBEAT" and msg.get_srcComponent() == 1:
                    mode = [msg.custom_mode >> 16 & 0xFF, msg.custom_mode >> 24 & 0xFF, bool(msg.base_mode & 128),
                            msg.system_status]
                    if mode != last_mode:
                        out["events"].append([t, kind, mode])
                        last_mode = mode
                        if not mode[2] and t > 5.0:
                            break
            out["flown_s"] = round(time.monotonic() - start, 1)
            out["offboard_link_counts"] = dict(counts)
        finally:
            onboard.close()
    return out


def summary(data: dict) -> dict:
    """Where each item was reached and each leg's speeds, from :func:`measure`'s record."""
    pos = np.array(data["positions"])
    reached = [(t, seq) for t, kind, seq, *_ in (e for e in data["events"] if len(e) >= 3)
               if kind == "MISSION_ITEM_REACHED"]
    out = {"reached": [], "legs": []}
    for t, seq in reached:
        p = pos[np.argmin(np.abs(pos[:, 0] - t))]
        out["reached"].append({"seq": seq, "t_s": t, "position_ned_m": [round(float(x), 2) for x in p[1:4]]})
    speed = np.hypot(pos[:, 4], pos[:, 5])
    for (t0, a), (t1, b) in zip(reached, reached[1:]):
        leg = speed[(pos[:, 0] > t0) & (pos[:, 0] < t1)]
        if leg.size:
            out["legs"].append({"from": a, "to": b, "max_mps": round(float(leg.max()), 2),
                                "median_mps": round(float(np.median(leg)), 2)})
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tests.px4.mission_facts", description=__doc__.splitlines()[0])
    ap.add_argument("work_dir", type=Path, help="a directory for PX4's files")
    ap.add_argument("--json", type=Path, default=None, help="write the record and its summary here")
    args = ap.parse_args(argv)
    data = measure(args.work_dir)
    data["summary"] = summary(data)
    for event in data["events"]:
        print(event)
    print(json.dumps(data["summary"], indent=1))
    print("offboard link, messages in", data["flown_s"], "s:", data["offboard_link_counts"])
    if args.json is not None:
        args.json.write_text(json.dumps(data))
    return 0


if __name__ == "__main__":
    sys.exit(main())
