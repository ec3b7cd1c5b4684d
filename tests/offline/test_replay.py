"""Replay of tlogs: round trip of lockstep runs, logs written by pymavlink elsewhere, errors and CLI exits."""

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.cli import main
from companion.offline.harness import run_lockstep
from companion.offline.replay import ReplayError, replay
from companion.mavlink.tlog import TlogError, TlogWriter, read_tlog
from companion.offline.harness import LOCKSTEP_EPOCH_S

SCENARIO = "configs/antipodal.toml"
T0 = 1_700_000_000.0  # a Unix time, outside the lockstep epoch window


@pytest.fixture(scope="module")
def antipodal(tmp_path_factory):
    """A 20 s lockstep demo run that recorded its link."""
    path = tmp_path_factory.mktemp("replay") / "a.tlog"
    run = run_lockstep(SCENARIO, seed=0, tlog_path=path, duration_s=20, stop_after_goal_s=None)
    return run, path


@pytest.fixture(scope="module")
def antipodal_replay(antipodal):
    return replay(antipodal[1], SCENARIO)


def test_that_replaying_a_lockstep_log_reproduces_every_recorded_command(antipodal, antipodal_replay):
    run, path = antipodal
    res = antipodal_replay
    recorded = [m for _, m in read_tlog(path) if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]
    assert res.mode == "compare" and res.lockstep and res.time_offset_s == LOCKSTEP_EPOCH_S
    assert len(recorded) > 300
    assert res.commands_recorded == res.commands_compared == len(recorded)
    assert res.unmatched_commands == 0 and res.tick_mismatches == 0
    assert res.max_abs_diff_mps <= 1e-9
    # every compared setpoint, axis by axis, against the log itself
    got = np.asarray(res.commands_mps, dtype=np.float32).astype(float)
    want = np.array([[m.vx, m.vy, m.vz] for m in recorded])
    assert np.max(np.abs(got - want)) <= 1e-9
    # and the replayed planner made the same decisions as the recorded one (float64)
    assert len(res.companion.records) == len(run.companion.records) > 0
    for a, b in zip(res.companion.records, run.companion.records):
        assert a.t_link_s == b.t_link_s and a.status == b.status
        assert np.max(np.abs(a.command - b.command)) <= 1e-9


def test_that_the_replay_counts_and_summary_describe_the_log(antipodal, antipodal_replay):
    _, path = antipodal
    res = antipodal_replay
    msgs = list(read_tlog(path))
    own = sum(1 for _, m in msgs if (m.get_srcSystem(), m.get_srcComponent()) == (1, 191))
    assert (res.messages, res.outbound, res.inbound) == (len(msgs), own, len(msgs) - own)
    assert res.duration_s == pytest.approx(20.0, abs=0.06)
    assert res.ticks == res.recorded_ticks == 400  # 20 s at 20 Hz, every tick recorded
    summary = json.loads(json.dumps(res.summary()))
    assert summary["replans"] == len(res.companion.records)
    assert sum(summary["plan_status"].values()) == summary["replans"]
    assert summary["max_abs_diff_mps"] == res.max_abs_diff_mps


def test_that_silent_ticks_during_a_link_outage_are_put_back_on_the_setpoint_grid(tmp_path):
    path = tmp_path / "outage.tlog"
    run_lockstep(SCENARIO, seed=1, tlog_path=path, duration_s=12,
                 drop=lambda t, direction, _: direction == "to_companion" and 5.0 <= t <= 9.0)
    res = replay(path, SCENARIO)
    assert res.ticks > res.recorded_ticks  # the companion ticked without sending while the link was lost
    assert res.ticks == 240
    assert res.commands_compared == res.commands_recorded > 0
    assert res.unmatched_commands == 0 and res.tick_mismatches == 0
    assert res.max_abs_diff_mps <= 1e-9


# --------------------------------------------------------------------------- a log written elsewhere

MAVPROXY_LIKE = """
import math, os, struct
os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as m

T0 = {t0!r}
log = mavutil.mavlogfile({path!r}, write=True)  # pymavlink's own tlog writer, as MAVProxy uses it
vehicle = m.MAVLink(None, 1, 1)
obstacle = m.MAVLink(None, 101, 197)
obstacle.signing.secret_key = bytes(range(32))  # the obstacle's link is signed
obstacle.signing.sign_outgoing = True
obstacle.signing.link_id = 1
obstacle.signing.timestamp = 300_000_000_000
nan = float("nan")

def record(t, mav, msg, link=0):
    buf = msg.pack(mav)
    mav.seq = (mav.seq + 1) % 256
    usec = (int(t * 1e6) & ~3) | link  # MAVProxy: the low 2 bits of the stamp hold the link number
    log.write(struct.pack(">Q", usec) + bytes(buf))
    return buf

def cov(var):
    c = [0.0] * 21
    c[0] = c[6] = c[11] = var
    return c

signed = 0
for i in range(120):  # 6 s at 20 Hz
    tb = 0.05 * i
    t = T0 + 0.2 + tb  # received 0.2 s after the vehicle's boot clock says
    if i % 20 == 0:
        record(t, vehicle, m.MAVLink_heartbeat_message(2, 12, 157, 50593792, 4, 3))  # armed AUTO.LOITER
        buf = record(t, obstacle, m.MAVLink_heartbeat_message(0, 8, 0, 0, 4, 3), link=1)
        signed += bool(buf[2] & 1)
    record(t, vehicle, m.MAVLink_odometry_message(
        int(tb * 1e6), 1, 1, 0.01 * math.sin(tb), 0.0, -5.0, [1, 0, 0, 0], 0.0, 0.0, 0.0, nan, nan, nan,
        cov(0.02), cov(0.01), 0, 8, 100))
    if i % 2 == 0:
        x = 12.0 - 1.0 * tb  # an obstacle coming head-on at 1 m/s
        buf = record(t, obstacle, m.MAVLink_odometry_message(
            int(tb * 1e6), 1, 1, x, 0.2, -5.0, [1, 0, 0, 0], -1.0, 0.0, 0.0, nan, nan, nan,
            cov(0.02), [nan] + [0.0] * 20, 0, 0, 100), link=1)
        signed += bool(buf[2] & 1)
last = m.MAVLink_statustext_message(6, b"killed mid-record", 0, 0).pack(vehicle)
log.write(struct.pack(">Q", int((T0 + 6.3) * 1e6)) + bytes(last[: len(last) // 2]))  # truncated tail
log.close()
print(signed)
"""


