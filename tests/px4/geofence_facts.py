"""Measure PX4 SITL (SIH) at its failsafe geofence: the facts mavsim's geofence imitates.

Usage::

    python -m tests.px4.geofence_facts WORK_DIR [--json FILE] [--hor 15] [--ver 10]

Starts PX4 SITL (``tests.px4.sitl.Sitl``) and, on its ground link as a ground station does,
reads the geofence parameters (GF_ACTION, GF_MAX_HOR_DIST, GF_MAX_VER_DIST, GF_PREDICT,
GF_COUNT, GF_SOURCE, GF_ALTMODE) with PARAM_REQUEST_READ, sets GF_MAX_HOR_DIST and
GF_MAX_VER_DIST (PARAM_SET), arms and takes off to 5 m (MAV_CMD_NAV_TAKEOFF). Then, as a
companion on the offboard link, two legs in OFFBOARD: a climb at 1 m/s until PX4 leaves
OFFBOARD or 20 s pass, and (back in OFFBOARD after a 1 m/s descent to 5 m, if PX4 lets it)
north at 2 m/s the same way. Prints, and writes as JSON: the parameters, the mode changes,
PX4's texts, and for each leg where PX4 left OFFBOARD and how far from home (horizontal and
up, its estimate) the vehicle was then and at its farthest. Needs the PX4 SITL build
(``PX4_SITL_DIR`` or ``../shared/px4-sitl``); about 2 minutes.
"""

from __future__ import annotations

import argparse
import json
import math
import struct
import sys
import time
from pathlib import Path

from tests.px4.gcs import GroundStation
from tests.px4.sitl import OFFBOARD_URL, Sitl

PARAMS = ("GF_ACTION", "GF_MAX_HOR_DIST", "GF_MAX_VER_DIST", "GF_PREDICT", "GF_COUNT", "GF_SOURCE", "GF_ALTMODE")
OFFBOARD_MAIN = 6


def _param(gcs, name: str, timeout_s: float = 5.0) -> float | None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        gcs.mav.param_request_read_send(1, 1, name.encode(), -1)
        msg = gcs.recv_match(type="PARAM_VALUE", blocking=True, timeout=1)
        if msg is not None and msg.param_id == name:
            if 1 <= msg.param_type <= 6:     # an integer: PX4 sends its bits in the float field
                return struct.unpack("<i", struct.pack("<f", msg.param_value))[0]
            return msg.param_value
    return None


