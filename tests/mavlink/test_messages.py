"""Decoding of inbound MAVLink messages and encoding of outbound ones, through real bytes."""

import logging
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink import messages as M
from companion.mavlink.autopilots import ModeRole, px4
from companion.errors import InputError

NAN = float("nan")


def wire(msg, sysid=1, compid=1):
    """Pack with a sender identity and parse back, as the companion would receive it."""
    sender = mavlink2.MAVLink(None, sysid, compid)
    receiver = mavlink2.MAVLink(None, 255, 0)
    (out,) = receiver.parse_buffer(bytes(msg.pack(sender)))
    return out


def upper_triangle(cov6):
    return [cov6[i][j] for i in range(6) for j in range(i, 6)]


def odometry(pos=(1.0, 2.0, -3.0), vel=(0.5, 0.0, 0.0), pose_cov=None, vel_cov=None, frame=1, child=1,
             q=(1.0, 0.0, 0.0, 0.0), t_us=2_500_000):
    pose_cov = pose_cov if pose_cov is not None else [NAN] * 21
    vel_cov = vel_cov if vel_cov is not None else [NAN] * 21
    return mavlink2.MAVLink_odometry_message(t_us, frame, child, *pos, list(q), *vel, 0, 0, 0,
                                             list(pose_cov), list(vel_cov), 0, 8, 0)


def diag_ut(x, y, z):
    ut = [0.0] * 21
    ut[0], ut[6], ut[11] = x, y, z
    ut[15] = ut[18] = ut[20] = NAN  # PX4 leaves what it does not know as NaN
    return ut


# ------------------------------------------------------------------ HEARTBEAT


def test_that_px4_armed_offboard_heartbeat_decodes_to_offboard_autopilot():
    hb = M.decode(wire(mavlink2.MAVLink_heartbeat_message(2, 12, 145, px4.OFFBOARD, 4, 3)))
    assert isinstance(hb, M.VehicleHeartbeat)
    assert hb.is_autopilot and hb.armed and hb.offboard
    assert (hb.mode, hb.role, hb.kind, hb.key, hb.type, hb.system_status) == ("OFFBOARD", ModeRole.OFFBOARD, px4.PX4, (1, 1), 2, 4)


def test_that_obstacle_heartbeat_is_not_an_autopilot_and_has_no_mode():
    hb = M.decode(wire(mavlink2.MAVLink_heartbeat_message(2, 8, 0, 0, 4, 3), sysid=101, compid=0))
    assert not hb.is_autopilot and not hb.offboard and hb.mode == "" and hb.key == (101, 0)


def test_that_disarmed_loiter_heartbeat_is_not_armed():
    hb = M.decode(wire(mavlink2.MAVLink_heartbeat_message(2, 12, 29, px4.AUTO_LOITER, 3, 3)))
    assert not hb.armed and hb.mode == "AUTO.LOITER" and not hb.offboard


# ------------------------------------------------------------------ ODOMETRY


def test_that_px4_style_odometry_gives_position_velocity_and_diagonal_covariances():
    obs = M.decode(wire(odometry(pose_cov=diag_ut(0.1, 0.2, 0.3), vel_cov=diag_ut(0.01, 0.02, 0.03)), sysid=101))
    assert isinstance(obs, M.PoseObservation)
    assert obs.key == (101, 1) and obs.source == "ODOMETRY"
    assert obs.t_s == pytest.approx(2.5)
    np.testing.assert_allclose(obs.position_ned, [1, 2, -3])
    np.testing.assert_allclose(obs.velocity_ned, [0.5, 0, 0])
    np.testing.assert_allclose(obs.position_cov, np.diag([0.1, 0.2, 0.3]), rtol=1e-6)
    np.testing.assert_allclose(obs.velocity_var, [0.01, 0.02, 0.03], rtol=1e-6)


