"""mavsim in lockstep: PX4 offboard behaviour seen through MAVLink bytes, and determinism."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from mavsim.cli import main as mavsim_main
from mavsim.lockstep import LockstepSimulator
from tests.support.mavsim_client import AIRBORNE, GROUND, POS_ONLY, Client, acks, of_type, texts, vel_sp, with_obstacles


def test_that_heartbeat_looks_like_px4_hovering_in_hold():
    c = Client(AIRBORNE)
    msgs = c.run(1.5)
    hb = c.heartbeat(msgs)
    assert (hb.type, hb.autopilot, hb.mavlink_version) == (2, 12, 3)
    assert hb.get_srcSystem() == 1 and hb.get_srcComponent() == 1
    assert c.mode(msgs) == "LOITER" and hb.custom_mode == 50593792
    assert hb.base_mode == 157 and hb.system_status == 4  # armed AUTO, active


def test_that_ground_start_is_disarmed_in_posctl():
    c = Client(GROUND)
    hb = c.heartbeat(c.run(1.5))
    assert mavutil.mode_string_v10(hb) == "POSCTL" and hb.custom_mode == 196608
    assert hb.base_mode & 128 == 0 and hb.system_status == 3
    assert of_type(c.run(0.3), "EXTENDED_SYS_STATE")[-1].landed_state == 1


def test_that_offboard_is_refused_in_flight_without_a_stream():
    c = Client(AIRBORNE)
    c.run(1.0)
    msgs = c.set_mode_offboard()
    assert [a.result for a in acks(msgs, 176)] == [0]
    assert "Switching to Offboard is currently not available" in texts(msgs)
    assert c.mode(msgs) == "LOITER"


def test_that_older_px4_rejection_ack_is_configurable():
    c = Client({**AIRBORNE, "sim": {"offboard_reject_ack": 1}})
    assert [a.result for a in acks(c.set_mode_offboard(), 176)] == [1]


def test_that_offboard_is_accepted_with_a_stream_and_tracks_velocity_with_the_lag():
    c = Client(AIRBORNE)
    c.run(1.0, vel_sp(0.0))
    msgs = c.set_mode_offboard(vel_sp(0.0))
    assert acks(msgs, 176)[0].result == 0 and c.mode(msgs) == "OFFBOARD"
    assert c.heartbeat(msgs).base_mode == 145 and c.heartbeat(msgs).custom_mode == 393216
    c.run(0.3, vel_sp(1.0))  # one time constant after a 1 m/s step
    v = c.sim.truth.drone_velocity_ned_mps[0]
    assert v == pytest.approx(1.0 - math.exp(-1.0), abs=0.06)
    c.run(2.0, vel_sp(1.0))
    assert c.sim.truth.drone_velocity_ned_mps == pytest.approx([1.0, 0.0, 0.0], abs=0.01)
    lpn = of_type([m for _, m in c.log], "LOCAL_POSITION_NED")[-1]
    assert lpn.vx == pytest.approx(1.0, abs=0.2)


def test_that_time_constant_comes_from_the_scenario():
    c = Client({**AIRBORNE, "sim": {"velocity_time_constant_s": 1.0}})
    c.run(1.0, vel_sp(0.0))
    c.set_mode_offboard(vel_sp(0.0))
    c.run(1.0, vel_sp(1.0))
    assert c.sim.truth.drone_velocity_ned_mps[0] == pytest.approx(1.0 - math.exp(-1.0), abs=0.06)


def test_that_setpoint_loss_falls_back_to_hold_after_one_second_and_never_reenters():
    c = Client(AIRBORNE)
    c.run(1.0, vel_sp(1.0))
    c.set_mode_offboard(vel_sp(1.0))
    t_last = c.sim.time_s - 0.05
    c.run(0.9)
    assert c.sim.truth.mode == "OFFBOARD"
    msgs = c.run(0.5)
    changes = c.sim.summary()["mode_changes"]
    assert changes[-1]["mode"] == "POSCTL"
    assert 1.0 <= changes[-1]["t_s"] - t_last <= 1.1
    assert any(t.startswith("Failsafe") for t in texts(msgs))
    assert c.heartbeat(c.run(1.0)).system_status == 5  # failsafe shown as critical
    c.run(2.0, vel_sp(1.0))  # the stream comes back: PX4 does not re-enter OFFBOARD
    assert c.sim.truth.mode == "POSCTL"


def test_that_loss_timeout_and_fallback_follow_the_parameters():
    c = Client(AIRBORNE)
    c.send(mavlink2.MAVLink_param_set_message(1, 1, b"COM_OF_LOSS_T", 0.5, 9))
    val = [m for m in c.run(0.1) if m.get_type() == "PARAM_VALUE"]
    assert val and val[0].param_value == pytest.approx(0.5)
    c.send(mavlink2.MAVLink_param_set_message(1, 1, b"COM_OBL_RC_ACT", mavlink2.struct.unpack("<f", mavlink2.struct.pack("<i", 4))[0], 6))
    c.run(0.5, vel_sp(0.0))
    c.set_mode_offboard(vel_sp(0.0))
    t_last = c.sim.time_s - 0.05
    c.run(1.0)
    change = c.sim.summary()["mode_changes"][-1]
    assert change["mode"] == "AUTO.LAND" and 0.5 <= change["t_s"] - t_last <= 0.6


def test_that_disarmed_on_ground_offboard_is_selectable_but_arming_needs_the_stream():
    c = Client(GROUND)
    c.run(0.5)
    msgs = c.set_mode_offboard()
    assert acks(msgs, 176)[0].result == 0 and c.mode(msgs) == "OFFBOARD"
    msgs = c.run(2.0)  # no failsafe while disarmed
    assert c.mode(msgs) == "OFFBOARD"
    msgs = c.command(400, 1)
    assert acks(msgs, 400)[0].result == 1 and any("Arming denied" in t for t in texts(msgs))
    c.run(0.5, vel_sp(0.0))
    c.send(mavlink2.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0))
    msgs = c.run(0.5, vel_sp(0.0, 0.0, -1.0))  # climb: takes off in OFFBOARD
    assert acks(msgs, 400)[0].result == 0 and c.heartbeat(c.run(1.0, vel_sp(0, 0, -1.0))).base_mode & 128
    assert c.sim.truth.drone_position_ned_m[2] < -0.5 and not c.sim.truth.on_ground


def test_that_takeoff_climbs_at_px4_speed_to_mis_takeoff_alt_then_loiters():
    c = Client(GROUND)
    c.run(0.5)
    assert acks(c.command(400, 1), 400)[0].result == 0
    msgs = c.command(22, 0, 0, 0, float("nan"), 0, 0, float("nan"), run_s=1.0)
    assert acks(msgs, 22)[0].result == 0 and c.mode(msgs) == "TAKEOFF"
    assert c.sim.truth.drone_velocity_ned_mps[2] == pytest.approx(-1.5, abs=0.1)
    assert 3 in [m.landed_state for m in of_type(msgs, "EXTENDED_SYS_STATE")]
    msgs = c.run(3.0)
    assert c.mode(msgs) == "LOITER"
    c.run(2.0)
    assert c.sim.truth.drone_position_ned_m[2] == pytest.approx(-2.5, abs=0.1)
    assert of_type(c.run(0.3), "EXTENDED_SYS_STATE")[-1].landed_state == 2


def test_that_disarm_in_air_is_denied_and_land_auto_disarms():
    c = Client(AIRBORNE)
    msgs = c.command(400, 0)
    assert acks(msgs, 400)[0].result == 1 and c.sim.truth.armed
    msgs = c.command(21, run_s=10.0)
    assert acks(msgs, 21)[0].result == 0 and c.sim.truth.on_ground
    assert not c.sim.truth.armed and "Disarmed by landing" in texts([m for _, m in c.log])


def test_that_auto_disarm_happens_ten_seconds_after_arming_without_takeoff():
    c = Client(GROUND)
    c.command(400, 1)
    c.run(9.0)
    assert c.sim.truth.armed
    c.run(1.5)
    assert not c.sim.truth.armed


def test_that_every_command_is_acknowledged_and_unknown_ones_are_unsupported():
    c = Client(AIRBORNE)
    ack = acks(c.command(31337), 31337)
    assert len(ack) == 1 and ack[0].result == 3
    assert (ack[0].target_system, ack[0].target_component) == (245, 190)


def test_that_requested_messages_are_sent_after_an_ack():
    c = Client(AIRBORNE)
    for msg_id, mtype in ((148, "AUTOPILOT_VERSION"), (242, "HOME_POSITION")):
        msgs = c.command(512, msg_id, run_s=0.0)
        msgs = c.run(0.01)
        kinds = [m.get_type() for m in msgs if m.get_type() in ("COMMAND_ACK", mtype)]
        assert kinds[:2] == ["COMMAND_ACK", mtype] and acks(msgs, 512)[0].result == 0
    home = of_type(msgs, "HOME_POSITION")[0]
    assert home.latitude == round(47.397742e7) and home.altitude == 488000
    assert acks(c.command(512, 9999), 512)[0].result == 2


def test_that_set_message_interval_changes_the_rate():
    c = Client(AIRBORNE)
    assert acks(c.command(511, 32, 100_000), 511)[0].result == 0
    assert len(of_type(c.run(2.0), "LOCAL_POSITION_NED")) == pytest.approx(20, abs=1)
    assert acks(c.command(511, 32, -1), 511)[0].result == 0
    assert not of_type(c.run(1.0), "LOCAL_POSITION_NED")


def test_that_a_stream_switched_back_on_restarts_at_once_even_after_all_were_off():
    # the autopilot skips its streams until the earliest is due: switching every stream off makes
    # that "never", and switching one back on must bring it forward to now
    from mavsim.telemetry import STREAM_IDS

    c = Client(AIRBORNE)
    for msg_id in STREAM_IDS.values():
        c.command(511, msg_id, -1, run_s=0.0)
    c.run(0.5)
    assert not [m for m in c.run(1.0) if m.get_srcSystem() == 1 and m.get_type() != "COMMAND_ACK"]
    c.command(511, 32, 0, run_s=0.0)     # LOCAL_POSITION_NED back to its default rate
    msgs = c.run(1.0)
    lpn = of_type(msgs, "LOCAL_POSITION_NED")
    assert lpn and lpn[0].time_boot_ms <= round(1e3 * (c.sim.time_s - 1.0)) + 10
    assert len(lpn) == pytest.approx(30, abs=1)
    # a slower rate then a faster one: the faster applies from the step it was asked at
    c.command(511, 32, 2_000_000, run_s=0.0)
    c.run(0.3)
    c.command(511, 32, 100_000, run_s=0.0)
    assert len(of_type(c.run(1.0), "LOCAL_POSITION_NED")) == pytest.approx(10, abs=1)


def test_that_the_velocity_only_setpoint_shortcut_flies_as_the_general_path(monkeypatch):
    from mavsim.personalities.px4 import Commander

    def fly() -> tuple[bytes, bytes]:
        c = Client(AIRBORNE)
        c.run(0.5, vel_sp(0.0))
        c.set_mode_offboard(vel_sp(0.0))
        for vx, vy, vz in ((1.5, -0.7, 0.2), (-0.3, 2.0, -0.4), (0.0, -0.0, 0.1)):
            c.run(0.7, vel_sp(vx, vy, vz))
        truth = c.sim.truth
        return truth.drone_position_ned_m.tobytes(), truth.drone_velocity_ned_mps.tobytes()

    parts = Commander._setpoint_parts
    taken = []

    def recorded(self, sp):
        out = parts(self, sp)
        taken.append(out[-1])
        return out

    monkeypatch.setattr(Commander, "_setpoint_parts", recorded)
    shortcut = fly()
    assert taken and all(taken)      # every setpoint of that flight took the shortcut
    monkeypatch.setattr(Commander, "_setpoint_parts", lambda self, sp: parts(self, sp)[:-1] + (False,))
    assert fly() == shortcut         # the general np.where path: the same bits


def test_that_params_list_read_and_set_are_consistent():
    c = Client(AIRBORNE)
    c.send(mavlink2.MAVLink_param_request_list_message(1, 1))
    values = of_type(c.run(0.1), "PARAM_VALUE")
    names = {v.param_id: v for v in values}
    assert {"COM_OF_LOSS_T", "COM_OBL_RC_ACT", "MIS_TAKEOFF_ALT", "MPC_XY_VEL_MAX"} <= set(names)
    assert all(v.param_count == len(values) for v in values)
    assert sorted(v.param_index for v in values) == list(range(len(values)))
    assert names["COM_OBL_RC_ACT"].param_type == 6 and names["COM_OF_LOSS_T"].param_value == 1.0
    c.send(mavlink2.MAVLink_param_request_read_message(1, 1, b"MIS_TAKEOFF_ALT", -1))
    assert of_type(c.run(0.1), "PARAM_VALUE")[0].param_value == pytest.approx(2.5)
    c.send(mavlink2.MAVLink_param_set_message(1, 1, b"MPC_XY_VEL_MAX", float("nan"), 9))
    assert of_type(c.run(0.1), "PARAM_VALUE")[0].param_value == pytest.approx(12.0)


def test_that_velocity_is_limited_by_mpc_xy_vel_max():
    c = Client({**AIRBORNE, "sim": {"params": {"MPC_XY_VEL_MAX": 2.0}}})
    c.run(0.5, vel_sp(0.0))
    c.set_mode_offboard(vel_sp(0.0))
    c.run(3.0, vel_sp(5.0))
    assert c.sim.truth.drone_velocity_ned_mps[0] == pytest.approx(2.0, abs=0.02)


def test_that_mission_list_is_empty():
    c = Client(AIRBORNE)
    c.send(mavlink2.MAVLink_mission_request_list_message(1, 1, 0))
    count = of_type(c.run(0.1), "MISSION_COUNT")
    assert len(count) == 1 and count[0].count == 0 and count[0].target_system == 245


@pytest.mark.parametrize("frame", [0, 7, 9])
def test_that_unsupported_frames_are_rejected_with_a_statustext_and_are_no_proof_of_life(frame):
    c = Client(AIRBORNE)
    msgs = c.run(1.0, vel_sp(1.0, frame=frame))
    assert any("frame" in t for t in texts(msgs))
    assert c.mode(c.set_mode_offboard(vel_sp(1.0, frame=frame))) == "LOITER"


@pytest.mark.parametrize("sp", [vel_sp(float("nan")), vel_sp(1e9), vel_sp(1.0, mask=0xFFF)])
def test_that_absurd_setpoints_are_rejected_and_are_no_proof_of_life(sp):
    c = Client(AIRBORNE)
    c.run(1.0, sp)
    assert c.mode(c.set_mode_offboard(sp)) == "LOITER"
    assert c.sim.summary()["link"].get("rejected_value", 0) + c.sim.summary()["link"].get("rejected_mask", 0) > 0


def test_that_body_frame_velocity_is_rotated_by_yaw():
    c = Client({**AIRBORNE, "sim": {"start_yaw_rad": math.pi / 2}})
    c.run(0.5, vel_sp(1.0, frame=8))
    c.set_mode_offboard(vel_sp(1.0, frame=8))
    c.run(2.0, vel_sp(1.0, frame=8))
    assert c.sim.truth.drone_velocity_ned_mps == pytest.approx([0.0, 1.0, 0.0], abs=0.02)


def test_that_position_setpoints_are_flown_to():
    target = lambda: mavlink2.MAVLink_set_position_target_local_ned_message(  # noqa: E731
        0, 1, 1, 1, POS_ONLY, 3.0, -2.0, -6.0, 0, 0, 0, 0, 0, 0, 0, 0)
    c = Client(AIRBORNE)
    c.run(0.5, target)
    c.set_mode_offboard(target)
    c.run(10.0, target)
    assert c.sim.truth.drone_position_ned_m == pytest.approx([3.0, -2.0, -6.0], abs=0.05)


def test_that_messages_for_another_system_are_ignored():
    c = Client(AIRBORNE)
    c.send(mavlink2.MAVLink_command_long_message(7, 1, 400, 0, 0, 21196, 0, 0, 0, 0, 0))
    assert not acks(c.run(0.2)) and c.sim.truth.armed


def test_that_obstacles_are_separate_systems_that_are_not_autopilots():
    sc = with_obstacles(AIRBORNE, 3)
    c = Client(sc)
    msgs = c.run(2.0)
    for i, sysid in enumerate((101, 102, 103)):
        hb = of_type(msgs, "HEARTBEAT", sysid)
        assert hb and hb[0].autopilot == mavlink2.MAV_AUTOPILOT_INVALID and hb[0].get_srcComponent() != 1
        odo = of_type(msgs, "ODOMETRY", sysid)
        assert len(odo) == pytest.approx(20, abs=1) and odo[0].frame_id == 1
        assert [odo[0].pose_covariance[k] for k in (0, 6, 11)] == pytest.approx([0.02, 0.03, 0.04])
    first = next(m for m in msgs if m.get_type() == "HEARTBEAT")
    assert first.get_srcSystem() == 1  # the autopilot speaks first


def test_that_reported_positions_carry_the_configured_noise():
    cov = [[0.04, 0.01, 0.0], [0.01, 0.02, 0.0], [0.0, 0.0, 0.01]]
    c = Client({**AIRBORNE, "sim": {"position_noise_cov_m2": cov}}, seed=3)
    odo = of_type(c.run(30.0), "ODOMETRY")
    assert [odo[0].pose_covariance[k] for k in (0, 1, 6, 11)] == pytest.approx([0.04, 0.01, 0.02, 0.01])
    pts = np.array([[m.x, m.y, m.z] for m in odo[30:]])  # hovering: truth stays at the start
    assert np.cov(pts.T) == pytest.approx(np.array(cov), abs=0.006)
    assert pts.mean(axis=0) == pytest.approx([0.0, 0.0, -5.0], abs=0.03)


def test_that_truth_reports_collisions_and_goal():
    sc = with_obstacles({**AIRBORNE, "mission": {"goal_ned_m": [0.0, 0.0, -5.0], "goal_tolerance_m": 0.3}}, 1)
    c = Client(sc)
    c.run(22.0)
    s = c.sim.summary()
    assert s["collided"] and s["collisions"][0]["with"] == "o1"
    assert s["min_distance_m"]["o1"] == pytest.approx(0.0, abs=0.01)
    assert s["goal_reached"] and s["time_to_goal_s"] == 0.0
    assert c.sim.goal_reached_t_s == s["time_to_goal_s"]     # the harness's per-tick query, without the summary
    import json
    json.dumps(s)


def test_that_walls_count_as_collisions():
    sc = {**AIRBORNE, "map": {"walls": [{"normal_ned": [0.0, 1.0, 0.0], "offset_m": 1.0}]}}
    c = Client(sc)
    c.run(0.5, vel_sp(0.0, 1.0))
    c.set_mode_offboard(vel_sp(0.0, 1.0))
    c.run(2.0, vel_sp(0.0, 1.0))
    s = c.sim.summary()
    assert s["collided"] and s["collisions"][0]["kind"] == "wall"


def test_that_the_same_seed_gives_byte_identical_tlogs(tmp_path):
    def flight(seed, path):
        c = Client(with_obstacles(AIRBORNE, 3, transport="adsb"), seed=seed, tlog=path)  # ADSB: on the API link
        c.run(1.0, vel_sp(0.5))
        c.set_mode_offboard(vel_sp(0.5))
        c.run(2.0, vel_sp(0.5, 0.2))
        c.run(1.5)
        c.sim.close()
        return path.read_bytes()

    a, b = flight(7, tmp_path / "a.tlog"), flight(7, tmp_path / "b.tlog")
    assert a == b and len(a) > 10_000
    assert flight(8, tmp_path / "c.tlog") != a
    log = mavutil.mavlink_connection(str(tmp_path / "a.tlog"))
    types, stamps = set(), []
    while (m := log.recv_match()) is not None:
        types.add((m.get_srcSystem(), m.get_type()))
        stamps.append(m._timestamp)
    assert {(245, "SET_POSITION_TARGET_LOCAL_NED"), (1, "COMMAND_ACK"), (1, "ADSB_VEHICLE"), (101, "ADSB_VEHICLE")} <= types
    assert stamps == sorted(stamps) and stamps[0] == pytest.approx(1_704_067_200.0)


def test_that_output_is_one_packet_per_element_in_time_order():
    sim = LockstepSimulator(with_obstacles(AIRBORNE, 2), seed=0)
    out = sim.advance(1.0)
    dec = mavlink2.MAVLink(None)
    assert all(len(dec.parse_buffer(data) or []) == 1 for _, data in out)
    assert [t for t, _ in out] == sorted(t for t, _ in out) and out[-1][0] <= sim.time_s == 1.0


@pytest.mark.parametrize("data, where", [
    ({"sim": {"tau": 0.3}}, r"\[sim\] unknown key 'tau'"),
    ({"world": {"obstacle": []}}, r"\[world\] unknown key 'obstacle'"),
    ({"world": {"obstacles": [{"start_ned_m": [0, 0, -5], "velocity_ned_mps": [1, 0, 0], "speed": 1}]}},
     r"\[world.obstacles\[0\]\] unknown key 'speed'"),
    ({"world": {"obstacles": [{"start_ned_m": [0, 0, -5]}]}}, r"velocity_ned_mps"),
    ({"sim": {"position_noise_cov_m2": [[1, 2, 0], [2, 1, 0], [0, 0, 1]]}}, r"positive semi-definite"),
    ({"sim": {"params": {"COM_OF_LOSS_T": -1.0}}}, r"params.COM_OF_LOSS_T"),
])
def test_that_bad_scenarios_are_rejected_naming_section_and_key(data, where):
    from mavsim.errors import ScenarioError
    from mavsim.scenario import scenario_from_dict

    with pytest.raises(ScenarioError, match=where):
        scenario_from_dict(data, "x.toml")


def test_that_an_airborne_disarmed_spawn_is_held_until_armed_with_a_stream():
    c = Client({**AIRBORNE, "sim": {"start_armed": False}})
    hb = c.heartbeat(c.run(2.0))
    assert hb.base_mode & 128 == 0 and c.sim.truth.drone_position_ned_m[2] == pytest.approx(-5.0)
    assert c.mode(c.set_mode_offboard()) == "OFFBOARD"  # disarmed: selectable without a stream
    assert acks(c.command(400, 1), 400)[0].result == 1
    c.run(0.5, vel_sp(1.0))
    c.send(mavlink2.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0))
    msgs = c.run(2.0, vel_sp(1.0))
    assert acks(msgs, 400)[0].result == 0 and c.sim.truth.drone_velocity_ned_mps[0] > 0.9
    assert c.sim.truth.drone_position_ned_m[2] == pytest.approx(-5.0, abs=0.01)


@pytest.mark.parametrize("motion", [
    {"velocity_ned_mps": np.array([0.7, -1.3, 0.05]), "waypoints_ned_m": None, "loop": False},
    {"velocity_ned_mps": None, "waypoints_ned_m": np.array([[10.0, 0.0, -5.0], [10.0, 8.0, -4.0]]), "loop": False},
    {"velocity_ned_mps": None, "waypoints_ned_m": np.array([[10.0, 0.0, -5.0], [10.0, 8.0, -4.0]]), "loop": True},
])
def test_that_an_obstacle_position_is_the_first_part_of_its_state(motion):
    # the truth recorder asks for the position alone at every physics step: the same bits
    from mavsim.obstacles import ObstacleTrack
    from mavsim.scenario import Obstacle

    ob = Obstacle(name="o", radius_m=0.5, start_ned_m=np.array([1.0, 2.0, -5.0]), speed_mps=1.7,
                  measurement_cov_m2=0.01 * np.eye(3), velocity_cov_m2ps2=None, report_rate_hz=10.0,
                  start_delay_s=1.25, **motion)
    track = ObstacleTrack(ob)
    for t_s in (0.0, 1.0, 1.25, 1.26, 3.3, 7.77, 12.5, 40.0):
        assert track.position(t_s).tobytes() == track.state(t_s)[0].tobytes(), t_s


def test_that_the_lag_profile_carries_no_controller_state():
    from mavsim.vehicle import VehicleCommand, VehicleParams, initial_state, step

    state = step(initial_state(np.array([0.0, 0.0, -5.0])), VehicleCommand(np.array([1.0, 0.0, 0.0])), 0.01,
                 VehicleParams())
    assert state.controller is None


def test_that_the_px4_zero_controller_state_is_one_read_only_instance():
    from mavsim.personalities.px4_response import ControllerState

    assert ControllerState.zero() is ControllerState.zero()
    with pytest.raises(ValueError):
        ControllerState.zero().integral_mps2[0] = 1.0


def test_that_the_truth_trace_samples_drone_and_obstacles_at_10_hz_and_is_written_by_the_cli(tmp_path):
    trace = tmp_path / "truth_trace.jsonl"
    assert mavsim_main(["--scenario", "corridor", "--lockstep", "--duration", "2", "--truth-trace", str(trace)]) == 0
    rows = [json.loads(line) for line in trace.read_text().splitlines()]
    assert [r["t_s"] for r in rows] == pytest.approx([0.1 * k for k in range(21)], abs=1e-6)
    # the leader flies north at 1 m/s from 3 m ahead; the drone hovers where it started
    assert rows[-1]["obstacles_ned_m"]["leader"] == pytest.approx([5.0, 0.0, -5.0], abs=1e-6)
    assert rows[-1]["drone_ned_m"] == pytest.approx([0.0, 0.0, -5.0], abs=1e-3)