def measure(work_dir: Path, hor_m: float, ver_m: float) -> dict:
    from pymavlink import mavutil
    from pymavlink.dialects.v20 import common as m2

    out: dict = {"params_default": {}, "events": [], "legs": []}
    with Sitl(work_dir), GroundStation() as station:
        gcs = station.conn
        onboard = mavutil.mavlink_connection(OFFBOARD_URL, source_system=1, source_component=191)
        start = time.monotonic()
        state = {"mode": None, "armed": False, "pos": None, "home": None}

        def pump(dt: float = 0.05) -> None:
            while onboard.recv_match(blocking=False) is not None:   # the offboard link learns PX4's address
                pass
            end = time.monotonic() + dt
            while True:
                msg = gcs.recv_match(blocking=True, timeout=max(0.0, end - time.monotonic()))
                if msg is None:
                    break
                t = round(time.monotonic() - start, 2)
                kind = msg.get_type()
                out.setdefault("gcs_counts", {})[kind] = out.get("gcs_counts", {}).get(kind, 0) + 1
                if kind == "STATUSTEXT":
                    out["events"].append([t, "text", msg.text])
                elif kind == "HEARTBEAT" and msg.get_srcComponent() == 1:
                    mode = (msg.custom_mode >> 16 & 0xFF, msg.custom_mode >> 24 & 0xFF)
                    armed = bool(msg.base_mode & 128)
                    if (mode, armed) != (state["mode"], state["armed"]):
                        out["events"].append([t, "mode", list(mode), armed])
                    state["mode"], state["armed"] = mode, armed
                elif kind == "LOCAL_POSITION_NED":
                    state["pos"] = (msg.x, msg.y, msg.z)
                elif kind == "HOME_POSITION":
                    state["home"] = (msg.x, msg.y, msg.z)
                elif kind == "COMMAND_ACK":
                    out["events"].append([t, "ack", msg.command, msg.result])
                if time.monotonic() >= end:
                    break

        def away() -> tuple[float, float]:
            (x, y, z), (hx, hy, hz) = state["pos"], state["home"]
            return round(math.hypot(x - hx, y - hy), 2), round(-(z - hz), 2)

        def offboard_leg(name: str, velocity: tuple[float, float, float], max_s: float, until_up: float | None = None):
            leg = {"name": name, "velocity": velocity}
            t0 = time.monotonic()
            sent_mode = False
            farthest = (0.0, 0.0)
            while time.monotonic() - t0 < max_s:
                onboard.mav.set_position_target_local_ned_send(int((time.monotonic() - start) * 1e3), 1, 1, 1, 0b110111000111,
                                                               0, 0, 0, *velocity, 0, 0, 0, 0, 0)
                pump(0.05)
                if time.monotonic() - t0 > 0.5 and not sent_mode:
                    gcs.mav.command_long_send(1, 1, m2.MAV_CMD_DO_SET_MODE, 0, 1, OFFBOARD_MAIN, 0, 0, 0, 0, 0)
                    sent_mode = True
                if state["pos"] is None or state["home"] is None:
                    continue
                h, up = away()
                farthest = (max(farthest[0], h), max(farthest[1], up))
                if state["mode"][0] == OFFBOARD_MAIN and "entered_s" not in leg:
                    leg["entered_s"] = round(time.monotonic() - start, 2)
                if "entered_s" in leg and state["mode"][0] != OFFBOARD_MAIN and "left_s" not in leg:
                    leg["left_s"], leg["left_at_m"], leg["left_to"] = round(time.monotonic() - start, 2), [h, up], list(state["mode"])
                if until_up is not None and up <= until_up:
                    break
                if "left_s" in leg and time.monotonic() - start > leg["left_s"] + 8.0:
                    break
            if state["pos"] is not None:
                leg["end_at_m"] = list(away())
            leg["farthest_m"] = list(farthest)
            out["legs"].append(leg)

        try:
            station.wait_heartbeat()
            station.wait_home()
            for name in PARAMS:
                out["params_default"][name] = _param(gcs, name)
            for name, value in (("GF_MAX_HOR_DIST", hor_m), ("GF_MAX_VER_DIST", ver_m)):
                gcs.mav.param_set_send(1, 1, name.encode(), value, m2.MAV_PARAM_TYPE_REAL32)
                time.sleep(0.3)
            out["params_set"] = {n: _param(gcs, n) for n in ("GF_MAX_HOR_DIST", "GF_MAX_VER_DIST")}
            gcs.mav.command_long_send(1, 1, 512, 0, 242, 0, 0, 0, 0, 0, 0)      # HOME_POSITION
            for _ in range(30):
                gcs.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
                pump(1.0)
                if state["armed"]:
                    break
            gcs.mav.command_long_send(1, 1, m2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, math.nan, math.nan, math.nan, math.nan)
            t_to = time.monotonic()
            while time.monotonic() - t_to < 20.0:
                gcs.mav.command_long_send(1, 1, 512, 0, 242, 0, 0, 0, 0, 0, 0)
                pump(0.5)
                if state["home"] is not None and state["pos"] is not None and away()[1] > 2.0 \
                        and state["mode"] == (4, 3):   # AUTO.LOITER: the takeoff is over
                    break
            pump(3.0)
            offboard_leg("climb", (0.0, 0.0, -1.0), 25.0)
            offboard_leg("descend", (0.0, 0.0, 1.0), 25.0, until_up=5.0)
            offboard_leg("north", (2.0, 0.0, 0.0), 30.0)
            pump(3.0)
        finally:
            onboard.close()
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tests.px4.geofence_facts", description=__doc__.splitlines()[0])
    ap.add_argument("work_dir", type=Path, help="a directory for PX4's files")
    ap.add_argument("--json", type=Path, default=None, help="write the record here")
    ap.add_argument("--hor", type=float, default=15.0, help="GF_MAX_HOR_DIST to set (m)")
    ap.add_argument("--ver", type=float, default=10.0, help="GF_MAX_VER_DIST to set (m)")
    args = ap.parse_args(argv)
    data = measure(args.work_dir, args.hor, args.ver)
    print(json.dumps({k: v for k, v in data.items() if k != "events"}, indent=1))
    for event in data["events"]:
        print(event)
    if args.json is not None:
        args.json.write_text(json.dumps(data))
    return 0


if __name__ == "__main__":
    sys.exit(main())
