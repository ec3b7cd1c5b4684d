"""A fence uploaded to PX4 SITL as QGroundControl does, downloaded and kept by ``fly --fence vehicle``.

The fence of :mod:`tests.loop.test_fence_flight` (an inclusion rectangle and a 4 m exclusion
square across the first leg) is uploaded on PX4's ground link (mission type FENCE: the
polygons' vertices with their count in param1, MISSION_COUNT / MISSION_REQUEST_INT /
MISSION_ITEM_INT / MISSION_ACK), then the companion uploads a two-waypoint mission
(``--mission FILE``), downloads the fence, arms, takes off and flies the mission round the
square. PX4 boots with its failsafe fence about home set (GF_MAX_HOR_DIST 40 m,
GF_MAX_VER_DIST 8 m), which the companion reads with the fence. About 1.5 minutes.

Asserted: PX4 accepts the fence; the flight exits 0 with both waypoints reached; the
companion downloaded the fence, read PX4's limits and placed all three (the two polygons, the
circle about home, the ceiling) before engaging; PX4's own estimate (SIH: within centimetres
of its truth) keeps the drone's radius inside the fence and under the ceiling at every sample
while airborne; PX4 logged no failsafe.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink.tlog import read_tlog
from tests.loop.test_fence_flight import EXCLUSION, INCLUSION, LOCAL, _latlon
from tests.px4.gcs import GroundStation, Item
from tests.px4.sitl import PARAMS, REPO, Sitl, raise_priority, sitl_dir
from tests.support.missions import plan_dict

pytestmark = [pytest.mark.px4]

#: PX4's failsafe fence about home for this flight: wide and high enough for the mission (m)
LIMITS = {"GF_MAX_HOR_DIST": 40.0, "GF_MAX_VER_DIST": 8.0}


def upload_fence() -> int:
    """Upload the fence on PX4's ground link as a ground station does; PX4's MISSION_ACK result."""
    items = []
    for cmd, ring in ((mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, INCLUSION),
                      (mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION, EXCLUSION)):
        items += [Item(cmd, mavlink2.MAV_FRAME_GLOBAL, (len(ring), 0, 0, 0), int(round(lat * 1e7)), int(round(lon * 1e7)), 0.0)
                  for lat, lon in _latlon(ring)]
    with GroundStation() as gcs:
        gcs.wait_heartbeat()
        return gcs.upload(items, mavlink2.MAV_MISSION_TYPE_FENCE)


def test_a_fence_uploaded_to_px4_is_downloaded_and_kept_through_a_mission(tmp_path):
    if sitl_dir() is None:
        pytest.fail("no PX4 SITL build: set PX4_SITL_DIR or put one at ../shared/px4-sitl (start-sih inside)")
    plan = tmp_path / "mission.plan"
    plan.write_text(json.dumps(plan_dict([(24.0, 0.0, -5.0), (24.0, 6.0, -5.0)], final=None)))
    tlog = tmp_path / "flight.tlog"
    with Sitl(tmp_path / "px4", params={**PARAMS, **LIMITS}) as sitl:
        assert upload_fence() == mavlink2.MAV_MISSION_ACCEPTED
        fly = subprocess.run([sys.executable, "-m", "companion.cli", "fly", "--connect", "udpin:127.0.0.1:14540",
                              "--scenario", str(REPO / "configs" / "antipodal_px4.toml"), "--mission", str(plan),
                              "--fence", "vehicle", "--arm", "--exit-after-goal", "1", "--tlog", str(tlog),
                              "--duration", "150", "--json"],
                             capture_output=True, text=True, cwd=REPO, timeout=300, preexec_fn=raise_priority)
        px4_log = (sitl.work_dir / "px4.log").read_text(errors="replace")
    assert fly.returncode == 0, fly.stderr[-2000:]
    report = json.loads(fly.stdout)
    texts = [text for _, text in report["events"]]
    print({k: report.get(k) for k in ("outcome", "mission_items_reached", "min_fence_clearance_m", "vehicle_mode")})
    assert report["mission_items_reached"] == [1, 2]
    placed = "companion: fence of 3 zones placed, ceiling 8 m above home"
    assert texts.index(placed) < next(i for i, t in enumerate(texts) if t.startswith("ENGAGED")), texts
    pos = np.array([(m.x, m.y, m.z) for _, m in read_tlog(tlog)
                    if m.get_type() == "LOCAL_POSITION_NED" and m.get_srcSystem() == 1])
    airborne = pos[pos[:, 2] < -2.0]
    clearance = min(LOCAL.clearance(p) for p in airborne)
    print(f"smallest distance inside the fence, PX4's estimate while airborne: {clearance:.3f} m")
    assert clearance >= 0.5, clearance                       # the drone's radius (configs/antipodal_px4.toml)
    home = [m for _, m in read_tlog(tlog) if m.get_type() == "HOME_POSITION"][-1]
    print(f"highest above home, PX4's estimate: {-(airborne[:, 2] - home.z).min():.3f} m")
    assert -(airborne[:, 2] - home.z).min() <= LIMITS["GF_MAX_VER_DIST"] - 0.5
    assert "Failsafe" not in px4_log
