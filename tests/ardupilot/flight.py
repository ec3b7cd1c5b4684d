"""Fly the companion against ArduCopter SITL through a scenario's encounter and judge it against SITL's truth.

Usage (one run, or several in a row)::

    python -m tests.ardupilot.flight [--scenario configs/antipodal_ardupilot.toml] [--runs 3]
        [--trouble none|lost_estimate|stale_plan] [--adsb] [--work /tmp/ardupilot-flight]

Each run picks a free SITL instance (N >= 3), starts ArduCopter SITL in a fresh directory, runs the
test's ground station and obstacle player (:mod:`tests.ardupilot.ground`: SIM_STATE truth, the
scenario's obstacles on the companion's obstacle link from the companion's ENGAGED), runs
``companion fly --autopilot ardupilot --arm --takeoff-alt 5 --exit-after-goal 1 --tlog`` as a
subprocess, watches the vehicle for 4 s after the companion exits (LOITER, holding), stops everything,
replays the tlog with ``companion replay`` and returns the figures.

``adsb``: the obstacles are played as ADS-B instead (every obstacle ``transport = "adsb"`` for the
ground station: ADSB_VEHICLE from each obstacle's own system into SITL's ground link, which ArduCopter
forwards to the companion's link); the companion gets no obstacle link.

``trouble``: 5 s after the companion engaged, ``lost_estimate`` drops the vehicle's LOCAL_POSITION_NED
on the companion link (a relay between SITL and the companion), ``stale_plan`` stops the companion's
planning process (SIGSTOP; SIGCONT once the vehicle is in LOITER). The companion must brake within its
acceleration bound and hand the vehicle back to LOITER itself: ArduCopter would hold the last velocity
for GUID_TIMEOUT (3 s) if the stream stopped, and never leaves GUIDED by itself.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

from mavsim.scenario import load_scenario
from tests.ardupilot.ground import Ground
from tests.ardupilot.sitl import REPO, CentredSticks, Sitl, free_instance
from tests.support.ports import free_udp_port
from tests.support.runs import fly_runs

logger = logging.getLogger(__name__)

TAKEOFF_ALT_M = 5.0
COMPANION_TIMEOUT_S = 170.0
HOLD_WATCH_S = 8.0
HEARTBEAT_LAG_S = 1.2     # the ground link's HEARTBEAT may show a mode up to a second after the companion's
TROUBLE_AFTER_S = 5.0     # trouble starts this long after ENGAGED
GUID_TIMEOUT_S = 3.0      # ArduCopter's default: how long it would hold the last velocity without a stream


def _companion(*args: str) -> list[str]:
    return [sys.executable, "-m", "companion.cli", *args]


def _children(pid: int) -> list[int]:
    try:
        return [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


def fly_once(work: Path, scenario: Path, seed: int = 0, trouble: str = "none", extra: tuple[str, ...] = (),
             adsb: bool = False) -> dict:
    """One flight; returns the figures (see the module docstring)."""
    work.mkdir(parents=True, exist_ok=True)
    played = scenario
    if adsb:   # the ground station's copy: every obstacle as ADS-B; the companion's scenario is unchanged
        played = work / "scenario_adsb.toml"
        played.write_text(Path(scenario).read_text().replace("[[world.obstacles]]\n",
                                                             '[[world.obstacles]]\ntransport = "adsb"\n'))
    tlog = work / "flight.tlog"
    with open(scenario, "rb") as f:
        c_min = float(tomllib.load(f)["planner"]["c_min"])
    instance, obstacle_port = free_instance(), free_udp_port()
    result: dict = {"work": str(work), "c_min": c_min, "instance": instance, "trouble": trouble,
                    "obstacles": "adsb" if adsb else "link"}
    relay = trouble == "lost_estimate"
    ground = Ground(load_scenario(played), 14550 + instance, obstacle_port, seed=seed,
                    relay_to=14540 + instance if relay else None)
    device = f"udpclient:127.0.0.1:{ground.relay_port}" if relay else None
    t_trouble = None
    stopped: list[int] = []
    ground.start()
    try:
        with Sitl(work / "sitl", instance, companion_device=device) as sitl, CentredSticks(instance) as sticks:
            cmd = _companion("fly", "--connect", f"udpin:127.0.0.1:{14540 + instance}", "--scenario", str(scenario),
                             "--autopilot", "ardupilot", "--arm", "--takeoff-alt", str(TAKEOFF_ALT_M),
                             *(() if adsb else ("--obstacles", f"udpin:127.0.0.1:{obstacle_port}")), "--exit-after-goal", "1",
                             "--tlog", str(tlog), "--duration", str(COMPANION_TIMEOUT_S - 20), "--json", *extra)
            fly = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
            deadline = time.monotonic() + COMPANION_TIMEOUT_S
            try:
                while fly.poll() is None and time.monotonic() < deadline:
                    t = ground.now()
                    if ground.engaged_t is not None:
                        sticks.start()                   # airborne: the pilot's throttle at mid from here
                    if trouble != "none" and t_trouble is None and ground.engaged_t is not None \
                            and t - ground.engaged_t >= TROUBLE_AFTER_S:
                        t_trouble = t
                        if trouble == "lost_estimate":
                            ground.drop_pose()
                        elif trouble == "stale_plan":
                            stopped = _children(fly.pid)
                            for pid in stopped:
                                os.kill(pid, signal.SIGSTOP)
                        logger.info("t=%.2f trouble: %s", t, trouble)
                    if stopped and ground.mode == "LOITER":
                        for pid in stopped:
                            os.kill(pid, signal.SIGCONT)
                        stopped = []
                    time.sleep(0.02)
                out, err = fly.communicate(timeout=max(1.0, deadline - time.monotonic()))
                rc = fly.returncode
            except subprocess.TimeoutExpired:
                fly.kill()
                out, err = fly.communicate()
                rc, err = -9, (err or "") + f"\ncompanion killed after {COMPANION_TIMEOUT_S} s"
            finally:
                for pid in stopped:
                    try:
                        os.kill(pid, signal.SIGCONT)
                    except ProcessLookupError:
                        pass
            t_exit = ground.now()
            time.sleep(HOLD_WATCH_S)
            result["sitl_alive"] = sitl.alive()
    finally:
        ground.stop()
    (work / "companion.stderr").write_text(err)
    result["companion_rc"] = rc
    report = json.loads(out) if out.strip().startswith("{") else {}
    result["companion_traceback"] = "Traceback" in err
    result["companion_report"] = {k: report.get(k) for k in (
        "outcome", "exit_code", "phase", "goal_reached_companion_t_s", "replans", "min_realised_contour",
        "failed_plans", "alerts", "setpoint_gap_max_ms", "tick_max_ms", "stale_events", "braking_events")}
    intake = report.get("obstacle_intake") or {}
    result["obstacle_reports_accepted"] = dict(intake.get("accepted", {}))
    result["obstacle_reports_rejected"] = intake.get("rejected_total")
    result["adsb_sent"], result["adsb_held"] = ground.adsb_sent, ground.adsb_held
    _figures(result, ground, report, t_exit, t_trouble)
    rep = subprocess.run(_companion("replay", str(tlog), "--scenario", str(scenario), "--arm", "--takeoff-alt",
                                    str(TAKEOFF_ALT_M), "--exit-after-goal", "1", "--json", *extra),
                         capture_output=True, text=True, timeout=300, cwd=REPO)
    if rep.returncode == 0:
        s = json.loads(rep.stdout)
        result["replay"] = {k: s.get(k) for k in ("replans", "commands_compared", "commands_recorded",
                                                  "max_abs_diff_mps", "unmatched_commands", "tick_mismatches")}
    else:
        result["replay"] = {"error": rep.stderr.strip()[-500:]}
    return result


def _at(ts: np.ndarray, xs: np.ndarray, t0: float, t1: float) -> np.ndarray | None:
    m = (ts >= t0) & (ts <= t1)
    return xs[m].mean(axis=0) if m.any() else None


def _figures(result: dict, ground: Ground, report: dict, t_exit: float, t_trouble: float | None) -> None:
    truth_t = np.array([t for t, _, _ in ground.truth])
    truth_p = np.array([p for _, p, _ in ground.truth]).reshape(-1, 3)
    truth_v = np.array([v for _, _, v in ground.truth]).reshape(-1, 3)
    est_t = np.array([t for t, _ in ground.estimate])
    est_p = np.array([p for _, p in ground.estimate]).reshape(-1, 3)
    t_eng = ground.engaged_t
    if truth_t.size:   # for a look afterwards: SIM_STATE's time (ground clock, s), NED position and velocity
        np.savez_compressed(Path(result["work"]) / "truth.npz", t=truth_t, p=truth_p, v=truth_v,
                            modes_t=np.array([t for t, _ in ground.modes]), modes=np.array([m for _, m in ground.modes]))
    result["modes"] = ground.modes
    result["engaged_after_start_s"] = None if t_eng is None else round(t_eng, 2)
    if t_eng is None or truth_t.size == 0:
        result["why"] = "never engaged" if truth_t.size else "no truth (SIM_STATE) received"
        return
    # takeoff: the companion's own reading (the vehicle's estimate), the ground link's estimate and the
    # truth over the 0.5 s before ENGAGED, each above its value on the ground
    said = [text for _, text in report.get("events", []) if str(text).startswith("takeoff height reached")]
    result["takeoff_said"] = said[0] if said else None
    z0_true = truth_p[0, 2]
    z0_est = est_p[: max(1, min(20, est_p.shape[0])), 2].mean() if est_p.size else np.nan
    tp = _at(truth_t, truth_p, t_eng - 0.5, t_eng)
    ep = _at(est_t, est_p, t_eng - 0.5, t_eng)
    result["takeoff_height_estimate_m"] = None if ep is None else round(float(-(ep[2] - z0_est)), 3)
    result["takeoff_height_truth_m"] = None if tp is None else round(float(-(tp[2] - z0_true)), 3)
    result["min_true_clearance_m"] = ground.referees["truth"].summary()["min_clearance_m"]
    result["min_estimate_clearance_m"] = ground.referees["estimate"].summary()["min_clearance_m"]
    result["min_true_goal_distance_m"] = ground.referees["truth"].summary()["min_goal_distance_m"]
    t_goal = report.get("goal_reached_companion_t_s")
    engaged = [t for t, text in report.get("events", []) if str(text).startswith("ENGAGED")]
    result["time_to_goal_s"] = None if t_goal is None or not engaged else round(float(t_goal - engaged[0]), 2)
    # the end: LOITER from the companion's exit on, the vehicle holding still over the watch
    settled = t_exit + HEARTBEAT_LAG_S
    before = [m for t, m in ground.modes if t <= settled]
    end_modes = before[-1:] + [m for t, m in ground.modes if t > settled]
    result["modes_after_exit"] = sorted(set(end_modes))
    watch = truth_t >= settled
    if watch.any():
        p = truth_p[watch]
        result["hold_drift_m"] = round(float(np.linalg.norm(p[-1] - p[0])), 3)
        speed = np.linalg.norm(truth_v[watch][:, :2], axis=1)
        result["hold_speed_max_mps"] = round(float(speed.max()), 3)
        last = truth_t[watch] >= truth_t[watch][-1] - 1.0
        result["hold_final_speed_mps"] = round(float(speed[last].max()), 3)
    # holding: LOITER throughout, at rest by the end of the watch. The vehicle is handed back
    # still moving (1 s after the goal; 0.55 m/s in one run) and LOITER brakes, then pulls back to
    # where it stopped at 0.1-0.16 m/s for another 2-3 s (measured: 0.07 m/s 4.4 s after LOITER,
    # still falling), so the watch is 8 s, the drift bound 1 m and the rest judged by the speed.
    result["holds_after_exit"] = bool(end_modes) and all(m == "LOITER" for m in end_modes) \
        and result.get("hold_drift_m", 9.9) < 1.0 and result.get("hold_final_speed_mps", 9.9) < 0.1
    result["texts"] = [(round(t - t_eng, 2), x) for t, x in ground.texts if not x.startswith(("ENGAGED", "companion"))][-30:]
    if t_trouble is not None:
        _brake_figures(result, ground, truth_t, truth_p, truth_v, t_trouble)


def _brake_figures(result: dict, ground: Ground, truth_t, truth_p, truth_v, t_trouble: float) -> None:
    """How the vehicle stopped after the trouble: its speed then, when it was below 0.1 m/s, how far it
    went, the largest deceleration (0.2 s differences of the true velocity) and when LOITER came."""
    after = truth_t >= t_trouble
    t, p, v = truth_t[after], truth_p[after], truth_v[after]
    speed = np.linalg.norm(v[:, :2], axis=1)
    result["trouble_speed_mps"] = round(float(speed[0]), 3)
    loiter = [tm for tm, m in ground.modes if tm >= t_trouble and m == "LOITER"]
    result["loiter_after_trouble_s"] = round(loiter[0] - t_trouble, 2) if loiter else None
    still = np.nonzero(speed < 0.1)[0]
    if still.size:
        k = int(still[0])
        result["stopped_after_trouble_s"] = round(float(t[k] - t[0]), 2)
        result["distance_to_stop_m"] = round(float(np.linalg.norm(p[k, :2] - p[0, :2])), 3)
    result["distance_if_guid_timeout_m"] = round(float(speed[0]) * GUID_TIMEOUT_S, 3)
    step = max(1, int(round(0.2 / max(1e-3, float(np.median(np.diff(t))) if t.size > 2 else 0.02))))
    if t.size > step:
        acc = np.linalg.norm(v[step:, :2] - v[:-step, :2], axis=1) / (t[step:] - t[:-step])
        result["max_accel_after_trouble_mps2"] = round(float(acc.max()), 3)
    result["pose_messages_dropped"] = ground.dropped
    if loiter:
        end = truth_t >= loiter[0] + HEARTBEAT_LAG_S
        if end.any():
            q = truth_p[end]
            result["drift_in_loiter_m"] = round(float(np.linalg.norm(q[-1, :2] - q[0, :2])), 3)


def judge_safety(r: dict) -> list[str]:
    bad = []
    if r.get("min_true_clearance_m") is None or r["min_true_clearance_m"] <= 0.0:
        bad.append(f"collision in truth: min clearance {r.get('min_true_clearance_m')} m")
    if not r.get("holds_after_exit"):
        bad.append(f"end: modes {r.get('modes_after_exit')}, drift {r.get('hold_drift_m')} m, "
                   f"speed at the end {r.get('hold_final_speed_mps')} m/s")
    return bad


def judge_replay(r: dict) -> list[str]:
    rp = r.get("replay", {})
    if rp.get("max_abs_diff_mps") != 0.0 or rp.get("unmatched_commands") or \
            rp.get("commands_compared") != rp.get("commands_recorded"):
        return [f"replay {rp}"]
    return []


def judge_encounter(r: dict) -> list[str]:
    bad = []
    rc = r.get("companion_report", {})
    if rc.get("min_realised_contour") is None or rc["min_realised_contour"] < r.get("c_min", 0.90) - 1e-9:
        bad.append(f"realised contour {rc.get('min_realised_contour')} below c_min")
    if r.get("time_to_goal_s") is None or r["time_to_goal_s"] > 25.0:
        bad.append(f"time to goal {r.get('time_to_goal_s')} s after ENGAGED")
    if rc.get("outcome") != "goal reached":
        bad.append(f"outcome {rc.get('outcome')}")
    return bad


def judge_takeoff(r: dict) -> list[str]:
    """The takeoff height within 0.3 m of the height asked, in the vehicle's own estimate (truth printed beside)."""
    h = r.get("takeoff_height_estimate_m")
    if h is None or abs(h - TAKEOFF_ALT_M) > 0.3:
        return [f"takeoff height {h} m in the estimate ({r.get('takeoff_height_truth_m')} m in truth), asked {TAKEOFF_ALT_M} m"]
    return []


