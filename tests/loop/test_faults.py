"""Defined behaviour under faults, in lockstep with mavsim (docs/FAULTS.md: one test per row).

Every fault is cut into the lockstep link by :class:`tests.support.lockstep_faults.VehicleSide`,
which also counts, from the vehicle's side, the setpoints and mode requests that reached it.
The encounter of ``configs/antipodal.toml`` is at 8 s (the obstacles meet at the circle's centre).
"""

from __future__ import annotations

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink.offboard import OffboardConfig, Phase
from companion.offline.harness import run_lockstep
from companion.realtime.run_end import Outcome, RunEnd
from tests.support.lockstep_faults import Cut, PlanOrigins, VehicleSide, gcs_mode_switch, left_offboard_t

SCENARIO = "configs/antipodal.toml"
ENCOUNTER_S = 8.0
SETPOINT_RATE_HZ = 20.0


def _fly(cuts=(), **kw):
    side = VehicleSide(list(cuts))
    result = run_lockstep(SCENARIO, seed=kw.pop("seed", 0), drop=side, duration_s=kw.pop("duration_s", 30.0), **kw)
    return result, side


def _texts(result) -> list[str]:
    return [text for _, text in result.companion.state.events]


def _modes(result) -> list[str]:
    return [m["mode"] for m in result.truth["mode_changes"]]


def test_that_a_half_second_autopilot_link_cut_is_ridden_through():
    result, side = _fly([Cut(ENCOUNTER_S, ENCOUNTER_S + 0.5)])
    s = result.summary()
    assert _modes(result) == ["AUTO.LOITER", "OFFBOARD"]          # PX4's 1 s offboard-loss timeout not reached
    assert RunEnd().outcome(result.companion) is Outcome.GOAL_REACHED
    assert not s["collided"] and s["goal_reached"], s
    assert result.companion.sequencer.phase is Phase.ENGAGED


@pytest.mark.parametrize("cut_s", [2.0, 10.0])
def test_that_after_an_autopilot_link_cut_px4s_failsafe_is_named_and_not_fought(cut_s):
    """Both ways cut mid-encounter: the companion brakes on its stale estimate, PX4 leaves OFFBOARD
    for Position mode 1 s after the last setpoint, and when the link is back the companion sees it,
    stops, never asks for OFFBOARD again and ends "autopilot failsafe" (exit 7), not "pilot took over"."""
    result, side = _fly([Cut(ENCOUNTER_S, ENCOUNTER_S + cut_s)])
    s = result.summary()
    texts = _texts(result)
    assert any("estimate stale, braking" in t for t in texts), texts
    if cut_s > 3.0:                                                # the HEARTBEAT timeout (3 s)
        assert any(t.startswith("LINK_LOST") for t in texts), texts
    left = left_offboard_t(result.truth)
    assert left is not None and ENCOUNTER_S + 0.9 <= left <= ENCOUNTER_S + 1.9, result.truth["mode_changes"]
    assert "OFFBOARD" not in _modes(result)[2:], _modes(result)  # never re-taken
    assert side.mode_requests_after(left) == 0
    assert side.setpoints_after(left) == 0                       # the cut held them; none after it
    assert side.left_offboard_seen_t == pytest.approx(ENCOUNTER_S + cut_s, abs=1.01)
    seq = result.companion.sequencer
    assert seq.phase is Phase.PILOT_TOOK_OVER and seq.left_by == "failsafe" and not seq.state.streaming
    assert any("autopilot failsafe after" in t and "link silence" in t for t in texts), texts
    outcome = RunEnd().outcome(result.companion)
    assert outcome is Outcome.AUTOPILOT_FAILSAFE and outcome.code == 7 and outcome.text == "autopilot failsafe"
    assert not s["collided"], s


def test_that_reengage_takes_the_vehicle_back_after_a_failsafe_once_the_link_is_back():
    """The opt-in policy (``--reengage``): a 2 s cut before the encounter leaves PX4 holding on the
    head-on obstacle's path; by default the companion does not fight that (and the obstacle hits the
    hovering vehicle: see docs/FAULTS.md); with ``reengage`` it asks for OFFBOARD again and flies on."""
    result, _ = _fly([Cut(3.0, 5.0)], offboard=OffboardConfig(reengage=True))
    s = result.summary()
    assert _modes(result)[2:] == ["POSCTL", "OFFBOARD"]
    assert not s["collided"] and s["goal_reached"], s


