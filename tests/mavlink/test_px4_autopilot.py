"""PX4 custom_mode encoding, mode names, roles and autopilot identity (companion.mavlink.autopilots.px4)."""

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink import autopilots
from companion.mavlink.autopilots import ModeRole, px4
from companion.errors import InputError


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("POSCTL", 196608),
        ("OFFBOARD", 393216),
        ("AUTO.TAKEOFF", 33816576),
        ("AUTO.LOITER", 50593792),
        ("AUTO.LAND", 100925440),
    ],
)
def test_that_reference_custom_modes_from_px4_match(name, value):
    assert px4.custom_mode_from_name(name) == value
    assert px4.mode_name(value) == name


def test_that_module_constants_hold_the_reference_values():
    assert (px4.POSCTL, px4.OFFBOARD, px4.AUTO_TAKEOFF, px4.AUTO_LOITER, px4.AUTO_LAND) == (
        196608, 393216, 33816576, 50593792, 100925440)


def _hb(custom_mode, base_mode=1):
    return mavlink2.MAVLink_heartbeat_message(2, 12, base_mode, custom_mode, 4, 3)


@pytest.mark.parametrize("main", list(px4.MainMode))
def test_that_mode_names_agree_with_pymavlink_mode_string(main):
    subs = list(px4.AutoSubMode) if main is px4.MainMode.AUTO else [0]
    for sub in subs:
        cm = px4.encode_custom_mode(main, sub)
        theirs = mavutil.mode_string_v10(_hb(cm))
        ours = px4.mode_name(cm)
        if main is px4.MainMode.AUTO:
            if sub in (px4.AutoSubMode.READY, px4.AutoSubMode.PRECLAND, px4.AutoSubMode.FOLLOW_TARGET):
                continue  # pymavlink has no name (READY, PRECLAND) or calls it FOLLOWME
            assert ours == "AUTO." + theirs
        else:
            assert ours == theirs


@given(st.integers(0, 255), st.integers(0, 255))
def test_that_encode_and_decode_are_inverse(main, sub):
    assert px4.decode_custom_mode(px4.encode_custom_mode(main, sub)) == (main, sub)


@given(st.integers(0, 2**32 - 1))
def test_that_mode_name_never_raises_and_round_trips_known_modes(custom_mode):
    name = px4.mode_name(custom_mode)
    if not name.startswith("UNKNOWN"):
        assert px4.mode_name(px4.custom_mode_from_name(name)) == name


def test_that_unknown_mode_names_are_refused_with_the_known_list():
    with pytest.raises(InputError, match="unknown PX4 mode name 'AUTO.NOPE'.*OFFBOARD"):
        px4.custom_mode_from_name("AUTO.NOPE")
    with pytest.raises(InputError):
        px4.custom_mode_from_name("POSCTL.LOITER")


@pytest.mark.parametrize(("base_mode", "armed"), [(145, True), (157, True), (209, True), (1, False), (81, False)])
def test_that_armed_comes_from_base_mode_bit_128(base_mode, armed):
    assert autopilots.is_armed(base_mode) is armed


def test_that_only_a_px4_autopilot_component_counts_as_autopilot():
    assert px4.is_autopilot_heartbeat(1, 1, 12, 2)
    assert px4.is_autopilot_heartbeat(7, 1, 12, 13)  # other MAV_SYS_ID, hexarotor
    assert not px4.is_autopilot_heartbeat(101, 0, 8, 2)  # mavsim obstacle system
    assert not px4.is_autopilot_heartbeat(1, 1, 3, 2)  # ArduPilot: not supported
    assert not px4.is_autopilot_heartbeat(1, 191, 12, 18)  # a companion
    assert not px4.is_autopilot_heartbeat(245, 190, 8, 6)  # MAVSDK ground station
    assert not px4.is_autopilot_heartbeat(1, 1, 12, 6)  # GCS type from compid 1
    assert not px4.is_autopilot_heartbeat(1, 100, 12, 30)  # camera


def test_that_set_mode_params_send_main_mode_unpacked_and_armed_bit_when_armed():
    assert px4.set_mode_params(px4.OFFBOARD, armed=True) == (129.0, 6.0, 0.0)
    assert px4.set_mode_params(px4.OFFBOARD, armed=False) == (1.0, 6.0, 0.0)
    assert px4.set_mode_params(px4.AUTO_LOITER, armed=True) == (129.0, 4.0, 3.0)
    with pytest.raises(InputError):
        px4.set_mode_params(0, armed=False)


def test_that_the_registry_knows_px4_by_its_heartbeat_and_nothing_else():
    assert autopilots.of_heartbeat(1, 1, 12, 2) is px4.PX4
    assert autopilots.of_heartbeat(1, 1, 3, 2) is not px4.PX4   # ArduPilot: its own module
    assert autopilots.of_heartbeat(101, 0, 8, 2) is None    # a mavsim obstacle system
    assert autopilots.of_heartbeat(1, 191, 12, 18) is None  # a companion that says PX4


@pytest.mark.parametrize(("mode", "role"), [
    (px4.OFFBOARD, ModeRole.OFFBOARD), (px4.AUTO_LOITER, ModeRole.HOLD), (px4.AUTO_TAKEOFF, ModeRole.TAKEOFF),
    (px4.POSCTL, ModeRole.POSITION), (px4.AUTO_RTL, ModeRole.OTHER), (px4.AUTO_LAND, ModeRole.OTHER),
    (px4.encode_custom_mode(px4.MainMode.AUTO, px4.AutoSubMode.MISSION), ModeRole.MISSION), (px4.AUTO_MISSION, ModeRole.MISSION),
    (px4.encode_custom_mode(px4.MainMode.MANUAL), ModeRole.OTHER), (0, ModeRole.OTHER),
])
def test_that_each_px4_mode_plays_its_role(mode, role):
    assert px4.PX4.mode_role(mode) is role


def test_that_the_requested_modes_are_offboard_hold_and_position_and_round_trip_to_their_roles():
    for role in (ModeRole.OFFBOARD, ModeRole.HOLD, ModeRole.POSITION):
        assert px4.PX4.mode_role(px4.PX4.custom_mode_of(role)) is role
    assert px4.PX4.mode_name(px4.PX4.custom_mode_of(ModeRole.HOLD)) == "AUTO.LOITER"
    with pytest.raises(InputError, match="never requests a PX4 mode for 'takeoff'"):
        px4.PX4.custom_mode_of(ModeRole.TAKEOFF)