def judge_brake(r: dict) -> list[str]:
    """After a stale plan or a lost estimate: braked to a stop in less distance than GUID_TIMEOUT's drift would
    be, within the acceleration bound (with margin for ArduCopter's own shaping), then LOITER, holding."""
    bad = []
    if r.get("loiter_after_trouble_s") is None:
        bad.append("never in LOITER after the trouble")
    if r.get("distance_to_stop_m") is None or r["distance_to_stop_m"] >= r.get("distance_if_guid_timeout_m", 0.0):
        bad.append(f"stopped after {r.get('distance_to_stop_m')} m (GUID_TIMEOUT: {r.get('distance_if_guid_timeout_m')} m)")
    if r.get("max_accel_after_trouble_mps2") is None or r["max_accel_after_trouble_mps2"] > 2.5:
        bad.append(f"braking at {r.get('max_accel_after_trouble_mps2')} m/s^2")
    if r.get("companion_report", {}).get("phase") != "HELD" or r.get("drift_in_loiter_m", 9.9) > 0.5:
        bad.append(f"end: phase {r.get('companion_report', {}).get('phase')}, drift in LOITER {r.get('drift_in_loiter_m')} m")
    return bad


def judge(r: dict) -> list[str]:
    if r.get("trouble", "none") != "none":
        return judge_brake(r) + judge_replay(r)
    return judge_safety(r) + judge_replay(r) + judge_encounter(r) + judge_takeoff(r)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default=str(REPO / "configs" / "antipodal_ardupilot.toml"))
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--trouble", default="none", choices=("none", "lost_estimate", "stale_plan"))
    ap.add_argument("--adsb", action="store_true", help="play the obstacles as ADS-B through SITL's ground link")
    ap.add_argument("--work", default="/tmp/ardupilot-flight")
    ap.add_argument("extra", nargs="*", help="extra companion arguments (after --)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO)
    return fly_runs(lambda i: fly_once(Path(args.work) / f"run{i}", Path(args.scenario), seed=i, trouble=args.trouble,
                                       extra=tuple(args.extra), adsb=args.adsb), judge, args.runs)


if __name__ == "__main__":
    sys.exit(main())