@pytest.mark.parametrize("mode, main, sub", [("POSCTL", 3, 0), ("AUTO.LOITER", 4, 3)])
def test_that_an_operator_mode_switch_stops_the_setpoints_and_is_never_undone(mode, main, sub):
    """QGroundControl switches the vehicle out of OFFBOARD mid-encounter. Counted at the vehicle: no
    setpoint and no mode request after the first HEARTBEAT that shows the switch; before it, at most
    one HEARTBEAT period (1 s) of setpoints, which PX4 ignores outside OFFBOARD."""
    result, side = _fly(inject_vehicle=gcs_mode_switch(ENCOUNTER_S, main, sub))
    assert _modes(result) == ["AUTO.LOITER", "OFFBOARD", mode]
    left = left_offboard_t(result.truth)
    seen = side.left_offboard_seen_t
    assert seen is not None and 0.0 <= seen - left <= 1.0 + 1e-6
    assert side.setpoints_after(seen) == 0
    assert side.setpoints_after(left) <= round((seen - left) * SETPOINT_RATE_HZ) + 1
    assert side.mode_requests_after(left) == 0
    seq = result.companion.sequencer
    assert seq.phase is Phase.PILOT_TOOK_OVER and seq.left_by == "pilot" and not seq.state.streaming
    assert RunEnd().outcome(result.companion) is Outcome.PILOT_TOOK_OVER
    assert not result.summary()["collided"]


def test_that_a_failsafe_on_a_live_link_is_named_from_the_heartbeat():
    """Only the companion's messages to the vehicle are lost (2 s): PX4 falls back and shows
    system_status CRITICAL; the companion, still hearing it, stops within one HEARTBEAT and names it."""
    result, side = _fly([Cut(ENCOUNTER_S, ENCOUNTER_S + 2.0, "autopilot_up")])
    left = left_offboard_t(result.truth)
    assert left is not None and side.left_offboard_seen_t - left <= 1.0 + 1e-6
    assert side.setpoints_after(side.left_offboard_seen_t) == 0 and side.mode_requests_after(left) == 0
    assert "OFFBOARD" not in _modes(result)[2:]
    assert result.companion.sequencer.left_by == "failsafe"
    assert RunEnd().outcome(result.companion) is Outcome.AUTOPILOT_FAILSAFE
    assert not result.summary()["collided"]


class _Covariances:
    """``after_tick``: the trace of each track's position covariance as the planner would predict it now."""

    def __init__(self) -> None:
        self.trace: dict = {}

    def __call__(self, companion, t_s: float, _outbox) -> None:
        tracker = companion.tracker
        for key in tracker.keys():
            cov = tracker.predict(key, np.array([t_s]))[1][0]
            self.trace.setdefault(key, []).append((t_s, float(np.trace(cov[:3, :3]))))


def _drops(result) -> list[tuple[float, str]]:
    return [(t, text) for t, text in result.companion.state.events if "track dropped" in text]


def test_that_obstacle_link_silence_grows_the_covariance_then_drops_and_announces_each_track():
    """The obstacle link is silent 8 to 12 s: each track's predicted covariance grows from its last
    report, the tracks are dropped 3 s (drop_after_s) later and each is announced; when the link is
    back the tracks start again and the flight goes on."""
    covs = _Covariances()
    result, _ = _fly([Cut(ENCOUNTER_S, ENCOUNTER_S + 4.0, "obstacles")], after_tick=covs)
    drops = _drops(result)
    assert sorted(text for _, text in drops) == [f"obstacle sys {s}:197: track dropped, silent > 3 s" for s in (101, 102, 103)]
    assert all(ENCOUNTER_S + 3.0 <= t <= ENCOUNTER_S + 3.5 for t, _ in drops), drops
    for key, series in covs.trace.items():
        silent = [c for t, c in series if ENCOUNTER_S <= t < ENCOUNTER_S + 3.0]
        assert silent and all(b > a for a, b in zip(silent, silent[1:])), key   # grows while silent
        assert silent[-1] > 20 * silent[0], (key, silent[0], silent[-1])
    assert sorted(result.companion.tracker.keys()) == sorted(covs.trace)         # back after the link
    s = result.summary()
    assert s["obstacle_intake"]["tracks_dropped"] == 3
    assert not s["collided"] and s["goal_reached"], s


