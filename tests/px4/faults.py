"""Faults that real PX4 SITL produces, flown through the antipodal encounter (docs/FAULTS.md).

Usage (five runs of each for the note)::

    python -m tests.px4.faults --fault gps-off [--runs 5] [--work /tmp/px4-faults]
    python -m tests.px4.faults --fault restart [--runs 5] [--reengage]

``gps-off``: 3 s after PX4 entered OFFBOARD (the obstacles about 8 m away and closing) PX4's
simulated GPS is stopped for 5 s and started again (``sensor_gps_sim stop`` / ``start`` on
PX4's console: this build does not acknowledge ``failure gps off``, its failure injection
reaching no simulated sensor, measured "Timeout waiting for ack"). PX4's EKF dead-reckons:
the position covariance it reports in ODOMETRY grows, the companion's planner (``[companion]
drone_covariance = "reported"``) widens its margins with it, and when the GPS is back the EKF
resets its position (ODOMETRY ``reset_counter``), which the companion acts on (plan dropped,
replanned from the new estimate).

``restart``: 3 s after OFFBOARD the companion is SIGKILLed with its planning process (its
process group); PX4's offboard-loss failsafe takes the vehicle; the same command line is then
started again. It must find the vehicle armed in a failsafe and not take it back (exit 1,
``GAVE_UP``), sending no setpoint and no command; with ``--reengage`` it takes it back from its
own hover and flies to the goal.

Judged against SIH's ground truth as :mod:`tests.px4.flight` judges a flight. Everything
started is stopped; every wait is bounded.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from companion.mavlink.tlog import read_tlog
from mavsim.scenario import load_scenario
from mavsim.traffic import PlayerLinks, TrafficPlayer
from tests.px4.flight import (COMPANION_TIMEOUT_S, HOLD, HOLD_WATCH_S, OBSTACLE_PORT, TAKEOFF_ALT_M,
                              companion_argv, fly_once, judge_replay, judge_safety)
from tests.px4.sitl import REPO, Sitl, raise_priority
from tests.support.processes import kill_process_group
from tests.support.runs import fly_runs

logger = logging.getLogger(__name__)

SCENARIO = REPO / "configs" / "antipodal_px4.toml"
FAULT_AFTER_S = 3.0      # after PX4's OFFBOARD: the obstacles about 8 m away, closing at 3 m/s
GPS_OFF_S = 5.0          # the outage (PX4's EKF2_NOAID_TOUT is 5 s)
FAILSAFE_WAIT_S = 5.0    # PX4 leaves OFFBOARD COM_OF_LOSS_T (1 s) after the last setpoint
COMPANION_SYSID, COMPANION_COMPID = 1, 191


def px4_console(sitl: Sitl, module: str, *args: str) -> tuple[int, str]:
    """Run ``px4-MODULE ARGS`` against the running PX4 (its console client); (exit code, output)."""
    exe = sitl.work_dir / "px4-sitl" / "bin" / f"px4-{module}"
    out = subprocess.run([str(exe), *args], capture_output=True, text=True, timeout=10.0,
                         cwd=sitl.work_dir / "run")
    return out.returncode, (out.stdout + out.stderr).strip()[-300:]


def _wait_in_offboard(player: TrafficPlayer, after_s: float, timeout_s: float = COMPANION_TIMEOUT_S) -> float | None:
    """Wait until ``after_s`` s after PX4's first OFFBOARD (the player's clock); that time, or None."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        t0 = player.engaged_t_s
        if t0 is not None and player.now_s() - t0 >= after_s:
            return player.now_s()
        time.sleep(0.02)
    return None


def gps_outage(after_s: float = FAULT_AFTER_S, for_s: float = GPS_OFF_S):
    """A ``during`` hook of :func:`tests.px4.flight.fly_once`: PX4's GPS off ``after_s`` s into
    OFFBOARD for ``for_s`` s. Returns the console's answers and the times (s after OFFBOARD)."""
    def inject(player: TrafficPlayer, sitl: Sitl) -> dict:
        t_off = _wait_in_offboard(player, after_s)
        if t_off is None:
            return {"why": "never in OFFBOARD"}
        off = px4_console(sitl, "sensor_gps_sim", "stop")
        t_off = player.now_s() - player.engaged_t_s
        while player.now_s() - player.engaged_t_s < t_off + for_s:
            time.sleep(0.02)
        on = px4_console(sitl, "sensor_gps_sim", "start")
        t_on = player.now_s() - player.engaged_t_s
        return {"gps_off_s": round(t_off, 2), "gps_on_s": round(t_on, 2), "off": off, "on": on}
    return inject