@pytest.fixture(scope="module")
def mavproxy_log(tmp_path_factory):
    path = tmp_path_factory.mktemp("mavproxy") / "flight.tlog"
    script = textwrap.dedent(MAVPROXY_LIKE.format(t0=T0, path=str(path)))
    proc = subprocess.run([sys.executable, "-c", script], check=True, timeout=60, capture_output=True, text=True)
    return path, int(proc.stdout.strip())


def test_that_a_pymavlink_written_plain_flight_with_signing_and_a_cut_tail_replays_as_what_if(mavproxy_log):
    path, signed = mavproxy_log
    assert signed == 6 + 60  # obstacle heartbeats and odometry went out signed
    res = replay(path, SCENARIO)
    assert res.mode == "what-if" and not res.lockstep and res.time_offset_s == 0.0
    assert res.messages == 6 + 6 + 120 + 60  # the truncated record is dropped, nothing else
    assert res.outbound == 0 and res.commands_compared == 0 and res.max_abs_diff_mps is None
    assert res.companion.state.messages_rejected == 0
    assert len(res.companion.tracker) == 1  # the signed obstacle was tracked
    assert res.replans >= 15  # ~6 s of engaged ticks, a replan every 0.3 s
    assert res.command_times_s.size > 100
    vmax = res.companion.planner_config.velocity_max
    assert np.all(np.isfinite(res.commands_mps)) and np.all(np.abs(res.commands_mps) <= vmax + 1e-6)
    # It would fly toward the goal (north), keeping the obstacle's contour of touch above c_min.
    assert res.commands_mps[-1, 0] > 0.1
    planned = [r.planned_min_contour for r in res.companion.records if np.isfinite(r.planned_min_contour)]
    assert planned and min(planned) >= res.companion.planner_config.c_min - 0.05


def test_that_the_cli_replays_a_log_as_json(mavproxy_log, capsys):
    path, _ = mavproxy_log
    assert main(["replay", str(path), "--scenario", SCENARIO, "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["mode"] == "what-if" and summary["replans"] > 0 and summary["tracks"] == 1


def test_that_the_cli_prints_a_human_summary(antipodal, capsys):
    assert main(["replay", str(antipodal[1]), "--scenario", SCENARIO]) == 0
    out = capsys.readouterr().out
    assert "commands compared (recorded)" in out and "max |difference| [m/s]" in out and "inbound / outbound" in out


# --------------------------------------------------------------------------- errors


def _obstacle_only_log(path):
    mav = mavlink2.MAVLink(None, 101, 197)
    with TlogWriter(path) as log:
        for i in range(3):
            log.write(T0 + i, mav.heartbeat_encode(0, 8, 0, 0, 4, 3).pack(mav))


def test_that_a_log_without_a_vehicle_is_a_replay_error(tmp_path):
    _obstacle_only_log(tmp_path / "novehicle.tlog")
    with pytest.raises(ReplayError, match=r"novehicle.tlog: no vehicle in the log: no PX4 autopilot HEARTBEAT"):
        replay(tmp_path / "novehicle.tlog", SCENARIO)


def test_that_a_missing_log_is_a_tlog_error(tmp_path):
    with pytest.raises(TlogError, match="does not exist"):
        replay(tmp_path / "nope.tlog", SCENARIO)


@pytest.mark.parametrize(
    "name, make, message",
    [
        ("missing.tlog", None, "missing.tlog does not exist"),
        ("notes.tlog", lambda p: p.write_text("not telemetry\n" * 3), "notes.tlog is not a tlog"),
        ("empty.tlog", lambda p: p.write_bytes(b""), "empty.tlog is empty"),
        ("novehicle.tlog", _obstacle_only_log, "no PX4 autopilot HEARTBEAT"),
    ],
)
def test_that_bad_logs_exit_2_with_a_clear_message(tmp_path, capsys, name, make, message):
    path = tmp_path / name
    if make is not None:
        make(path)
    assert main(["replay", str(path), "--scenario", SCENARIO]) == 2
    err = capsys.readouterr().err
    assert err.startswith("companion replay: error: ") and message in err


def test_that_a_bad_scenario_exits_2(antipodal, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["replay", str(antipodal[1]), "--scenario", "configs/nope.toml"])
    assert exc.value.code == 2
    assert "configs/nope.toml: no such scenario file" in capsys.readouterr().err


def test_that_the_scenario_is_required(antipodal):
    with pytest.raises(SystemExit) as exc:
        main(["replay", str(antipodal[1])])
    assert exc.value.code == 2