def test_that_a_dead_obstacle_source_is_dropped_once_and_announced_and_the_others_kept():
    """Obstacle system 102 stops reporting at 6 s for good: its track alone is dropped 3 s later,
    announced once; the other two stay tracked."""
    result, _ = _fly([Cut(6.0, 1e9, "obstacles", sysid=102)])
    drops = _drops(result)
    assert [text for _, text in drops] == ["obstacle sys 102:197: track dropped, silent > 3 s"], drops
    assert 9.0 <= drops[0][0] <= 9.5                                        # pruned at a replan
    assert all(key[0] != 102 for key in result.companion.tracker.keys())
    s = result.summary()
    assert not s["collided"] and s["goal_reached"], s


def _with_resets(resets, **sim) -> dict:
    import tomllib

    with open(SCENARIO, "rb") as f:
        data = tomllib.load(f)
    data["sim"].update(**({"estimator_resets": resets} if resets else {}), **sim)
    return data


RESETS = [[ENCOUNTER_S, 1.5, 1.0, 0.0], [ENCOUNTER_S + 4.0, -1.5, -1.0, 0.0]]


@pytest.mark.parametrize("stream", ["ODOMETRY", "LOCAL_POSITION_NED"])
def test_that_an_estimator_reset_drops_the_plan_and_replans_from_the_new_position(stream):
    """PX4's EKF resets its position mid-encounter (1.8 m, then back 4 s later): seen from ODOMETRY's
    reset_counter, or as a jump of LOCAL_POSITION_NED when that is the only pose. The drone estimate
    restarts from the first report after it (never a blend of the two frames), the plan in force is
    dropped and the next one built at once from the new estimate; no tick flies a plan built before
    the last reset."""
    sim = {} if stream == "ODOMETRY" else {"stream_rates_hz": {"ODOMETRY": 0.0}}
    origins = PlanOrigins()
    result = run_lockstep(_with_resets(RESETS, **sim), seed=0, duration_s=30.0, after_tick=origins)
    s = result.summary()
    perception = result.companion.perception
    assert [round(t, 2) for t, _ in perception.resets] == [ENCOUNTER_S, ENCOUNTER_S + 4.0], perception.resets
    assert s["estimator_resets"] == 2 and perception.drone.resets == 2
    said = [(t, text) for t, text in result.companion.state.events if "estimator reset" in text]
    assert [t for t, _ in said] == pytest.approx([ENCOUNTER_S, ENCOUNTER_S + 4.0], abs=0.06), said
    assert origins.ticks_after_reset > 50 and origins.stale_frame_ticks == []
    for t_reset, t0 in origins.first_plan_after_reset:
        assert t_reset - 1e-9 <= t0 <= t_reset + 0.06, origins.first_plan_after_reset  # re-anchored at once
    assert not s["collided"] and s["goal_reached"], s


GPS_OUTAGE = [ENCOUNTER_S - 2.0, 4.0]   # 6 to 10 s: through the encounter, under PX4's 5 s limit


def test_that_a_gps_outage_is_said_widens_the_margins_and_the_reset_after_it_is_replanned():
    """mavsim's estimator dead-reckons for 4 s through the encounter (``[sim] gps_outages``): the
    standard deviation it reports grows (the planner's margins with it), the companion says once
    that the position is uncertain and once that it is certain again, and acts on the reset that
    ends the outage; no collision in truth, the goal reached."""
    origins = PlanOrigins()
    result = run_lockstep(_with_resets([], gps_outages=[GPS_OUTAGE]), seed=0, duration_s=30.0, after_tick=origins)
    s = result.summary()
    events = result.companion.state.events
    uncertain = [t for t, text in events if text.startswith("companion: position uncertain (sd ")]
    certain = [t for t, text in events if text.startswith("companion: position certain again")]
    reset = [t for t, text in events if "estimator reset" in text]
    start, end = GPS_OUTAGE[0], GPS_OUTAGE[0] + GPS_OUTAGE[1]
    assert len(uncertain) == 1 and start + 2.0 <= uncertain[0] <= start + 2.6, events   # sd 0.5 m at 2.4 s
    assert len(reset) == 1 and reset[0] == pytest.approx(end, abs=0.06), events
    assert len(certain) == 1 and certain[0] == pytest.approx(end, abs=0.06), events
    assert s["position_uncertain_events"] == 1
    assert s["reported_position_sd_max_m"] == pytest.approx(np.hypot(0.8, np.sqrt(0.02)), abs=0.02)
    assert s["estimator_resets"] == 1 and origins.stale_frame_ticks == []
    drone_covs = [r.drone_cov[0, 0] for r in result.companion.records if start + 3.0 <= r.t_vehicle_s < end]
    assert drone_covs and min(drone_covs) > 0.3          # planned with the grown covariance, not the filter's
    assert not s["collided"] and s["goal_reached"], s