def test_that_off_diagonal_covariance_is_read_from_the_upper_triangle():
    cov6 = np.eye(6)
    cov3 = np.array([[0.5, 0.1, 0.05], [0.1, 0.4, -0.02], [0.05, -0.02, 0.3]])
    cov6[:3, :3] = cov3
    obs = M.decode(wire(odometry(pose_cov=upper_triangle(cov6))))
    np.testing.assert_allclose(obs.position_cov, cov3, rtol=1e-6)


def test_that_nan_in_covariance_element_zero_means_unknown():
    obs = M.decode(wire(odometry()))
    assert obs.position_cov is None and obs.velocity_cov is None and obs.position_var is None


@pytest.mark.parametrize(
    ("kwargs", "reason"),
    [
        ({"pos": (NAN, 0.0, 0.0)}, "non-finite position"),
        ({"pos": (0.0, float("inf"), 0.0)}, "non-finite position"),
        ({"frame": 8}, "frame_id 8"),
        ({"pose_cov": diag_ut(-0.1, 0.2, 0.3)}, "negative variances"),
        ({"pose_cov": diag_ut(0.1, NAN, 0.3)}, "non-finite"),
        ({"pose_cov": upper_triangle(np.diag([1, 1, 1, 1, 1, 1]) + np.diag([2.0, 0, 0, 0, 0], 1))},
         "not positive definite"),
        ({"vel_cov": diag_ut(0.1, 0.0, 0.1)}, "velocity_covariance x/y/z block is not positive definite"),
        # eigenvalues 5, -1, -1: the determinant is positive, the leading 2x2 minor is not
        ({"pose_cov": upper_triangle(np.block([[np.full((3, 3), 2.0) - np.eye(3), np.zeros((3, 3))],
                                               [np.zeros((3, 3)), np.eye(3)]]))}, "not positive definite"),
        ({"pose_cov": diag_ut(1e30, 1e30, 1e30)}, "variances above 10000"),   # finite, absurd (issue 14)
        ({"pose_cov": diag_ut(0.1, 0.1, 1.0001e4)}, "variances above 10000"),
        ({"vel_cov": diag_ut(1e30, 0.1, 0.1)}, "velocity_covariance has variances above"),
    ],
)
def test_that_untrusted_odometry_is_rejected_and_logged_not_raised(kwargs, reason, caplog):
    with caplog.at_level(logging.WARNING, logger="companion.mavlink.messages"):
        out = M.decode(wire(odometry(**kwargs), sysid=102, compid=0))
    assert isinstance(out, M.Rejected)
    assert out.key == (102, 0) and out.msg_type == "ODOMETRY"
    assert reason in out.reason
    assert reason in caplog.text


def test_that_nan_velocity_is_unknown_not_a_rejection():
    obs = M.decode(wire(odometry(vel=(NAN, NAN, NAN), vel_cov=diag_ut(0.1, 0.1, 0.1))))
    assert obs.velocity_ned is None and obs.velocity_cov is None


