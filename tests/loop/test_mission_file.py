"""Mission files: QGroundControl .plan and QGC WPL 110, and the one-line errors of bad ones."""

from __future__ import annotations

import json
import math

import pytest

from companion.errors import ConfigError
from companion.loop.mission_file import parse_plan, parse_wpl, read_mission_file
from tests.support.missions import plan_dict, plan_text

WPS = [(8.0, 0.0, -5.0), (8.0, 8.0, -6.0), (0.0, 8.0, -5.0)]


def test_that_a_plan_file_gives_its_items_home_fence_and_rally_points(tmp_path):
    data = plan_dict(WPS)
    data["geoFence"]["polygons"] = [{"inclusion": True, "version": 1,
                                     "polygon": [[47.3977, 8.5455], [47.3980, 8.5455], [47.3980, 8.5460]]}]
    data["geoFence"]["circles"] = [{"inclusion": False, "version": 1, "circle": {"center": [47.3978, 8.5457], "radius": 3.5}}]
    data["rallyPoints"]["points"] = [[47.3979, 8.5456, 20.0]]
    path = tmp_path / "m.plan"
    path.write_text(json.dumps(data))
    plan = read_mission_file(path)
    assert [i.command for i in plan.items] == [22, 16, 16, 16, 20]
    assert [i.seq for i in plan.items] == [0, 1, 2, 3, 4]
    assert plan.items[1].frame == 3 and plan.items[1].params[1] == 1.0 and math.isnan(plan.items[1].params[3])
    assert plan.items[2].z == 6.0
    assert plan.planned_home.alt_m == 488.0
    assert plan.polygons[0].inclusion and len(plan.polygons[0].vertices) == 3
    assert not plan.circles[0].inclusion and plan.circles[0].radius_m == 3.5
    assert plan.rally[0].alt_m == 20.0


def test_that_a_wpl_file_takes_item_zero_as_home(tmp_path):
    text = ("QGC WPL 110\n"
            "0\t1\t0\t16\t0\t0\t0\t0\t47.397742\t8.545594\t488.0\t1\n"
            "1\t0\t3\t22\t0\t0\t0\t0\t47.397742\t8.545594\t5.0\t1\n"
            "2\t0\t3\t16\t0\t1.5\t0\t0\t47.397814\t8.545594\t5.0\t1\n"
            "3\t0\t3\t21\t0\t0\t0\t0\t47.397814\t8.545594\t0.0\t1\n")
    path = tmp_path / "m.waypoints"
    path.write_text(text)
    plan = read_mission_file(path)
    assert plan.planned_home.alt_m == 488.0
    assert [(i.seq, i.command) for i in plan.items] == [(0, 22), (1, 16), (2, 21)]
    assert plan.items[1].params[1] == 1.5 and plan.items[1].x == 47.397814


@pytest.mark.parametrize("mutate, says", [
    (lambda d: d.update(version=2), "m.plan: version: 2, only version 1"),
    (lambda d: d.update(fileType="Mission"), "m.plan: fileType: 'Mission'"),
    (lambda d: d["mission"].update(items=[]), "m.plan: mission.items: the mission is empty"),
    (lambda d: d["mission"]["items"][1].update(frame=1), "mission item 2 (MAV_CMD 16): frame 1 (MAV_FRAME_LOCAL_NED) is not supported"),
    (lambda d: d["mission"]["items"][1].update(frame=10), "frame 10 (MAV_FRAME_GLOBAL_TERRAIN_ALT) is not supported"),
    (lambda d: d["mission"]["items"][2].update(type="ComplexItem"), "m.plan: mission.items[2]: type 'ComplexItem'"),
    (lambda d: d["mission"]["items"][1].update(params=[0, 0, 0]), "mission.items[1].params: seven values"),
    (lambda d: d["mission"]["items"][1]["params"].__setitem__(4, "x"), "mission.items[1].params[4]: 'x' is not a finite"),
    (lambda d: d.pop("mission"), "m.plan: mission: missing"),
])
def test_that_a_bad_plan_file_is_one_error_naming_file_and_field(tmp_path, mutate, says):
    data = plan_dict(WPS)
    mutate(data)
    path = tmp_path / "m.plan"
    path.write_text(json.dumps(data))
    with pytest.raises(ConfigError, match=None) as info:
        read_mission_file(path)
    assert says in str(info.value) and "\n" not in str(info.value)


def test_that_a_truncated_plan_file_says_so(tmp_path):
    path = tmp_path / "cut.plan"
    path.write_text(plan_text(WPS)[:300])
    with pytest.raises(ConfigError, match=r"cut.plan: not valid JSON \(line \d+ column \d+.*truncated"):
        read_mission_file(path)


@pytest.mark.parametrize("text, says", [
    ("QGC WPL 120\n", "only QGC WPL 110"),
    ("QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\t47.39\t8.54\t488\t1\n", "the mission is empty"),
    ("QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\t47.39\t8.54\t488\t1\n1\t0\t3\t16\t0\t0\n", "line 3: 12 fields expected"),
    ("QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\t47.39\t8.54\t488\t1\n1\t0\t1\t16\t0\t0\t0\t0\t1\t2\t-3\t1\n",
     "frame 1 (MAV_FRAME_LOCAL_NED) is not supported"),
])
def test_that_a_bad_wpl_file_is_one_error(text, says):
    with pytest.raises(ConfigError) as info:
        parse_wpl(text, "w.txt")
    assert says in str(info.value) and str(info.value).startswith("w.txt")


def test_that_a_missing_file_is_named(tmp_path):
    with pytest.raises(ConfigError, match="nope.plan: mission file not found"):
        read_mission_file(tmp_path / "nope.plan")
    assert parse_plan(plan_text(WPS)).items
