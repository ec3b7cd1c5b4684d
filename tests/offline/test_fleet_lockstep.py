"""Two companions swapping places in lockstep, each knowing the other only by its announcements
(companion/offline/fleet_harness.py, swap.py)."""

import numpy as np
import pytest

from companion.loop.intake.traffic_config import FLEET_LINK
from companion.offline.fleet_harness import run_fleet_lockstep
from companion.offline.swap import swap_scenarios


def test_that_the_swap_puts_drones_on_a_circle_bound_for_the_opposite_points():
    scenarios = swap_scenarios(4, radius_m=6.0)
    starts = np.array([s["vehicle"]["start_ned_m"] for s in scenarios])
    goals = np.array([s["mission"]["goal_ned_m"] for s in scenarios])
    assert np.allclose(np.linalg.norm(starts[:, :2], axis=1), 6.0) and np.allclose(goals, starts * [-1, -1, 1])
    assert len({s["scenario"]["name"] for s in scenarios}) == 4
    assert all(s["world"] == scenarios[0]["world"] for s in scenarios) and len(scenarios[0]["world"]["obstacles"]) == 2
    with pytest.raises(ValueError, match="2 to 16"):
        swap_scenarios(1)


@pytest.mark.parametrize("mode", ["decentralised", "distributed", "prioritised"])
def test_that_two_drones_swap_head_on_without_touching_and_keep_c_min_between_them(mode):
    result = run_fleet_lockstep(swap_scenarios(2, traffic=False), seed=0, coordination=mode)
    s = result.summary()
    assert s["goal_reached"] and not s["collided"], s
    assert s["min_pair_clearance_m"] > 0.2, s
    c_min = result.drones[0].companion.scenario.planner.c_min
    assert s["min_peer_realised_contour"] >= c_min, s          # the promise, judged on the estimates
    assert s["fleet_packets"] > 200
    for d in result.drones:
        peers = [k for k in d.companion.tracker.keys() if isinstance(k, tuple) and k[-1] == FLEET_LINK]
        assert len(peers) == 1                                 # the other drone, heard on the fleet link only
        assert d.companion.peers.summary()["intents_received"] > 10
    if mode == "decentralised":
        assert all(d.companion.peers.counts["used"] == 0 for d in result.drones)    # constant velocity only
    elif mode == "distributed":
        assert all(d.companion.peers.counts["used"] > 0 for d in result.drones)
    else:   # drone 1 outranks drone 2: it leaves drone 2 out, drone 2 plans around drone 1's intent
        assert result.drones[0].companion.peers.counts["used"] == 0
        assert result.drones[1].companion.peers.counts["used"] > 0
        assert any(r.tracks_giving_way for r in result.drones[0].companion.records)
        assert any(r.tracks_along_intent for r in result.drones[1].companion.records)


def test_that_a_fleet_run_is_the_same_bits_for_the_same_seed():
    a = run_fleet_lockstep(swap_scenarios(2, traffic=False), seed=3, duration_s=6.0).summary()
    b = run_fleet_lockstep(swap_scenarios(2, traffic=False), seed=3, duration_s=6.0).summary()
    assert a == b


def test_that_without_keeping_right_drones_that_filter_each_other_dodge_the_same_way_and_those_that_adopt_do_not():
    # the reciprocal dance: with each peer's announced estimate fused as measurements by the
    # tracker (which lags the peer's dodge) and no rule of the road, both dodge west and down,
    # again and again; the c_min promise between them breaks (measured: contour 0.0, they touch).
    # Taking the announcement as the peer's state ("estimate"), they pass without the rule.
    def swap(keep_right, peer_reports):
        scenarios = swap_scenarios(2, traffic=False)
        for s in scenarios:
            s["fleet"] = {"keep_right": keep_right, "peer_reports": peer_reports}
        return run_fleet_lockstep(scenarios, seed=0, coordination="decentralised").summary()
    danced, kept = swap(False, "measurements"), swap(True, "measurements")
    assert danced["min_peer_realised_contour"] < 0.9 <= kept["min_peer_realised_contour"]
    assert danced["time_to_all_goals_s"] > 1.5 * kept["time_to_all_goals_s"]
    adopted = swap(False, "estimate")
    assert not adopted["collided"] and adopted["min_peer_realised_contour"] >= 0.9
    assert adopted["time_to_all_goals_s"] < 1.1 * kept["time_to_all_goals_s"]


def test_that_a_peer_gone_silent_is_flown_around_at_constant_velocity_then_forgotten_once():
    # drone 2's radio dies 3 s in, before they meet; it still hears drone 1 and gives way
    result = run_fleet_lockstep(swap_scenarios(2, traffic=False), seed=0, silent_after_s={1: 3.0})
    s = result.summary()
    assert not s["collided"] and s["goal_reached"], s
    one = result.drones[0].companion
    assert one.peers.counts["stale"] > 0                       # its last intent went stale: constant velocity
    dropped = [text for _, text in one.state.events if "sys 2:191" in text and "dropped" in text]
    assert len(dropped) == 1, one.state.events                  # forgotten, and said so once
    assert (2, 191, FLEET_LINK) not in one.tracker.keys()


def _forger(t_s):
    """Unsigned ODOMETRY claiming to be drone 2, standing 2 m ahead of drone 1 on its way (drone 1 starts at (6, 0))."""
    from pymavlink.dialects.v20 import common as mavlink2

    from companion.mavlink import fleet

    msg = fleet.encode_state(int(t_s * 1e6), [3.0, 0.0, -5.0], [0.0, 0.0, 0.0], 0.01 * np.eye(3), None)
    return [bytes(msg.pack(mavlink2.MAVLink(None, 2, 191)))] if t_s >= 2.0 else []


def test_that_a_forged_announcement_changes_no_plan_when_the_fleet_signs():
    key = bytes(range(32))
    plans = lambda r: [rec.plan_positions.tobytes() for rec in r.drones[0].companion.records]  # noqa: E731
    clean = run_fleet_lockstep(swap_scenarios(2, traffic=False), seed=0, duration_s=8.0, signing_key=key)
    forged = run_fleet_lockstep(swap_scenarios(2, traffic=False), seed=0, duration_s=8.0, signing_key=key, inject=_forger)
    assert plans(forged) == plans(clean)                          # not one plan changed
    assert forged.extra["signature_rejected"][0] > 100 and clean.extra["signature_rejected"] == [0, 0]
    unsigned = run_fleet_lockstep(swap_scenarios(2, traffic=False), seed=0, duration_s=8.0, inject=_forger)
    plain = run_fleet_lockstep(swap_scenarios(2, traffic=False), seed=0, duration_s=8.0)
    assert plans(unsigned) != plans(plain)                        # unsigned, the same forgery steers drone 1