def reported_position_std(tlog: Path) -> dict:
    """The vehicle's own ODOMETRY in the companion's tlog: the largest horizontal standard
    deviation it reported (m, the square root of the larger of the x and y variances), the
    first one (before the outage) and the reset counters seen."""
    sigmas, counters = [], []
    for _, m in read_tlog(tlog):
        if m.get_type() != "ODOMETRY" or m.get_srcSystem() != 1 or m.get_srcComponent() != 1:
            continue
        c = m.pose_covariance
        if np.isfinite(c[0]) and np.isfinite(c[6]):
            sigmas.append(float(np.sqrt(max(c[0], c[6]))))
        counters.append(int(m.reset_counter))
    return {"first_m": round(sigmas[0], 3) if sigmas else None, "largest_m": round(max(sigmas), 3) if sigmas else None,
            "reset_counters": sorted(set(counters))}


def setpoints_after_leaving_offboard(tlog: Path) -> int | None:
    """Setpoints the companion sent after the first HEARTBEAT of the vehicle showing it out of
    OFFBOARD once engaged (its tlog; None: it never left OFFBOARD while the companion ran)."""
    from companion.mavlink.autopilots import px4

    engaged, left_t, after = False, None, 0
    for t, m in read_tlog(tlog):
        kind = m.get_type()
        if kind == "HEARTBEAT" and m.get_srcSystem() == 1 and m.get_srcComponent() == 1:
            offboard = m.custom_mode == px4.OFFBOARD
            engaged = engaged or offboard
            if engaged and not offboard and left_t is None:
                left_t = t
        elif kind == "SET_POSITION_TARGET_LOCAL_NED" and left_t is not None and t > left_t \
                and m.get_srcComponent() == COMPANION_COMPID:
            after += 1
    return None if left_t is None else after


def fly_gps_outage(work: Path, seed: int = 0, after_s: float = FAULT_AFTER_S, for_s: float = GPS_OFF_S) -> dict:
    """One flight with PX4's GPS off for ``for_s`` s, ``after_s`` s into OFFBOARD; the figures."""
    r = fly_once(work, SCENARIO, seed=seed, during=gps_outage(after_s, for_s))
    tlog = work / "flight.tlog"
    if tlog.is_file():
        r["reported_position_std"] = reported_position_std(tlog)
        r["setpoints_after_leaving_offboard"] = setpoints_after_leaving_offboard(tlog)
    return r


def judge_gps_outage(r: dict) -> list[str]:
    """The failed checks of a GPS-outage flight (docs/FAULTS.md, the GPS row).

    Always: no collision in SIH's truth, the replay exact, the outage real (PX4's reported
    standard deviation at least doubled) and said (``companion: position uncertain``). Then one of PX4's two outcomes (a 5 s outage races
    PX4's own 5 s limit on dead reckoning, EKF2_NOAID_TOUT): PX4 dead-reckoned through it, and
    the companion acted on the reset when the GPS was back and flew to the goal, handing back to
    Hold without a failsafe; or PX4 declared its position invalid first and took the vehicle
    (failsafe), and the companion named it (exit 7) and sent no setpoint after the HEARTBEAT
    showing it."""
    bad = judge_replay(r)
    if r.get("min_true_clearance_m") is None or r["min_true_clearance_m"] <= 0.0:
        bad.append(f"collision in truth: {r.get('min_true_clearance_m')} m")
    d = r.get("during") or {}
    if d.get("off", [1])[0] != 0 or d.get("on", [1])[0] != 0:
        bad.append(f"GPS not switched: {d}")
    std = r.get("reported_position_std") or {}
    if not std.get("largest_m") or not std.get("first_m") or std["largest_m"] < 2.0 * std["first_m"]:
        bad.append(f"PX4's reported position did not degrade: {std}")
    rc = r.get("companion_report") or {}
    if not rc.get("position_uncertain_events"):
        bad.append(f"the uncertain position was not said: {rc.get('reported_position_sd_max_m')} m at most")
    if r.get("companion_rc") == 7 and rc.get("outcome") == "autopilot failsafe":
        if not r.get("failsafe_texts"):
            bad.append("exit 7 without PX4's 'Failsafe activated'")
        if r.get("setpoints_after_leaving_offboard") != 0:
            bad.append(f"{r.get('setpoints_after_leaving_offboard')} setpoints after PX4 left OFFBOARD")
        if "OFFBOARD" in (r.get("modes_after_exit") or ["OFFBOARD"]):
            bad.append(f"modes after the exit {r.get('modes_after_exit')}")
    else:
        bad += judge_safety(r)
        if not rc.get("estimator_resets"):
            bad.append(f"no estimator reset acted on: {rc.get('estimator_resets')}")
        if r.get("companion_rc") != 0 or rc.get("outcome") != "goal reached":
            bad.append(f"end: exit {r.get('companion_rc')}, outcome {rc.get('outcome')}")
    return bad


