"""The setpoint stream never waits for the planner (issue 14 item 1), independent of machine speed.

The stream runs on a virtual clock (``run_realtime``'s injectable ``clock`` and ``sleep``)
against a scripted autopilot, with the planner in its own process. The planner solves the
first request, then every later solve blocks for 30 s of wall time. Whatever the machine's
speed, every tick must send its setpoint exactly on the 50 ms grid, the first plan must be
flown until it is older than ``max_plan_age_s``, then the stream must brake within the
acceleration bound to a stop, and the autopilot link must not be declared lost.
"""

from __future__ import annotations

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.loop.app import Companion
from companion.loop.config import load_scenario
from companion.realtime.stream import PlanWorker, run_realtime
from companion.mavlink.link import Received
from tests.support.blocking_planner import FirstThenBlock
from tests.support.inbound import px4_offboard_heartbeat

SCENARIO = "tests/data/short_hop.toml"


class ScriptedAutopilot:
    """PX4 armed in OFFBOARD, hovering at the start: HEARTBEAT at 4 Hz, LOCAL_POSITION_NED at 20 Hz."""

    def __init__(self, clock):
        self.clock = clock
        self.sent: list[tuple[float, object]] = []
        self._mav = mavlink2.MAVLink(None, 1, 1)
        self._next = 0.0
        self._i = 0

    def _rx(self, msg, t_s):
        raw = bytes(msg.pack(self._mav))
        return Received(t_s, self._mav.parse_buffer(raw)[0], raw)

    def poll(self):
        out, now = [], self.clock()
        while self._next <= now + 1e-9:
            if self._i % 5 == 0:
                out.append(self._rx(px4_offboard_heartbeat(), now))
            out.append(self._rx(mavlink2.MAVLink_local_position_ned_message(int(round(self._next * 1000)), 0, 0, -5, 0, 0, 0), now))
            self._i += 1
            self._next = round(self._next + 0.05, 6)
        return out

    def send(self, msg, t_s=None):
        self.sent.append((t_s, msg))


def test_that_a_stuck_planner_neither_delays_a_setpoint_nor_keeps_an_old_plan_flying():
    scenario = load_scenario(SCENARIO)
    now = [0.0]
    worker = PlanWorker(scenario.planner, make_planner=FirstThenBlock)
    companion = Companion(scenario, planning=worker)
    link = ScriptedAutopilot(lambda: now[0])

    def sleep(dt: float) -> None:
        if not companion.records and worker.busy:
            assert worker.wait_for_result(120.0), "the first plan never came"  # only the first plan is awaited
        now[0] += dt

    try:
        stats = run_realtime(companion, link, duration_s=3.025, clock=lambda: now[0], sleep=sleep)
    finally:
        worker.close(timeout_s=0.5)

    setpoints = [(t, m) for t, m in link.sent if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]
    times = np.array([t for t, _ in setpoints])
    assert len(setpoints) == stats.ticks == 61  # 0.00 .. 3.00 s
    assert np.allclose(np.diff(times), 0.05, atol=1e-6)
    assert stats.summary()["setpoint_gap_max_ms"] == 50.0
    # the loop's steps reach the gap probe: on the virtual clock only a sleep takes time (2 ms polls)
    detail = stats.summary()["setpoint_gap_max_detail"]
    assert detail["gap_ms"] == 50.0 and detail["longest_step"] == "sleep" and detail["longest_step_ms"] == 2.0
    assert companion.sequencer.phase.name == "ENGAGED"  # no false LINK_LOST while the planner is stuck
    # no request is built while the planner is busy: the stuck job is the last one (none waits to be thrown away)
    assert worker.stats.solved == 1 and worker.stats.submitted == 2 and worker.stats.superseded == 0

    # plan 0 (requested at t = 0, applied at the next tick) is flown while it is fresh ...
    (record,) = companion.records
    assert record.t_link_s == 0.0 and record.t_applied_s == 0.05
    plan = companion.executor.plan
    cmds = np.array([[m.vx, m.vy, m.vz] for _, m in setpoints])
    max_age = scenario.companion.max_plan_age_s
    flown = (times >= 0.05) & (times <= max_age + 1e-9)
    steps = np.floor(times[flown] / scenario.planner.step_s + 1e-9).astype(int)
    # the plan's commands as the wire carries them (float32; a tiny value such as 3e-46 m/s is 0 there)
    np.testing.assert_array_equal(cmds[flown].astype(np.float32), np.asarray(plan.commands, dtype=np.float32)[steps])
    assert np.max(np.abs(cmds[flown])) > 0.1
    # ... then the stream brakes within the acceleration bound, to a stop.
    braking = cmds[times > max_age + 1e-9]
    step = np.asarray(scenario.planner.accel_max) / scenario.companion.setpoint_rate_hz
    previous = np.vstack([cmds[flown][-1:], braking[:-1]])
    assert np.all(np.abs(braking - previous) <= step + 1e-6)
    assert np.all(np.abs(braking) <= np.abs(previous) + 1e-7)
    assert np.all(braking[-1] == 0.0)
    texts = [m.text for _, m in link.sent if m.get_type() == "STATUSTEXT"]
    assert sum("plan older than" in t for t in texts) == 1 and companion.state.old_plan_events == 1
