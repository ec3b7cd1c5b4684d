"""Closed loop in lockstep through the real MAVLink bytes: mavsim + companion (issue 6).

Each run is deterministic for its seed; the summaries come from the simulator's ground
truth (collisions with true positions and physical radii) and the companion's records.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from companion.offline.harness import run_lockstep

C_MIN_TOL = 1e-3  # solver tolerance on the exact recheck of the planned contour of touch


@functools.lru_cache(maxsize=None)
def _run(path: str, **kw):
    return run_lockstep(path, seed=0, **kw)


def _planned_contours_in_range(result) -> np.ndarray:
    return np.array([r.planned_min_contour for r in result.companion.records if np.isfinite(r.planned_min_contour)])


def test_that_the_antipodal_encounter_is_flown_without_collision_and_reaches_the_goal():
    result = _run("configs/antipodal.toml")
    s = result.summary()
    assert not s["collided"], s
    assert s["goal_reached"], s
    assert s["engaged"] and s["final_mode"] == "OFFBOARD"
    planned = _planned_contours_in_range(result)
    assert planned.size > 10, "obstacles were never within sensing range"
    assert planned.min() >= 0.90 - C_MIN_TOL, planned.min()
    # The realised contour (from the estimates at each replan) is reported.
    assert s["min_realised_contour"] is not None and 0.0 <= s["min_realised_contour"] <= 1.0
    assert s["min_true_clearance_m"] > 0.0


def test_that_the_corridor_is_flown_behind_the_obstacle_within_the_lower_bound_and_the_walls():
    result = _run("configs/corridor.toml", c_max=None)
    s = result.summary()
    assert not s["collided"], s
    assert s["goal_reached"], s
    assert _planned_contours_in_range(result).min() >= 0.30 - C_MIN_TOL
    assert s["min_wall_clearance_m"] > 0.0
    assert s["replans_with_slack"] == 0


def test_that_the_upper_bound_makes_the_corridor_run_finish_sooner_without_collision():
    """The paper's claim: with c_max the drone keeps up with the leader and finishes sooner.

    What does not hold here is "every planned contour >= c_min": c_max brings every step
    near the leader and the terminal cost presses them onto the c_min boundary, so an
    update of the leader's estimate (0.04 m median, 0.09 m p90 along the normal between
    replans) puts some replans' current state inside c_min and they need slack (see the
    README). This test pins what does hold, including no contact with the walls (there
    was before the planner modelled the vehicle's velocity lag).
    """
    with_bound = _run("configs/corridor.toml")
    without = _run("configs/corridor.toml", c_max=None).summary()
    s = with_bound.summary()
    assert not s["collided"], with_bound.truth["collisions"]
    assert s["goal_reached"] and without["goal_reached"]
    assert s["time_to_goal_s"] < without["time_to_goal_s"] - 5.0, (s["time_to_goal_s"], without["time_to_goal_s"])
    assert s["min_wall_clearance_m"] > 0.05


def test_that_the_same_seed_gives_the_same_flight():
    a = run_lockstep("tests/data/short_hop.toml", seed=3, duration_s=6.0)
    b = run_lockstep("tests/data/short_hop.toml", seed=3, duration_s=6.0)
    ca = np.array([r.command for r in a.companion.records])
    cb = np.array([r.command for r in b.companion.records])
    assert ca.shape == cb.shape and ca.size > 0
    assert np.array_equal(ca, cb)
    assert a.truth["final_position_ned_m"] == b.truth["final_position_ned_m"]


# ----------------------------------------------------------------------------- faults


def test_that_an_interrupted_setpoint_stream_makes_px4_fall_back_and_the_companion_yields():
    def cut_setpoints(t_s: float, direction: str, packet: bytes) -> bool:
        return direction == "to_vehicle" and 6.0 <= t_s < 9.0

    result = run_lockstep("configs/antipodal.toml", seed=0, duration_s=14.0, drop=cut_setpoints, stop_after_goal_s=None)
    modes = [m["mode"] for m in result.truth["mode_changes"]]
    assert "OFFBOARD" in modes
    left = modes.index("OFFBOARD") + 1
    assert left < len(modes), f"PX4 never left OFFBOARD: {modes}"
    assert "OFFBOARD" not in modes[left:], f"PX4 re-entered OFFBOARD: {modes}"  # not re-engaged
    assert result.truth["final_mode"] != "OFFBOARD"
    seq = result.companion.sequencer
    assert seq.phase.name == "PILOT_TOOK_OVER"
    assert not seq.state.streaming  # the companion stopped commanding: it does not fight the pilot


def test_that_a_telemetry_gap_makes_the_companion_brake_then_resume():
    def gap(t_s: float, direction: str, packet: bytes) -> bool:
        # MAVLink 2: byte 5 is the sender's system id; drop the autopilot's messages for 1.5 s.
        return direction == "to_companion" and 5.0 <= t_s < 6.5 and packet[5] == 1

    result = run_lockstep("configs/antipodal.toml", seed=0, drop=gap)
    s = result.summary()
    assert s["stale_events"] >= 1
    texts = [text for _, text in result.companion.state.events]
    assert any("stale" in t for t in texts) and any("resuming" in t for t in texts)
    assert not s["collided"] and s["goal_reached"], s


def _bad_obstacle_odometry(kind: str) -> bytes:
    from pymavlink.dialects.v20 import common as mavlink2

    mav = mavlink2.MAVLink(None, srcSystem=150, srcComponent=197)
    cov = [float("nan")] * 21
    pos = [5.0, 1.0, -5.0]
    if kind == "nan_position":
        pos = [float("nan"), 1.0, -5.0]
        cov = [0.02, 0, 0, 0, 0, 0, 0.02, 0, 0, 0, 0, 0.02] + [0.0] * 9
    elif kind == "broken_covariance":
        cov = [0.02, 0.5, 0, 0, 0, 0, 0.02, 0, 0, 0, 0, 0.02] + [0.0] * 9  # not positive definite
    msg = mavlink2.MAVLink_odometry_message(
        5_000_000, 1, 1, pos[0], pos[1], pos[2], [1, 0, 0, 0], 0, 0, 0, 0, 0, 0, cov, [float("nan")] * 21, 0, 0, 0
    )
    return msg.pack(mav)


@pytest.mark.parametrize("kind", ["nan_position", "broken_covariance"])
def test_that_bad_obstacle_reports_are_rejected_and_the_loop_keeps_flying(kind):
    def inject(t_s: float) -> list[bytes]:
        return [_bad_obstacle_odometry(kind)] if 4.0 <= t_s < 8.0 else []

    result = run_lockstep("configs/antipodal.toml", seed=0, inject=inject)
    s = result.summary()
    assert s["obstacle_reports_rejected"] >= 10, s["obstacle_reports_rejected"]
    assert (150, 197) not in result.companion.tracker.keys()
    assert not s["collided"] and s["goal_reached"], s


def test_that_twenty_percent_packet_loss_is_still_safe():
    result = run_lockstep("configs/antipodal.toml", seed=0, loss_probability=0.2)
    s = result.summary()
    assert result.dropped_packets > 100
    assert not s["collided"], s
    planned = _planned_contours_in_range(result)
    assert planned.min() >= 0.90 - C_MIN_TOL