# ---------------------------------------------------------------------------------------- restart

def _fly_argv(tlog: Path, *extra: str) -> list[str]:
    return companion_argv("fly", "--connect", "udpin:127.0.0.1:14540", "--scenario", str(SCENARIO), "--arm",
                          "--obstacles", f"udpin:127.0.0.1:{OBSTACLE_PORT}", "--takeoff-alt", str(TAKEOFF_ALT_M),
                          "--exit-after-goal", "1", "--tlog", str(tlog), "--duration", str(COMPANION_TIMEOUT_S - 20),
                          "--json", *extra)


def fly_killed_and_restarted(work: Path, seed: int = 0, after_s: float = FAULT_AFTER_S,
                             reengage: bool = False) -> dict:
    """The companion SIGKILLed ``after_s`` s into OFFBOARD and started again; the figures."""
    work.mkdir(parents=True, exist_ok=True)
    r: dict = {"work": str(work), "reengage": reengage}
    player = TrafficPlayer(load_scenario(SCENARIO), PlayerLinks(obstacle_port=OBSTACLE_PORT), seed=seed,
                           keep_samples=True)
    stop, errors = threading.Event(), []

    def play() -> None:
        try:
            player.run(2 * COMPANION_TIMEOUT_S + 120.0, stop.is_set)
        except Exception as exc:  # reported by the test, never swallowed
            logger.exception("traffic player failed")
            errors.append(repr(exc))

    nice_before = os.getpriority(os.PRIO_PROCESS, 0)
    raise_priority()
    first = second = None
    try:
        with player, Sitl(work / "sih") as sitl:
            thread = threading.Thread(target=play, daemon=True)
            thread.start()
            try:
                first = subprocess.Popen(_fly_argv(work / "first.tlog"), stdout=subprocess.PIPE,
                                         stderr=subprocess.PIPE, text=True, cwd=REPO, start_new_session=True,
                                         preexec_fn=raise_priority)
                t_kill = _wait_in_offboard(player, after_s)
                if t_kill is None:
                    r["why"] = "never in OFFBOARD"
                    return r
                kill_process_group(first)
                t0 = player.engaged_t_s
                r["killed_s"] = round(player.now_s() - t0, 2)
                deadline = time.monotonic() + FAILSAFE_WAIT_S
                while time.monotonic() < deadline and not [m for t, m in player.mode_changes
                                                            if t > t0 and m != "OFFBOARD"]:
                    time.sleep(0.02)
                left = [(t, m) for t, m in player.mode_changes if t > t0 and m != "OFFBOARD"]
                r["failsafe"] = (round(left[0][0] - t0, 2), left[0][1]) if left else None
                second = subprocess.Popen(_fly_argv(work / "second.tlog", *(("--reengage",) if reengage else ())),
                                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO,
                                          start_new_session=True, preexec_fn=raise_priority)
                out, err = second.communicate(timeout=COMPANION_TIMEOUT_S)
                r["second_exit_s"] = round(player.now_s() - t0, 2)
                time.sleep(HOLD_WATCH_S)
                r["px4_alive"] = sitl.alive()
            finally:
                for proc in (first, second):
                    if proc is not None and proc.poll() is None:
                        kill_process_group(proc)
                stop.set()
                thread.join(timeout=5.0)
    finally:
        try:
            os.setpriority(os.PRIO_PROCESS, 0, nice_before)
        except OSError:
            pass
    (work / "second.stderr").write_text(err)
    report = json.loads(out) if out.strip().startswith("{") else {}
    r["world_errors"] = errors
    r["second_rc"] = second.returncode
    r["second_traceback"] = "Traceback" in err
    r["second_report"] = {k: report.get(k) for k in ("outcome", "exit_code", "phase", "events",
                                                     "goal_reached_companion_t_s", "min_realised_contour")}
    t0 = player.engaged_t_s
    r["modes"] = [(round(t - t0, 2), m) for t, m in player.mode_changes]   # s after the first OFFBOARD
    r["px4_texts"] = [(round(t - t0, 2), text.strip()) for t, text in player.texts]
    summary = player.summary()
    r["min_true_clearance_m"] = summary["referee"]["truth"]["min_clearance_m"]
    sent = [m for _, m in read_tlog(work / "second.tlog")
            if m.get_srcSystem() == COMPANION_SYSID and m.get_srcComponent() == COMPANION_COMPID]
    setpoints = [m for m in sent if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]
    r["second_setpoints"] = len(setpoints)
    r["second_commands"] = sum(m.get_type() in ("COMMAND_LONG", "COMMAND_INT") for m in sent)
    r["second_first_setpoint_mps"] = [setpoints[0].vx, setpoints[0].vy, setpoints[0].vz] if setpoints else None
    return r


