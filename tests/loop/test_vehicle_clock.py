"""The autopilot's clock on link time: pose arrivals, TIMESYNC round trips, and how they combine."""

from __future__ import annotations

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.loop.app import Companion
from companion.loop.supervisor import CLOCK_DISAGREES_TEXT
from companion.loop.config import load_scenario
from companion.loop.vehicle_clock import VehicleClock, link_ns
from tests.support.inbound import px4_heartbeat, received

EPOCH = 1_764_633_600.0  # link time as a real link has it: Unix seconds


class _Autopilot:
    """A vehicle clock ``t_v = (t_link - EPOCH - boot) * (1 - slow)`` with one-way latencies."""

    def __init__(self, boot_s=-12.0, slow=0.008, up_s=0.004, down_s=0.004, rng=None):
        self.boot_s, self.slow, self.up_s, self.down_s = boot_s, slow, up_s, down_s
        self.rng = rng or np.random.default_rng(0)

    def vehicle(self, t_link: float) -> float:
        return (t_link - EPOCH - self.boot_s) * (1.0 - self.slow)

    def true_offset(self, t_link: float) -> float:
        return t_link - self.vehicle(t_link)

    def fly(self, clock: VehicleClock, t0: float, t1: float, pose_hz=30.0, sync_hz=2.0, jitter_s=0.002):
        """Poses (stamped at send, arriving after ``down_s`` plus jitter) and round trips."""
        t = t0
        next_sync = t0
        while t < t1:
            clock.observe_pose(t + self.down_s + self.rng.uniform(0, jitter_s), self.vehicle(t))
            if t >= next_sync:
                ts1 = clock.request(t)
                t_at_vehicle = t + self.up_s + self.rng.uniform(0, jitter_s)
                t_back = t_at_vehicle + self.down_s + self.rng.uniform(0, jitter_s)
                clock.answer(t_back, link_ns(self.vehicle(t_at_vehicle)), ts1)
                next_sync += 1.0 / sync_hz
            t += 1.0 / pose_hz
        return t


def test_that_timesync_recovers_a_drifting_clock_where_the_arrival_bound_carries_the_latency():
    ap = _Autopilot(slow=0.008, up_s=0.030, down_s=0.030)  # a radio link: 30 ms each way
    clock = VehicleClock()
    t_end = ap.fly(clock, EPOCH, EPOCH + 20.0)
    truth = ap.true_offset(t_end)
    assert clock.summary(t_end)["source"] == "timesync"
    assert abs(clock.offset(t_end) - truth) < 2e-3  # symmetric legs: the midpoint is right
    # the arrival bound is off by the 30 ms latency less the drift over its 0.5 s window (4 ms)
    assert clock.one_way_offset(t_end) - truth == pytest.approx(0.030 - 0.5 * 0.008, abs=2e-3)
    assert clock.summary(t_end)["drift"] == pytest.approx(0.008, abs=5e-4)


def test_that_an_answer_stamped_late_by_a_stepping_clock_is_capped_by_the_arrival_bound():
    ap = _Autopilot(slow=0.0, up_s=0.001, down_s=0.001)
    clock = VehicleClock()
    t = EPOCH
    for k in range(200):  # the answers carry the clock of the last 20 ms simulation step
        clock.observe_pose(t + 0.001, ap.vehicle(t))
        if k % 15 == 0:
            ts1 = clock.request(t)
            stepped = np.floor((ap.vehicle(t + 0.001)) / 0.02) * 0.02 - 0.015
            clock.answer(t + 0.002, link_ns(stepped), ts1)
        t += 1 / 30
    assert clock.sync_offset(t) > clock.one_way_offset(t)
    assert clock.offset(t) == clock.one_way_offset(t)
    assert clock.summary(t)["source"] == "arrivals" and not clock.disagrees


def test_that_answers_on_another_clock_are_set_aside_after_three_and_never_used_before():
    ap = _Autopilot(slow=0.0)
    clock = VehicleClock()
    t = EPOCH
    used = []
    for k in range(120):
        clock.observe_pose(t + 0.004, ap.vehicle(t))
        if k % 10 == 0:
            ts1 = clock.request(t)
            clock.answer(t + 0.008, link_ns(t - 3600.0), ts1)  # a Unix clock an hour off, not the boot clock
            used.append(clock.offset(t + 0.008))
        t += 1 / 30
    assert clock.disagrees
    for offset in used:  # the wrong clock never moved the mapping, not even before it was set aside
        assert abs(offset - ap.true_offset(t)) < 0.01
    assert clock.summary(t)["source"] == "arrivals"


