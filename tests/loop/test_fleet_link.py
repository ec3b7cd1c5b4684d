"""A drone's announcements to its fleet and a peer's intents taken in (fleet_announcer.py, intake/obstacles.py)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.errors import ConfigError
from companion.loop.fleet_announcer import FleetAnnouncer
from companion.loop.fleet_config import FleetConfig
from companion.loop.intake.obstacles import ObstacleIntake
from companion.loop.intake.traffic_config import TrafficConfig
from companion.loop.peer_intents import PeerIntents
from companion.mavlink import fleet
from companion.mavlink.link import Received
from estimator import ObstacleTracker, TrackerConfig

AP = (1, 1)
PEER_SYS = 2


def _estimate(t_v, x=0.0):
    return SimpleNamespace(t_s=t_v, position=np.array([x, 0.0, -5.0]), velocity=np.array([1.0, 0.0, 0.0]),
                           position_cov=0.01 * np.eye(3), velocity_cov=0.04 * np.eye(3))


def _plan(n=20, tau=0.3, speed=1.0):
    k = np.arange(1, n + 1)[:, None]
    return SimpleNamespace(initial_velocity=np.array([speed, 0.0, 0.0]),
                           positions=np.hstack([speed * tau * k, np.zeros((n, 1)), np.full((n, 1), -5.0)]),
                           velocities=np.tile([speed, 0.0, 0.0], (n, 1)))


def _types(msgs):
    return [m.get_type() for m in msgs]


def test_that_the_announcer_sends_state_at_its_rate_the_plan_when_new_and_again_and_withdraws_it():
    ann = FleetAnnouncer(FleetConfig(state_rate_hz=10.0, intent_resend_s=0.5), step_s=0.3)
    plan = _plan()
    sent = []
    for i in range(40):                                  # 2 s of 20 Hz ticks, vehicle time = link time + 100
        t = 0.05 * i
        sent.append(ann.outbox(t, _estimate(100.0 + t), plan if i < 30 else None, 100.0, np.array([0.0, 0.0, -5.0])))
    states = [m for out in sent for m in out if m.get_type() == "ODOMETRY"]
    intents = [(i, m) for i, out in enumerate(sent) for m in out if m.get_type() == "TRAJECTORY_REPRESENTATION_WAYPOINTS"]
    assert len(states) == 20                                            # 10 Hz
    assert [i for i, _ in intents] == [0, 10, 20, 30]                   # new plan, resent every 0.5 s, withdrawn at once
    first = intents[0][1]
    assert first.time_usec == 100_000_000 and first.valid_points == 5
    assert np.allclose(first.pos_x, [0.0, 1.5, 3.0, 4.5, 6.0]) and np.allclose(first.vel_x, 1.0)
    assert intents[-1][1].valid_points == 0
    assert ann.sent == {"states": 20, "intents": 3, "withdrawals": 1}
    # a new plan goes out at once, not at the next resend
    ann2 = FleetAnnouncer(FleetConfig(), step_s=0.3)
    ann2.outbox(0.0, None, _plan(), 100.0, np.zeros(3))
    assert _types(ann2.outbox(0.05, None, _plan(speed=0.5), 100.05, np.zeros(3))) == ["TRAJECTORY_REPRESENTATION_WAYPOINTS"]


def _rx(msg, t_s, system=PEER_SYS, link="obstacles1"):
    mav = mavlink2.MAVLink(None, system, 191)
    parsed = mavlink2.MAVLink(None).parse_char(msg.pack(mav))
    return Received(t_s, parsed, b"", link)


def _intake(peers):
    # vehicle time = link time - 100 s; the peer's own clock runs 5000 s ahead of link time
    return ObstacleIntake(TrafficConfig(), ObstacleTracker(TrackerConfig()), lambda t: t - 100.0, 0.5, peers=peers)


def _peer_clock(t_link):
    return int(round((t_link + 5000.0) * 1e6))


def test_that_a_peers_intent_is_placed_on_the_vehicle_time_base_by_its_state_announcements_clock():
    peers = PeerIntents(FleetConfig(), own_system=1)
    it = _intake(peers)
    p = np.array([[0.0, 0.0, -5.0], [1.5, 0.0, -5.0], [3.0, 0.0, -5.0]])
    v = np.tile([1.0, 0.0, 0.0], (3, 1))
    # before any state: no clock to place it by
    assert it.claims(_rx(fleet.encode_intent(_peer_clock(200.0), p, v), 200.0), AP)
    assert peers.keys() == [] and it.summary()["waiting"] == {"obstacles1 sys 2: intent before its state (no clock)": 1}
    for k in range(5):                                  # states arriving 20 ms after they were stamped
        t = 200.0 + 0.1 * k
        it.claims(_rx(fleet.encode_state(_peer_clock(t - 0.02), [0.1 * k, 0, -5], [1, 0, 0], 0.01 * np.eye(3), None), t), AP)
    key = (PEER_SYS, 191, "obstacles1")
    assert it.tracker.keys() == [key]
    # the plan starts 0.2 s after it is sent (the peer's planner lead): placed there, not clamped to arrival
    it.claims(_rx(fleet.encode_intent(_peer_clock(200.6), p, v), 200.42), AP)
    intent = peers.fresh(key, 100.5)
    assert intent is not None and abs(intent.t0_s - (200.6 + 0.02 - 100.0)) < 1e-3
    assert np.allclose(intent.positions, p, atol=1e-5) and intent.spacing_s == FleetConfig().intent_knot_spacing_s
    assert it.summary()["accepted"]["obstacles1 sys 2 intent"] == 1
    # an intent claiming to start far ahead is garbage; a withdrawn one is forgotten
    it.claims(_rx(fleet.encode_intent(_peer_clock(260.0), p, v), 200.5), AP)
    assert any("ahead" in r for r in it.summary()["rejected"])
    it.claims(_rx(fleet.encode_intent(_peer_clock(200.5), None, None), 200.5), AP)
    assert peers.keys() == []


def test_that_intents_are_ignored_without_a_fleet_and_forgotten_with_their_track():
    plain = ObstacleIntake(TrafficConfig(), ObstacleTracker(TrackerConfig()), lambda t: t - 100.0, 0.5)
    assert plain.claims(_rx(fleet.encode_intent(1, np.zeros((2, 3)), np.zeros((2, 3))), 200.0), AP)  # claimed, unused
    peers = PeerIntents(FleetConfig(), own_system=1)
    it = _intake(peers)
    it.claims(_rx(fleet.encode_state(_peer_clock(200.0), [0, 0, -5], [0, 0, 0], 0.01 * np.eye(3), None), 200.0), AP)
    it.claims(_rx(fleet.encode_intent(_peer_clock(200.0), np.zeros((2, 3)), np.zeros((2, 3))), 200.0), AP)
    it.outbound(200.0, AP)
    assert len(peers) == 1
    it.tracker.prune(100.0 + it.tracker.config.drop_after_s + 1.0)
    it.outbound(210.0, AP)                                              # the track's drop is noticed here
    assert len(peers) == 0


def test_that_the_fleet_frame_is_the_vehicles_origin_placed_about_the_fleets():
    from companion.core.geo import reproject
    from companion.loop.fleet_frame import FleetFrame
    from companion.loop.vehicle_reference import VehicleReference
    from companion.mavlink.traffic import GlobalOrigin

    ref = VehicleReference()
    assert np.allclose(FleetFrame(None, ref).offset(), 0.0)          # no fleet origin: the vehicles' own frame
    frame = FleetFrame((47.3977, 8.5456, 488.0), ref)
    assert frame.offset() is None and ref.origin_request.wanted       # waits for (and asks) the vehicle's origin
    lat, lon = reproject(30.0, -12.0, 47.3977, 8.5456)                # the vehicle's origin 30 m north, 12 m west
    ref.on_origin(GlobalOrigin(lat, lon, 490.0))
    assert np.allclose(frame.offset(), [30.0, -12.0, -2.0], atol=1e-6)


def test_that_positions_cross_the_fleet_link_in_the_fleets_frame():
    from companion.loop.fleet_frame import FleetFrame
    from companion.loop.vehicle_reference import VehicleReference

    class Shifted(FleetFrame):
        def offset(self):
            return np.array([30.0, -12.0, -2.0])

    frame = Shifted(None, VehicleReference())
    ann = FleetAnnouncer(FleetConfig(), step_s=0.3)
    odo, intent = ann.outbox(0.0, _estimate(100.0, x=1.0), _plan(), 100.0, np.array([0.0, 0.0, -5.0]), frame.offset())
    assert np.allclose([odo.x, odo.y, odo.z], [31.0, -12.0, -7.0]) and np.allclose(intent.pos_x[:2], [30.0, 31.5])
    assert ann.outbox(1.0, _estimate(101.0), _plan(), 100.0, np.zeros(3), None) == []   # frame unknown: silent
    peers = PeerIntents(FleetConfig(), own_system=1)
    it = ObstacleIntake(TrafficConfig(), ObstacleTracker(TrackerConfig()), lambda t: t - 100.0, 0.5, peers=peers,
                        fleet_frame=frame)
    it.claims(_rx(fleet.encode_state(_peer_clock(200.0), [31.0, -12.0, -7.0], [1, 0, 0], 0.01 * np.eye(3), None),
                  200.0, link="fleet"), AP)
    it.claims(_rx(fleet.encode_intent(_peer_clock(200.0), np.array([[31.0, -12.0, -7.0]]), np.zeros((1, 3))),
                  200.0, link="fleet"), AP)
    key = (PEER_SYS, 191, "fleet")
    assert np.allclose(it.tracker.state(key).position, [1.0, 0.0, -5.0])
    assert np.allclose(peers.fresh(key, 100.0).positions, [[1.0, 0.0, -5.0]])


def test_that_a_peers_announced_estimate_is_its_track_state_unless_configured_as_measurements():
    """A peer on the fleet link announces its companion's estimate, which its autopilot
    corrects now and then (0.5 m north at 1.5 s here). Taken as the track's state
    (``[fleet] peer_reports = "estimate"``) the track is the announcement; ``"measurements"``
    (the default) fuses it like an obstacle's reports and takes the correction in slowly.
    An obstacle link's ODOMETRY stays a measurement either way."""
    def fly(peer_reports, link):
        peers = PeerIntents(FleetConfig(peer_reports=peer_reports), own_system=1)
        it = ObstacleIntake(TrafficConfig(), ObstacleTracker(TrackerConfig(accel_noise_psd_m2ps3=0.01)),
                            lambda t: t - 100.0, 0.5, peers=peers)
        for k in range(31):   # east at 1 m/s
            t = 200.0 + 0.1 * k
            north = 0.5 if k >= 15 else 0.0
            it.claims(_rx(fleet.encode_state(_peer_clock(t), [north, 0.1 * k, -5.0], [0.0, 1.0, 0.0],
                                             0.01 * np.eye(3), 0.004 * np.eye(3)), t, link=link), AP)
        key = (PEER_SYS, 191, link)
        return it.tracker.state(key).position, it.tracker.stats
    announced = np.array([0.5, 3.0, -5.0])
    position, stats = fly("estimate", "fleet")
    assert np.allclose(position, announced, atol=1e-4) and stats.adopted == 30
    for peer_reports, link in (("measurements", "fleet"), ("estimate", "obstacles1")):
        position, stats = fly(peer_reports, link)
        assert stats.adopted == 0 and np.linalg.norm(position - announced) > 0.1, (peer_reports, link, position)
    assert FleetConfig().peer_reports == "measurements"
    try:
        FleetConfig(peer_reports="guess")
    except ConfigError as exc:
        assert "peer_reports" in str(exc)
    else:
        raise AssertionError("peer_reports = 'guess' accepted")