def judge_restart(r: dict) -> list[str]:
    """The failed checks of a kill-and-restart flight (docs/FAULTS.md, the restart row)."""
    bad = []
    if r.get("min_true_clearance_m") is None or r["min_true_clearance_m"] <= 0.0:
        bad.append(f"collision in truth: {r.get('min_true_clearance_m')} m")
    if r.get("failsafe") is None:
        bad.append("PX4 never left OFFBOARD after the kill")
    if r.get("second_traceback") or r.get("world_errors"):
        bad.append(f"traceback or player error: {r.get('world_errors')}")
    rep = r.get("second_report") or {}
    offboards = [m for _, m in r.get("modes", []) if m == "OFFBOARD"]
    if r.get("reengage"):
        if r.get("second_rc") != 0 or rep.get("outcome") != "goal reached":
            bad.append(f"second fly: exit {r.get('second_rc')}, outcome {rep.get('outcome')}")
        if r.get("second_first_setpoint_mps") != [0.0, 0.0, 0.0]:
            bad.append(f"first setpoint of the second fly {r.get('second_first_setpoint_mps')}, not its own hover")
        if len(offboards) != 2 or not r.get("modes") or r["modes"][-1][1] != HOLD:
            bad.append(f"modes {r.get('modes')}")
    else:
        if r.get("second_rc") != 1 or rep.get("phase") != "GAVE_UP":
            bad.append(f"second fly: exit {r.get('second_rc')}, phase {rep.get('phase')}")
        if r.get("second_setpoints") or r.get("second_commands"):
            bad.append(f"second fly sent {r.get('second_setpoints')} setpoints, {r.get('second_commands')} commands")
        if len(offboards) != 1:
            bad.append(f"OFFBOARD taken back: modes {r.get('modes')}")
    return bad


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fault", choices=("gps-off", "restart"), required=True)
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--reengage", action="store_true", help="restart: the second fly has --reengage")
    ap.add_argument("--work", default="/tmp/px4-faults")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO)
    work = Path(args.work)
    if args.fault == "gps-off":
        return fly_runs(lambda i: fly_gps_outage(work / f"gps{i}", seed=i), judge_gps_outage, args.runs)
    return fly_runs(lambda i: fly_killed_and_restarted(work / f"restart{i}", seed=i, reengage=args.reengage),
                    judge_restart, args.runs)


if __name__ == "__main__":
    sys.exit(main())