def test_that_only_answers_to_our_own_recent_requests_count_and_memory_stays_bounded():
    clock = VehicleClock()
    clock.observe_pose(EPOCH, 10.0)
    assert not clock.answer(EPOCH + 0.01, link_ns(10.0), link_ns(EPOCH - 5.0))  # someone else's request
    for k in range(1000):
        clock.request(EPOCH + k * 0.001)
    assert not clock.answer(EPOCH + 2.0, link_ns(12.0), link_ns(EPOCH))  # ours, but long forgotten
    ts1 = clock.request(EPOCH + 2.0)
    assert not clock.answer(EPOCH + 1.0, link_ns(12.0), ts1)  # back before it was sent
    assert clock.summary()["timesync_foreign"] == 2
    assert len(clock._pending) <= 32 and len(clock._round_trips) <= 64


def test_that_the_arrival_bound_takes_over_when_answers_stop():
    ap = _Autopilot(slow=0.0, up_s=0.02, down_s=0.02)
    clock = VehicleClock()
    t = ap.fly(clock, EPOCH, EPOCH + 5.0)
    assert clock.summary(t)["source"] == "timesync"
    t = ap.fly(clock, t, t + 10.0, sync_hz=1e-9)  # one request at the start, then none
    assert clock.summary(t)["source"] == "arrivals"
    assert clock.offset(t) == clock.one_way_offset(t)


def test_that_a_simulated_clock_slipping_under_load_never_makes_a_flowing_estimate_look_stale():
    # PX4 SITL's clock under a loaded host: at the wall clock's rate, then 20 % slow for 3 s,
    # stopped for 0.3 s (nothing sent), 10 % slow after. Poses every 32 ms of its own time
    # arrive 1 ms after they are stamped; TIMESYNC answers carry the clock at receipt.
    rate = [(0.0, 1.0), (5.0, 0.8), (8.0, 0.0), (8.3, 0.9)]   # (link s after EPOCH, clock rate from then)

    def vehicle(t_link):
        v, (t_prev, r_prev) = 100.0, rate[0]
        for t_k, r_k in rate[1:] + [(float("inf"), 0.0)]:
            v += r_prev * (min(t_link - EPOCH, t_k) - t_prev)
            if t_link - EPOCH <= t_k:
                return v
            t_prev, r_prev = t_k, r_k

    clock = VehicleClock()
    t, next_pose, next_sync, newest_sent = EPOCH, EPOCH, EPOCH, None
    worst_while_slow = oldest_looking = 0.0
    while t < EPOCH + 14.0:
        if t >= next_pose and vehicle(t + 1e-3) > vehicle(t):   # a stopped clock sends nothing
            clock.observe_pose(t + 1e-3, vehicle(t))
            newest_sent = (t, vehicle(t))
            next_pose = t + 0.032
        if t >= next_sync:
            ts1 = clock.request(t)
            clock.answer(t + 2e-3, link_ns(vehicle(t + 1e-3)), ts1)
            next_sync = t + 0.5
        t = round(t + 1e-3, 6)
        if newest_sent is not None and t > EPOCH + 1.0:
            mapped_age = clock.vehicle_time(t) - newest_sent[1]   # what the loop compares with estimate_timeout_s
            oldest_looking = max(oldest_looking, mapped_age)
            if EPOCH + 5.0 <= t < EPOCH + 8.0:   # beyond the link time since it was sent, while 20 % slow
                worst_while_slow = max(worst_while_slow, mapped_age - (t - newest_sent[0]))
    # the bound over 0.5 s lags the slip over 0.5 s: 0.1 s at 20 % slow (over a 2 s window: 0.4 s)
    assert 0.0 < worst_while_slow < 0.11, worst_while_slow
    # the stop is 0.3 s without a pose, and for a window after it the poses look 0.3 s late: under 0.5 s
    assert oldest_looking < 0.45, oldest_looking
    assert clock.summary(t)["drift"] > 0.05   # the clock ran slow, and the report says so


