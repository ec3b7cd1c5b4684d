"""Reading named parameters from the autopilot (PARAM_REQUEST_READ / PARAM_VALUE), with retries and an end."""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink.param_read import ParamRead

AUTOPILOT = (1, 1)


def _value(name: str, value: float, src=AUTOPILOT, ptype=mavlink2.MAV_PARAM_TYPE_REAL32):
    msg = mavlink2.MAVLink_param_value_message(name.encode(), value, ptype, 100, 7)
    mav = mavlink2.MAVLink(None, srcSystem=src[0], srcComponent=src[1])
    return mav.parse_char(msg.pack(mav))


def test_each_name_is_asked_once_and_the_values_kept_as_they_travel():
    read = ParamRead(AUTOPILOT, ("GF_MAX_HOR_DIST", "GF_MAX_VER_DIST"))
    sent = read.start(10.0)
    assert [(m.get_type(), m.param_id, m.param_index, m.target_system) for m in sent] == [
        ("PARAM_REQUEST_READ", "GF_MAX_HOR_DIST", -1, 1), ("PARAM_REQUEST_READ", "GF_MAX_VER_DIST", -1, 1)]
    read.on_message(10.1, _value("GF_MAX_VER_DIST", 10.0))
    assert not read.done and read.step(10.5) == []            # not yet a timeout
    again = read.step(11.0)                                    # the unanswered name only
    assert [m.param_id for m in again] == ["GF_MAX_HOR_DIST"] and read.resent == 1
    read.on_message(11.1, _value("GF_MAX_HOR_DIST", 15.0))
    assert read.done and read.values == {"GF_MAX_HOR_DIST": (15.0, 9), "GF_MAX_VER_DIST": (10.0, 9)}
    assert read.step(20.0) == []


def test_answers_from_another_system_or_of_another_name_do_not_count():
    read = ParamRead(AUTOPILOT, ("GF_MAX_HOR_DIST",))
    read.start(0.0)
    read.on_message(0.1, _value("GF_MAX_HOR_DIST", 99.0, src=(2, 1)))
    read.on_message(0.1, _value("GF_MAX_VER_DIST", 10.0))
    read.on_message(0.1, _value("GF_MAX_HOR_DIST", float("nan")))
    assert read.values == {}


def test_a_name_never_answered_fails_after_the_retries_naming_it():
    read = ParamRead(AUTOPILOT, ("GF_MAX_HOR_DIST", "NO_SUCH_PARAM"), timeout_s=1.0, retries=2)
    read.start(0.0)
    read.on_message(0.1, _value("GF_MAX_HOR_DIST", 15.0))
    assert len(read.step(1.0)) == 1 and len(read.step(2.0)) == 1
    assert read.step(3.0) == [] and read.over and not read.done
    assert read.failed == "no PARAM_VALUE for NO_SUCH_PARAM after 3 requests 1 s apart"


@pytest.mark.parametrize("names", [(), ("X" * 17,), tuple(f"P{k}" for k in range(17))])
def test_nothing_unbounded_is_asked(names):
    with pytest.raises(ValueError):
        ParamRead(AUTOPILOT, names)
