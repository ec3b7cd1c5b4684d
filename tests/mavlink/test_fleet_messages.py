"""A fleet's announcements as standard MAVLink (companion/mavlink/fleet.py)."""

import math

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink import fleet, messages, traffic


def _wire(msg, system=3, component=191):
    """The message packed by system/component and parsed back, as a link would deliver it."""
    mav = mavlink2.MAVLink(None, srcSystem=system, srcComponent=component)
    data = msg.pack(mav)
    return mavlink2.MAVLink(None).decode(bytearray(data))


def test_that_an_intent_goes_out_and_comes_back_with_its_knots():
    p = np.array([[0.0, 1.0, -5.0], [1.5, 1.2, -5.1], [3.0, 1.0, -5.0]])
    v = np.array([[1.0, 0.0, 0.0], [1.0, 0.1, 0.0], [1.0, -0.1, 0.1]])
    got = fleet.decode_intent(_wire(fleet.encode_intent(123_456_789, p, v)))
    assert isinstance(got, fleet.IntentReport)
    assert got.key == (3, 191) and got.stamp == 123_456_789
    assert np.allclose(got.positions, p, atol=1e-5) and np.allclose(got.velocities, v, atol=1e-6)
    withdrawn = fleet.decode_intent(_wire(fleet.encode_intent(5, None, None)))
    assert withdrawn.positions.shape == (0, 3)


def test_that_the_unused_fields_say_they_are_unused():
    msg = _wire(fleet.encode_intent(1, np.zeros((2, 3)), np.zeros((2, 3))))
    assert all(math.isnan(x) for x in msg.acc_x) and all(math.isnan(x) for x in msg.pos_yaw)
    assert list(msg.command) == [65535] * 5
    assert all(math.isnan(x) for x in msg.pos_x[2:])


def test_that_a_bad_intent_is_rejected_with_its_reason():
    p, v = np.zeros((5, 3)), np.zeros((5, 3))
    msg = fleet.encode_intent(1, p, v)
    msg.valid_points = 6
    assert "valid_points" in fleet.decode_intent(msg).reason
    msg = fleet.encode_intent(1, p, v)
    msg.pos_y = [0.0, math.inf, 0.0, 0.0, 0.0]
    assert "non-finite" in fleet.decode_intent(msg).reason
    msg = fleet.encode_intent(1, p, v)
    msg.vel_x = [0.0, 5e3, 0.0, 0.0, 0.0]
    assert isinstance(fleet.decode_intent(msg), messages.Rejected)


def test_that_a_state_announcement_is_an_odometry_traffic_report_with_its_covariances():
    pc = np.array([[0.04, 0.01, 0.0], [0.01, 0.05, 0.0], [0.0, 0.0, 0.09]])
    vc = 0.01 * np.eye(3)
    msg = _wire(fleet.encode_state(2_000_000, [1.0, 2.0, -5.0], [0.5, -0.5, 0.0], pc, vc, reset_counter=2))
    assert msg.frame_id == mavlink2.MAV_FRAME_LOCAL_NED and msg.reset_counter == 2
    report = traffic.decode_odometry(msg)
    assert isinstance(report, traffic.TrafficReport)
    assert np.allclose(report.position_ned, [1.0, 2.0, -5.0]) and np.allclose(report.velocity_ned, [0.5, -0.5, 0.0])
    assert np.allclose(report.position_cov, pc) and np.allclose(report.velocity_cov, vc)