def test_that_a_degraded_gps_is_said_and_widens_the_margins_without_a_reset():
    """A noisy GPS, still fused, for 6 s from 6 s (``[sim] gps_degradations``, 1 m more per
    horizontal axis, reported): the companion says the position is uncertain at once and certain
    again when it ends, plans with the reported covariance, acts on no reset; the goal, no collision."""
    start, length = ENCOUNTER_S - 2.0, 6.0
    result = run_lockstep(_with_resets([], gps_degradations=[[start, length, 1.0]]), seed=0, duration_s=30.0)
    s = result.summary()
    events = result.companion.state.events
    uncertain = [t for t, text in events if text.startswith("companion: position uncertain (sd 1.0")]
    certain = [t for t, text in events if text.startswith("companion: position certain again")]
    assert len(uncertain) == 1 and start <= uncertain[0] <= start + 0.1, events
    assert len(certain) == 1 and start + length <= certain[0] <= start + length + 0.1, events
    drone_covs = [r.drone_cov[0, 0] for r in result.companion.records if start + 0.2 <= r.t_vehicle_s < start + length]
    assert drone_covs and min(drone_covs) >= 1.0          # planned with the reported covariance
    assert s["estimator_resets"] == 0 and s["position_uncertain_events"] == 1
    assert not s["collided"] and s["goal_reached"], s


def test_that_px4s_failsafe_at_the_end_of_its_dead_reckoning_is_named_and_not_fought():
    """8 s without GPS from 6 s: 5 s in (``EKF2_NOAID_TOUT``) PX4's position is invalid and it lands
    blind in ALTCTL, CRITICAL: the companion stops within a HEARTBEAT, never asks for OFFBOARD
    again (PX4 would refuse it) and ends "autopilot failsafe" (exit 7); when the GPS is back PX4
    returns on its own."""
    start = ENCOUNTER_S - 2.0
    side = VehicleSide([])
    result = run_lockstep(_with_resets([], gps_outages=[[start, 8.0]]), seed=0, drop=side, duration_s=30.0)
    left = left_offboard_t(result.truth)
    assert left == pytest.approx(start + 5.0, abs=0.011), result.truth["mode_changes"]
    assert _modes(result) == ["AUTO.LOITER", "OFFBOARD", "ALTCTL", "AUTO.RTL"]
    assert result.truth["mode_changes"][-1]["t_s"] == pytest.approx(start + 8.0, abs=0.011)
    assert side.left_offboard_seen_t - left <= 1.0 + 1e-6
    assert side.setpoints_after(side.left_offboard_seen_t) == 0 and side.mode_requests_after(left) == 0
    texts = _texts(result)
    assert any(t.startswith("companion: position uncertain (sd ") for t in texts), texts
    seq = result.companion.sequencer
    assert seq.phase is Phase.PILOT_TOOK_OVER and seq.left_by == "failsafe" and not seq.state.streaming
    assert RunEnd().outcome(result.companion) is Outcome.AUTOPILOT_FAILSAFE
    assert not any(c["t_start_s"] < left for c in result.truth["collisions"])


def test_that_reengage_takes_the_vehicle_back_from_px4s_return_once_its_position_is_valid():
    """The same 8 s outage with ``--reengage``: PX4 refuses OFFBOARD while its position is invalid;
    once the GPS is back and it returns, the companion takes the vehicle back and flies to the goal."""
    start = ENCOUNTER_S - 2.0
    result = run_lockstep(_with_resets([], gps_outages=[[start, 8.0]]), seed=0, duration_s=40.0,
                          offboard=OffboardConfig(reengage=True))
    changes = [(round(m["t_s"], 2), m["mode"]) for m in result.truth["mode_changes"]]
    assert [m for _, m in changes] == ["AUTO.LOITER", "OFFBOARD", "ALTCTL", "AUTO.RTL", "OFFBOARD"], changes
    assert changes[3][0] == pytest.approx(start + 8.0, abs=0.011) and changes[4][0] > changes[3][0]
    assert any("Switching to Offboard is currently not available" in t for t in _texts(result))
    assert RunEnd().outcome(result.companion) is Outcome.GOAL_REACHED
    s = result.summary()
    assert not s["collided"] and s["goal_reached"], s


