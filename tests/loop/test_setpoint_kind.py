"""The setpoint kind chosen per scenario ([companion] setpoint_kind): velocity or position + velocity feed-forward."""

from __future__ import annotations

import pytest

from companion.errors import ConfigError
from companion.loop.config import load_scenario
from companion.mavlink.messages import TYPE_MASK_POSITION_VELOCITY, TYPE_MASK_VELOCITY
from companion.mavlink.tlog import read_tlog
from companion.offline.harness import run_lockstep


def _with(tmp_path, text: str, extra: str):
    path = tmp_path / "hop.toml"
    path.write_text(text.replace("[estimator.tracker]", extra + "\n[estimator.tracker]"))
    return path


def test_that_position_velocity_setpoints_stream_the_plan_and_reach_the_goal(tmp_path):
    base = open("tests/data/short_hop.toml").read()
    path = _with(tmp_path, base, '[companion]\nsetpoint_kind = "position_velocity"\n')
    tlog = tmp_path / "hop.tlog"
    result = run_lockstep(path, seed=0, tlog_path=tlog)
    s = result.summary()
    assert s["goal_reached"] and not s["collided"], s
    masks = [m.type_mask for _, m in read_tlog(tlog) if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]
    assert masks.count(TYPE_MASK_POSITION_VELOCITY) > 20            # while tracking a plan
    assert TYPE_MASK_VELOCITY in masks                               # prestream: zero velocity
    tracked = [m for _, m in read_tlog(tlog) if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"
               and m.type_mask == TYPE_MASK_POSITION_VELOCITY]
    assert max(m.x for m in tracked) == pytest.approx(4.0, abs=0.5)    # the reference ends at the goal


def test_that_an_unknown_setpoint_kind_names_the_file_and_key(tmp_path):
    base = open("tests/data/short_hop.toml").read()
    path = _with(tmp_path, base, '[companion]\nsetpoint_kind = "attitude"\n')
    with pytest.raises(ConfigError, match=r"hop.toml \[companion\]: setpoint_kind = 'attitude' is not one of velocity, position_velocity"):
        load_scenario(path)