def test_that_body_frame_velocity_is_rotated_into_ned_by_the_attitude():
    yaw = math.pi / 2  # facing east: body forward is NED east
    q = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
    obs = M.decode(wire(odometry(vel=(2.0, 0.0, 0.0), child=M.MAV_FRAME_BODY_FRD, q=q,
                                 vel_cov=diag_ut(0.04, 0.01, 0.01))))
    np.testing.assert_allclose(obs.velocity_ned, [0.0, 2.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(obs.velocity_var, [0.01, 0.04, 0.01], rtol=1e-5, atol=1e-9)


def test_that_local_frd_frame_is_accepted():
    assert isinstance(M.decode(wire(odometry(frame=20, child=20))), M.PoseObservation)


@given(st.lists(st.floats(allow_nan=True, allow_infinity=True, width=32), min_size=21, max_size=21))
def test_that_any_pose_covariance_gives_an_observation_or_a_rejection_never_an_exception(ut):
    out = M.decode(wire(odometry(pose_cov=ut)))
    assert isinstance(out, (M.PoseObservation, M.Rejected))
    if isinstance(out, M.PoseObservation) and out.position_cov is not None:
        np.linalg.cholesky(out.position_cov)
        np.testing.assert_array_equal(out.position_cov, out.position_cov.T)


# ------------------------------------------------------------------ LOCAL_POSITION_NED, ACK, STATUSTEXT


def test_that_local_position_ned_decodes_with_boot_time_and_no_covariance():
    obs = M.decode(wire(mavlink2.MAVLink_local_position_ned_message(12_345, 1, 2, -5, 0.1, 0.2, -0.3)))
    assert obs.source == "LOCAL_POSITION_NED" and obs.t_s == pytest.approx(12.345)
    np.testing.assert_allclose(obs.position_ned, [1, 2, -5])
    np.testing.assert_allclose(obs.velocity_ned, [0.1, 0.2, -0.3], rtol=1e-6)
    assert obs.position_cov is None and obs.velocity_cov is None


def test_that_local_position_ned_with_nan_position_is_rejected():
    out = M.decode(wire(mavlink2.MAVLink_local_position_ned_message(1, NAN, 2, -5, 0, 0, 0)))
    assert isinstance(out, M.Rejected)


def test_that_command_ack_decodes_command_result_and_target():
    ack = M.decode(wire(mavlink2.MAVLink_command_ack_message(176, 0, 0, 0, 1, 191)))
    assert ack == M.CommandAck(key=(1, 1), command=176, result=0, target_system=1, target_component=191)
    assert ack.accepted and ack.result_name == "MAV_RESULT_ACCEPTED"
    denied = M.decode(wire(mavlink2.MAVLink_command_ack_message(400, 1, 0, 0, 1, 191)))
    assert not denied.accepted and denied.result_name == "MAV_RESULT_TEMPORARILY_REJECTED"


def test_that_statustext_decodes_text_and_severity():
    st_ = M.decode(wire(mavlink2.MAVLink_statustext_message(
        4, b"Switching to Offboard is currently not available", 0, 0)))
    assert st_.text == "Switching to Offboard is currently not available" and st_.severity == 4


def test_that_unhandled_messages_decode_to_none():
    assert M.decode(wire(mavlink2.MAVLink_attitude_message(0, 0, 0, 0, 0, 0, 0))) is None


# ------------------------------------------------------------------ encoders


def test_that_type_masks_match_the_px4_bit_arithmetic():
    assert M.TYPE_MASK_VELOCITY == 1 + 2 + 4 + 64 + 128 + 256 + 1024 + 2048 == 3527
    assert M.TYPE_MASK_VELOCITY_YAW == 2503


def test_that_velocity_setpoint_uses_local_ned_and_velocity_only_mask():
    m = wire(M.velocity_setpoint(1500, [1.0, -2.0, -0.5]), 1, 191)
    assert (m.coordinate_frame, m.type_mask, m.time_boot_ms) == (1, 3527, 1500)
    assert (m.vx, m.vy, m.vz) == (1.0, -2.0, -0.5)
    assert (m.target_system, m.target_component) == (1, 1)


def test_that_velocity_setpoint_with_yaw_uses_mask_2503():
    m = wire(M.velocity_setpoint(0, [0, 0, 0], yaw=0.5))
    assert m.type_mask == 2503 and m.yaw == pytest.approx(0.5)


@pytest.mark.parametrize("bad", [[NAN, 0, 0], [0, float("inf"), 0], [0, 0], [[0, 0, 0]], ["a", 0, 0]])
def test_that_non_finite_or_misshapen_velocity_is_never_encoded(bad):
    with pytest.raises((InputError, ValueError)):
        M.velocity_setpoint(0, bad)


def test_that_non_finite_yaw_and_negative_time_are_refused():
    with pytest.raises(InputError, match="yaw"):
        M.velocity_setpoint(0, [0, 0, 0], yaw=NAN)
    with pytest.raises(InputError, match="time_boot_ms"):
        M.velocity_setpoint(-1, [0, 0, 0])


def test_that_boot_time_wraps_at_uint32():
    assert wire(M.velocity_setpoint(2**32 + 5, [0, 0, 0])).time_boot_ms == 5


def test_that_companion_heartbeat_is_an_onboard_controller_without_autopilot():
    m = wire(M.companion_heartbeat(), 1, 191)
    assert (m.type, m.autopilot) == (18, 8)
    assert not M.decode(m).is_autopilot


def test_that_statustext_is_truncated_to_50_ascii_characters():
    m = wire(M.statustext(6, "x" * 60 + "é"))
    assert m.text == "x" * 50
    assert wire(M.statustext(4, "braking: estimate stale é")).text == "braking: estimate stale ?"
    with pytest.raises(InputError):
        M.statustext(9, "x")


def test_that_named_value_float_names_are_limited_to_10_characters():
    m = wire(M.named_value_float(100, "ct_min", 0.93))
    assert m.name == "ct_min" and m.value == pytest.approx(0.93)
    with pytest.raises(InputError, match="1..10"):
        M.named_value_float(0, "contour_touch", 0.5)


def test_that_the_offboard_request_to_px4_sends_do_set_mode_with_main_mode_six_unpacked():
    m = wire(M.set_mode_command(px4.PX4, ModeRole.OFFBOARD, armed=True), 1, 191)
    assert (m.command, m.param1, m.param2, m.param3) == (176, 129.0, 6.0, 0.0)
    assert wire(M.set_mode_command(px4.PX4, ModeRole.OFFBOARD, armed=False)).param1 == 1.0


def test_that_hold_and_position_requests_to_px4_select_loiter_and_posctl():
    hold = wire(M.set_mode_command(px4.PX4, ModeRole.HOLD, armed=True))
    assert (hold.param2, hold.param3) == (4.0, 3.0)
    pos = wire(M.set_mode_command(px4.PX4, ModeRole.POSITION, armed=True))
    assert (pos.param2, pos.param3) == (3.0, 0.0)


def test_that_arm_disarm_and_takeoff_commands_carry_px4_params():
    arm = wire(M.arm_command(True))
    assert (arm.command, arm.param1) == (400, 1.0)
    assert wire(M.arm_command(False)).param1 == 0.0
    to = wire(M.takeoff_command())
    assert to.command == 22 and math.isnan(to.param7)
    assert wire(M.takeoff_command(495.5)).param7 == pytest.approx(495.5)
    with pytest.raises(InputError):
        M.takeoff_command(float("inf"))


def test_that_command_long_counts_confirmations_and_targets():
    m = wire(M.command_long(400, (1,), target_system=3, target_component=1, confirmation=2))
    assert (m.target_system, m.confirmation, m.param7) == (3, 2, 0.0)
    with pytest.raises(InputError):
        M.command_long(400, range(8))


def test_that_a_message_whose_fields_break_decoding_is_rejected_not_raised():
    msg = wire(odometry())
    msg.pose_covariance = [0.1] * 5  # wrong length from a broken sender
    out = M.decode(msg)
    assert isinstance(out, M.Rejected) and "21" in out.reason
    msg.frame_id = None
    assert isinstance(M.decode(msg), M.Rejected)


def test_that_a_position_velocity_setpoint_uses_both_and_ignores_acceleration_and_yaw():
    from companion.mavlink.messages import TYPE_MASK_POSITION_VELOCITY, position_velocity_setpoint

    msg = position_velocity_setpoint(1234, [1.0, 2.0, -5.0], [0.5, -0.25, 0.0], target_system=1, target_component=1)
    assert msg.type_mask == TYPE_MASK_POSITION_VELOCITY == 3520
    assert (msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz) == (1.0, 2.0, -5.0, 0.5, -0.25, 0.0)
    assert msg.coordinate_frame == 1 and msg.time_boot_ms == 1234


def test_that_a_non_finite_position_velocity_setpoint_is_refused():
    from companion.errors import InputError
    from companion.mavlink.messages import position_velocity_setpoint

    with pytest.raises(InputError, match="position \\+ velocity setpoint"):
        position_velocity_setpoint(0, [float("nan"), 0.0, 0.0], [0.0, 0.0, 0.0])