def test_that_a_plan_asked_before_a_reset_and_answered_after_it_is_never_flown():
    """Real time: the planning process answers a request built before the reset after it. That plan
    starts from a position of the old frame: discarded on arrival (counted), the stream brakes, and
    the next request, from the new estimate, goes at the first tick the planner is free."""
    from companion.core.planner import Planner
    from companion.loop.app import Companion
    from companion.loop.config import load_scenario
    from tests.loop.test_request_gating import HeldPlanner
    from tests.support.inbound import px4_offboard_heartbeat, received

    scenario = load_scenario("tests/data/short_hop.toml")
    service = HeldPlanner(Planner(scenario.planner))
    companion = Companion(scenario, planning=service)

    def feed(t_s: float, north_m: float) -> list:
        for msg in (px4_offboard_heartbeat(),
                    mavlink2.MAVLink_local_position_ned_message(int(t_s * 1000), north_m, 0.0, -5.0, 0.0, 0.0, 0.0)):
            companion.handle(received(msg, t_s=t_s))
        return companion.tick(t_s)

    t = 0.0
    while not service.waiting and t < 5.0:
        feed(t, 0.0)
        t = round(t + 0.05, 2)
    assert len(service.waiting) == 1 and not companion.perception.resets
    out = feed(t, 3.0)                       # the estimate jumps 3 m: LOCAL_POSITION_NED reset
    assert [m.text for m in out if m.get_type() == "STATUSTEXT"] == ["companion: estimator reset (3.0 m), replanning"]
    service.answer(solve=True)               # the old frame's plan comes back
    t = round(t + 0.05, 2)
    feed(t, 3.0)
    state = companion.state
    assert state.plans_before_reset == 1 and companion.executor.plan is None
    assert not service.waiting               # the answer was collected in this tick: free from the next
    t = round(t + 0.05, 2)
    feed(t, 3.0)
    assert len(service.waiting) == 1         # asked at once, not a replan period later, from the new estimate
    assert service.waiting[0].position[0] == pytest.approx(3.0, abs=1e-6)
    service.answer(solve=True)
    t = round(t + 0.05, 2)
    feed(t, 3.0)
    assert companion.executor.plan is not None and companion.executor.plan_p0[0] == pytest.approx(3.0, abs=1e-6)


def _critical(hb):
    import dataclasses

    return dataclasses.replace(hb, system_status=mavlink2.MAV_STATE_CRITICAL)


@pytest.mark.parametrize("reengage", [False, True])
def test_that_a_vehicle_found_in_a_failsafe_at_start_is_taken_only_with_reengage(reengage):
    """The sequencer's side of the restart row: armed, POSCTL, CRITICAL at the first HEARTBEAT."""
    from companion.mavlink.offboard import OffboardSequencer
    from tests.mavlink.test_offboard import hb

    seq = OffboardSequencer(OffboardConfig(reengage=reengage))
    seq.on_heartbeat(0.0, _critical(hb()))
    actions = seq.step(0.0)
    if reengage:
        assert seq.phase is Phase.PRESTREAM and seq.state.streaming
    else:
        assert seq.phase is Phase.GAVE_UP and not seq.state.streaming
        assert [a for a in actions if type(a).__name__ == "SendCommand"] == []
        assert "vehicle found armed in a failsafe (POSCTL)" in seq.events[-1].text


def test_that_a_mode_change_shown_with_critical_is_a_failsafe_and_without_it_a_pilot():
    """The naming rule on a live link (no HEARTBEAT lost): CRITICAL says failsafe, else pilot."""
    from companion.mavlink.autopilots import px4
    from companion.mavlink.offboard import OffboardSequencer
    from tests.mavlink.test_offboard import hb

    for critical, expected in ((True, "failsafe"), (False, "pilot")):
        seq = OffboardSequencer(OffboardConfig(prestream_s=0.0))
        t = 0.0
        while seq.phase is not Phase.ENGAGED and t < 5.0:
            seq.on_heartbeat(t, hb(px4.OFFBOARD if seq.phase is Phase.REQUEST_OFFBOARD else px4.POSCTL))
            seq.step(t)
            t += 1.0
        assert seq.phase is Phase.ENGAGED
        left = hb(px4.POSCTL)
        seq.on_heartbeat(t, _critical(left) if critical else left)
        assert seq.phase is Phase.PILOT_TOOK_OVER and seq.left_by == expected
