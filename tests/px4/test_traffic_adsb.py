"""``mavsim traffic`` playing ADS-B into PX4 SITL's ground link, flown through (``make px4-test``).

The antipodal encounter of ``configs/antipodal_px4.toml`` with every obstacle switched to
``transport = "adsb"``: the player sends ADSB_VEHICLE from each obstacle's own system into
PX4's GCS link (18570), lat/lon by PX4's projection about the GPS_GLOBAL_ORIGIN it requested,
from PX4's first armed OFFBOARD; PX4 re-streams it to the companion on 14540, and
``companion fly`` (no obstacle link) flies the encounter on it. Same harness as the README
recipe test (:mod:`tests.support.recipes`, a private network namespace where possible).

Asserted: the flight exits 0, the companion accepted ADS-B reports from three sources on
its autopilot link, the player engaged and judged on SIH's truth with no collision and
every obstacle within 4 m of the drone. About 1 minute.
"""

from __future__ import annotations

import json
import re

import pytest

from tests.px4.sitl import REPO, sitl_dir
from tests.px4.test_readme_recipe import _PRELUDE
from tests.support.recipes import run_recipe

pytestmark = [pytest.mark.px4]

_FLIGHT = """\
mavsim traffic --scenario antipodal_px4_adsb.toml --duration 180 --json > traffic.json &
companion fly --connect udpin:0.0.0.0:14540 --scenario configs/antipodal_px4.toml \\
    --arm --takeoff-alt 5 --exit-after-goal 1 --tlog flight.tlog
kill %1 && wait
"""


def test_that_adsb_played_into_px4_reaches_the_companion_and_the_encounter_is_flown(tmp_path):
    base = sitl_dir()
    if base is None:
        pytest.fail("no PX4 SITL build: set PX4_SITL_DIR or put one at ../shared/px4-sitl (start-sih inside)")
    text = (REPO / "configs" / "antipodal_px4.toml").read_text()
    tmp_path.mkdir(exist_ok=True)
    (tmp_path / "antipodal_px4_adsb.toml").write_text(
        text.replace("[[world.obstacles]]\n", '[[world.obstacles]]\ntransport = "adsb"\n'))
    proc = run_recipe(_FLIGHT, tmp_path, timeout_s=420, prelude=_PRELUDE.format(start=base / "start-sih"))
    print(proc.stdout[-4000:], proc.stderr[-4000:])
    summary = json.loads((tmp_path / "traffic.json").read_text())
    print(json.dumps({k: summary[k] for k in ("engaged_at_s", "origin", "judged_on", "min_distance_m", "goal_reached",
                                              "sent")}, indent=1))
    print(json.dumps(summary["referee"], indent=1))
    assert proc.returncode == 0, proc.stderr[-3000:]
    accepted = re.search(r"obstacle reports accepted\s+(\d+) from (\d+) sources", proc.stdout)
    assert accepted and int(accepted.group(1)) > 100 and accepted.group(2) == "3", proc.stdout[-3000:]
    assert summary["engaged"] and summary["judged_on"] == "truth" and summary["sent"]["adsb_sent"] > 100, summary
    assert not summary["collision"], summary["referee"]["truth"]
    assert max(ob["min_distance_m"] for ob in summary["referee"]["truth"]["obstacles"]) < 4.0