# ---------------------------------------------------------------------------- the companion's side


def _received(msg, src=(1, 1), t_s=EPOCH):
    return received(msg, src, t_s)


def test_that_the_companion_answers_the_autopilots_timesync_at_once_and_no_one_elses():
    companion = Companion(load_scenario("configs/antipodal.toml"))
    request = mavlink2.MAVLink_timesync_message(0, 8_048_000_000)
    assert companion.handle(_received(request)) == []  # the autopilot is not known yet
    companion.handle(_received(px4_heartbeat()))
    (answer,) = companion.handle(_received(request, t_s=EPOCH + 0.25))
    assert answer.get_type() == "TIMESYNC" and answer.ts1 == 8_048_000_000 and answer.tc1 == link_ns(EPOCH + 0.25)
    assert companion.handle(_received(request, src=(7, 1))) == []  # another system's request
    assert companion.handle(_received(mavlink2.MAVLink_timesync_message(123, 456))) == []  # an answer, not ours


def test_that_the_companion_asks_the_autopilot_at_timesync_hz_and_never_before_it_is_known(tmp_path):
    for rate, expected in ((2.0, 5), (0.0, 0)):
        text = open("configs/antipodal.toml").read().replace("[companion]", f"[companion]\ntimesync_hz = {rate}", 1)
        path = tmp_path / f"s{rate}.toml"
        path.write_text(text)
        companion = Companion(load_scenario(path))
        assert not any(m.get_type() == "TIMESYNC" for m in companion.tick(EPOCH))
        companion.handle(_received(px4_heartbeat()))
        sent = [m for k in range(1, 51) for m in companion.tick(EPOCH + 0.05 * k) if m.get_type() == "TIMESYNC"]
        assert len(sent) == expected and all(m.tc1 == 0 for m in sent)


def test_that_a_companion_whose_autopilot_answers_on_another_clock_says_so_once():
    companion = Companion(load_scenario("configs/antipodal.toml"))
    companion.handle(_received(px4_heartbeat()))
    texts = []
    for k in range(200):
        t = EPOCH + 0.05 * k
        companion.handle(_received(mavlink2.MAVLink_local_position_ned_message(int(1000 * (t - EPOCH + 30)), 0, 0, -5, 0, 0, 0), t_s=t))
        for m in companion.tick(t):
            if m.get_type() == "TIMESYNC" and m.tc1 == 0:
                companion.handle(_received(mavlink2.MAVLink_timesync_message(link_ns(t), m.ts1), t_s=t + 0.002))
            elif m.get_type() == "STATUSTEXT":
                texts.append(m.text)
    assert texts.count(CLOCK_DISAGREES_TEXT) == 1
    assert companion.perception.clock.disagrees
    assert abs(companion.vehicle_time(EPOCH + 9.95) - 39.95) < 0.01  # the pose stamps, not the Unix answers


def test_that_the_summary_line_says_which_clock_was_used_and_why():
    from companion.offline.report import format_report

    def line(**clock):
        base = {"source": "arrivals", "timesync_requests": 10, "timesync_answers": 10, "timesync_foreign": 0,
                "timesync_disagrees": False, "rtt_min_ms": 2.4, "drift": 1e-5, "one_way_minus_timesync_ms": None}
        text = format_report({"vehicle_clock": {**base, **clock}})
        return next(x for x in text.splitlines() if x.startswith("autopilot clock from")).split("  ")[-1].strip()

    assert line(source="timesync", one_way_minus_timesync_ms=0.39).startswith("TIMESYNC (arrival bound 0.39 ms above")
    assert line(one_way_minus_timesync_ms=-19.3) == "pose arrivals (TIMESYNC answers stamped 19.3 ms late)"
    assert line(one_way_minus_timesync_ms=0.0) == "pose arrivals (TIMESYNC agrees)"
    assert line(timesync_disagrees=True) == "pose arrivals (TIMESYNC answers disagreed with the pose stamps)"
    assert line(timesync_answers=0) == "pose arrivals (0 TIMESYNC answers of 10 requests)"
