"""Fly the companion against PX4 SITL through a scenario's encounter and judge it against SIH's ground truth.

Usage (one run, or five for the note)::

    python -m tests.px4.flight [--scenario configs/antipodal_px4.toml] [--runs 5] [--work /tmp/px4-flight]

Each run starts PX4 SIH in a fresh directory, runs mavsim's traffic player
(:class:`mavsim.traffic.TrafficPlayer`: obstacles to the companion from OFFBOARD, ground
truth), runs ``companion fly --arm --takeoff-alt 5
--exit-after-goal 1 --tlog`` as a subprocess, watches PX4 for 4 s after the companion
exits (it must hold, without "Failsafe" from 3 s before the companion stopped on; "Failsafe"
texts earlier in the flight are reported with the largest gap of the setpoint stream, which
PX4 answers with one after COM_OF_LOSS_T = 1 s), stops everything, replays the tlog with
``companion replay`` and returns the figures. Everything started is stopped.
"""

from __future__ import annotations

import argparse
import json
import logging
import subprocess
import sys
import threading
import time
import tomllib
from collections.abc import Callable
from pathlib import Path

import numpy as np

import os

from mavsim.scenario import load_scenario
from mavsim.traffic import PlayerLinks, TrafficPlayer
from tests.px4.sitl import REPO, Sitl, raise_priority
from tests.support.runs import fly_runs

logger = logging.getLogger(__name__)

TAKEOFF_ALT_M = 5.0
COMPANION_TIMEOUT_S = 150.0
HOLD_WATCH_S = 4.0
HEARTBEAT_LAG_S = 1.2   # how much later the ground link's HEARTBEAT may show a mode than the companion's
TAKEOFF_WINDOW_S = 0.5   # the takeoff height is the mean true height over this long before OFFBOARD
OBSTACLE_PORT = 14601  # the companion's receive-only obstacle link (`fly --obstacles`)
HOLD = "AUTO.LOITER"   # armed (the player marks a disarmed mode " disarmed")


def companion_argv(*args: str) -> list[str]:
    """The command line of ``companion ARGS`` with this Python."""
    return [sys.executable, "-m", "companion.cli", *args]


def fly_once(work: Path, scenario: Path, seed: int = 0, extra: tuple[str, ...] = (),
             signal_after_offboard: tuple[int, float] | None = None,
             during: Callable[[TrafficPlayer, Sitl], object] | None = None,
             params: dict[str, float] | None = None) -> dict:
    """One flight; returns the figures (see the module docstring).

    ``signal_after_offboard = (signum, s)`` sends the companion that signal ``s`` seconds after
    PX4 entered OFFBOARD (an operator's Ctrl-C or systemd's SIGTERM mid-encounter).
    ``during(player, sitl)`` runs in a thread beside the flight from the companion's start (a
    fault injected into PX4); what it returns is the result's ``during``. ``params``: PX4's
    boot parameters (default :data:`tests.px4.sitl.PARAMS`).
    """
    work.mkdir(parents=True, exist_ok=True)
    tlog = work / "flight.tlog"
    with open(scenario, "rb") as f:
        scen = tomllib.load(f)
    result_c_min = float(scen["planner"]["c_min"])
    result: dict = {"work": str(work), "c_min": result_c_min}
    nice_before = os.getpriority(os.PRIO_PROCESS, 0)
    raise_priority()   # the player's thread too: its truth and obstacle stamps are wall-clock
    result["nice"] = os.getpriority(os.PRIO_PROCESS, 0)
    try:
        _fly(work, scenario, seed, extra, tlog, result, signal_after_offboard, during, params)
    finally:
        try:
            os.setpriority(os.PRIO_PROCESS, 0, nice_before)
        except OSError:
            pass
    return result


def _run_companion(cmd: list[str], player: TrafficPlayer,
                   signal_after_offboard: tuple[int, float] | None) -> subprocess.CompletedProcess:
    """Run ``companion fly`` (killed after COMPANION_TIMEOUT_S), signalled after OFFBOARD if asked."""
    fly = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO,
                           preexec_fn=raise_priority)
    deadline = time.monotonic() + COMPANION_TIMEOUT_S
    try:
        if signal_after_offboard is not None:
            signum, after_s = signal_after_offboard
            while fly.poll() is None and time.monotonic() < deadline:
                t_off = player.engaged_t_s
                if t_off is not None and player.now_s() - t_off >= after_s:
                    fly.send_signal(signum)
                    break
                time.sleep(0.05)
        out, err = fly.communicate(timeout=max(1.0, deadline - time.monotonic()))
        return subprocess.CompletedProcess(cmd, fly.returncode, out, err)
    except subprocess.TimeoutExpired:
        fly.kill()
        _, err = fly.communicate()
        return subprocess.CompletedProcess(cmd, -9, "", (err or "") + f"\ncompanion killed after {COMPANION_TIMEOUT_S} s")


def _fly(work: Path, scenario: Path, seed: int, extra: tuple[str, ...], tlog: Path, result: dict,
         signal_after_offboard: tuple[int, float] | None = None,
         during: Callable[[TrafficPlayer, Sitl], object] | None = None,
         params: dict[str, float] | None = None) -> None:
    """The flight, its checks and the replay of :func:`fly_once`, filling ``result``. The
    obstacles and the ground truth are mavsim's traffic player (``mavsim traffic``), run in a
    thread of this process: it plays the scenario's obstacles on the companion's obstacle link
    from PX4's first armed OFFBOARD and hears SIH's truth and PX4's GCS link."""
    player = TrafficPlayer(load_scenario(scenario), PlayerLinks(obstacle_port=OBSTACLE_PORT), seed=seed,
                           keep_samples=True)
    stop = threading.Event()
    errors: list[str] = []

    def play() -> None:
        try:
            player.run(COMPANION_TIMEOUT_S + HOLD_WATCH_S + 120.0, stop.is_set)
        except Exception as exc:  # reported by the test, never swallowed
            logger.exception("traffic player failed")
            errors.append(repr(exc))

    with player, Sitl(work / "sih", params=params) as sitl:
        thread = threading.Thread(target=play, daemon=True)
        thread.start()
        if during is not None:
            def fault() -> None:
                try:
                    result["during"] = during(player, sitl)
                except Exception as exc:  # reported by the test, never swallowed
                    logger.exception("fault injection failed")
                    errors.append(repr(exc))
            threading.Thread(target=fault, daemon=True).start()
        try:
            proc = _run_companion(
                companion_argv("fly", "--connect", "udpin:127.0.0.1:14540", "--scenario", str(scenario), "--arm",
                               "--obstacles", f"udpin:127.0.0.1:{OBSTACLE_PORT}",
                               "--takeoff-alt", str(TAKEOFF_ALT_M), "--exit-after-goal", "1", "--tlog", str(tlog),
                               "--duration", str(COMPANION_TIMEOUT_S - 20), "--json", *extra),
                player, signal_after_offboard)
            t_exit = player.now_s()
            time.sleep(HOLD_WATCH_S)
            result["px4_alive"] = sitl.alive()
        finally:
            stop.set()
            thread.join(timeout=5.0)
    (work / "companion.stderr").write_text(proc.stderr)
    result["companion_rc"] = proc.returncode
    report = json.loads(proc.stdout) if proc.stdout.strip().startswith("{") else {}
    result["companion_traceback"] = "Traceback" in proc.stderr
    result["companion_report"] = {k: report.get(k) for k in ("outcome", "exit_code", "stop_requested_by", "phase",
                                                             "goal_reached_companion_t_s", "replans",
                                                             "min_realised_contour", "replans_with_slack",
                                                             "failed_plans", "plan_status", "alerts",
                                                             "estimator_resets", "plans_before_reset",
                                                             "position_uncertain_events", "reported_position_sd_max_m",
                                                             "planner_process", "inbound_superseded", "setpoint_gap_max_ms", "setpoint_gap_max_detail",
                                                             "setpoint_gap_max_at_s", "tick_max_ms", "stream_cpu_share", "stream_fifo_priority",
                                                             "vehicle_clock", "tracking_error", "drift_max_mps")}
    result["world_errors"] = errors
    summary = player.summary()
    result["traffic_player"] = {k: summary[k] for k in ("engaged_at_s", "origin", "judged_on", "min_distance_m",
                                                        "min_clearance_m", "goal_reached", "sent")}
    # the player's clock (s since it started) throughout
    truth_t = np.array([t for t, _ in player.samples["truth"]])
    truth_p = np.array([p for _, p in player.samples["truth"]]).reshape(-1, 3)
    est_t = np.array([t for t, _, _ in player.samples["estimate"]])
    est_p = np.array([p for _, p, _ in player.samples["estimate"]]).reshape(-1, 3)
    offboard_t = player.engaged_t_s
    np.savez(work / "traces.npz", truth_t=truth_t, truth_p=truth_p, est_t=est_t, est_p=est_p,
             modes=np.array([t for t, _ in player.mode_changes], float),
             offboard_t=np.nan if offboard_t is None else offboard_t, exit_t=t_exit,
             est_stamp_s=np.array([stamp for _, _, stamp in player.samples["estimate"]]))
    if offboard_t is None or truth_t.size == 0:
        result["why"] = "never in OFFBOARD" if truth_t.size else "no ground truth received"
        return
    # takeoff: the height the vehicle holds after the takeoff, as SIH's truth has it: the mean
    # true height over the last TAKEOFF_WINDOW_S before OFFBOARD (the companion leaves PX4 in
    # Hold for [offboard] takeoff_settle_s after AUTO.TAKEOFF ends), and PX4's own estimate then,
    # above what it read on the ground (PX4's local z is 0 at its EKF origin, not at the ground:
    # it read -0.2 to +0.6 m on the ground in SIH). The player's truth is about the same origin,
    # so the true height is taken above the truth on the ground too.
    window = (truth_t >= offboard_t - TAKEOFF_WINDOW_S) & (truth_t <= offboard_t)
    lifted_mask = -(truth_p[:, 2] - truth_p[0, 2]) > 0.05
    ground_z = truth_p[0, 2]
    result["takeoff_height_m"] = round(float(-(truth_p[window, 2].mean() - ground_z)), 3) if window.any() else None
    lifted = truth_t[lifted_mask]
    ground = est_t < (lifted[0] - 0.5 if lifted.size else -np.inf)
    est_window = (est_t >= offboard_t - TAKEOFF_WINDOW_S) & (est_t <= offboard_t)
    result["takeoff_height_px4_estimate_m"] = round(float(-(est_p[est_window, 2].mean() - est_p[ground, 2].mean())), 3) \
        if est_window.any() and ground.any() else None
    # collisions in truth: the player's referee, every truth sample after OFFBOARD
    result["min_true_clearance_m"] = summary["referee"]["truth"]["min_clearance_m"]
    # the same split at the companion's exit: while it commanded, and after it handed back
    # (a vehicle holding in the obstacles' path is then up to the traffic)
    in_control, after = clearance_in_control_and_after(player, truth_t, truth_p, t_exit)
    result["min_true_clearance_in_control_m"] = in_control
    result["min_true_clearance_after_exit_m"] = after
    # goal: the companion's time of arrival after engaging, and the true distance to the goal then
    t_goal = report.get("goal_reached_companion_t_s")
    engaged = [t for t, text in report.get("events", []) if str(text).startswith("ENGAGED")]
    result["time_to_goal_s"] = None if t_goal is None or not engaged else float(t_goal - engaged[0])
    result["min_true_goal_distance_m"] = summary["referee"]["truth"]["min_goal_distance_m"]
    # the end: PX4 holds, no failsafe (the mode in force at the companion's exit and every change after)
    # PX4 sends its HEARTBEAT at 1 Hz on each link on its own schedule: the player's (ground) link
    # may show Hold up to a second after the companion's did, so the end is judged from then on
    settled = t_exit + HEARTBEAT_LAG_S
    before = [m for t, m in player.mode_changes if t <= settled]
    end_modes = before[-1:] + [m for t, m in player.mode_changes if t > settled]
    result["modes_after_exit"] = sorted(set(end_modes))
    texts = player.texts
    result["failsafe_texts"] = [(round(t - offboard_t, 2), text.strip()) for t, text in texts if "ailsafe" in text]
    result["failsafe_texts_at_end"] = [text.strip() for t, text in texts if "ailsafe" in text and t >= t_exit - 3.0]
    # the setpoint stream as recorded: PX4 flags offboard loss after COM_OF_LOSS_T (1 s) without one
    from companion.mavlink.tlog import read_tlog
    sp_t = np.array([t for t, m in read_tlog(tlog) if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"])
    result["setpoints"] = int(sp_t.size)
    result["largest_setpoint_gap_s"] = round(float(np.diff(sp_t).max()), 2) if sp_t.size > 1 else None
    result["px4_texts"] = [(round(t - offboard_t, 2), text.strip()) for t, text in texts]
    result["companion_exit_after_offboard_s"] = round(t_exit - offboard_t, 2)
    result["holds_after_exit"] = bool(end_modes) and all(m == HOLD for m in end_modes)
    # replay the recorded tlog
    rep = subprocess.run(companion_argv("replay", str(tlog), "--scenario", str(scenario), "--arm", "--takeoff-alt",
                                        str(TAKEOFF_ALT_M), "--exit-after-goal", "1", "--json", *extra),
                         capture_output=True, text=True, timeout=300, cwd=REPO)
    if rep.returncode == 0:
        s = json.loads(rep.stdout)
        result["replay"] = {k: s.get(k) for k in ("replans", "commands_compared", "commands_recorded",
                                                  "max_abs_diff_mps", "unmatched_commands", "tick_mismatches")}
    else:
        result["replay"] = {"error": rep.stderr.strip()[-500:]}


def clearance_in_control_and_after(player: TrafficPlayer, truth_t: np.ndarray, truth_p: np.ndarray,
                                   t_exit: float) -> tuple[float | None, float | None]:
    """The smallest true clearance (m, 3 decimals) to the player's obstacles from the vehicle's
    OFFBOARD until the companion exited at ``t_exit`` and after it (None: no sample then), from
    the truth samples ``truth_t`` (s, the player's clock) and ``truth_p`` (NED m)."""
    referee, t0 = player.referees["truth"], player.engaged_t_s
    radii = np.array(referee.radius_sum)
    split: dict[bool, float] = {}
    for t, p in zip(truth_t, truth_p):
        if t0 is None or t < t0:
            continue
        c = float(np.min(np.linalg.norm(referee.obstacle_positions(t - t0) - p, axis=1) - radii))
        split[t <= t_exit] = min(split.get(t <= t_exit, np.inf), c)
    return tuple(round(split[k], 3) if k in split else None for k in (True, False))


def judge_safety(r: dict, *, while_in_control: bool = False) -> list[str]:
    """The failed safety and hand-back checks of a run (empty when they held): no collision
    in SIH's truth (over the whole flight, or ``while_in_control``: until the companion
    exited), and Hold without a failsafe after the companion stops."""
    bad = []
    key = "min_true_clearance_in_control_m" if while_in_control else "min_true_clearance_m"
    if r.get(key) is None or r[key] <= 0.0:
        bad.append(f"collision in truth: {key} {r.get(key)} m")
    if not r.get("holds_after_exit") or r.get("failsafe_texts_at_end"):
        bad.append(f"end: modes {r.get('modes_after_exit')}, failsafe texts {r.get('failsafe_texts_at_end')}")
    return bad


def judge_replay(r: dict) -> list[str]:
    """The failed replay check of a run: ``companion replay`` must reproduce every command exactly."""
    rp = r.get("replay", {})
    if rp.get("max_abs_diff_mps") != 0.0 or rp.get("unmatched_commands") or \
            rp.get("commands_compared") != rp.get("commands_recorded"):
        return [f"replay {rp}"]
    return []


def judge_encounter(r: dict) -> list[str]:
    """The missed encounter targets of issue 13 (empty when met): the realised contour of touch
    never below the scenario's ``c_min``, and the goal within 25 s of OFFBOARD."""
    bad = []
    rc = r.get("companion_report", {})
    if rc.get("min_realised_contour") is None or rc["min_realised_contour"] < r.get("c_min", 0.90) - 1e-9:
        bad.append(f"realised contour {rc.get('min_realised_contour')} below c_min")
    if r.get("time_to_goal_s") is None or r["time_to_goal_s"] > 25.0:
        bad.append(f"time to goal {r.get('time_to_goal_s')} s after OFFBOARD")
    return bad


def judge_takeoff(r: dict) -> list[str]:
    """The missed takeoff target of issue 13 (empty when met): the requested altitude within
    0.3 m in SIH's truth. It measures PX4's height estimate as much as the companion (PX4
    holds its own estimate, which was up to 1.5 m off SIH's truth after the climb; docs/PX4.md)."""
    if r.get("takeoff_height_m") is None or abs(r["takeoff_height_m"] - TAKEOFF_ALT_M) > 0.3:
        return [f"takeoff height {r.get('takeoff_height_m')} m in truth "
                f"({r.get('takeoff_height_px4_estimate_m')} m in PX4's estimate), asked {TAKEOFF_ALT_M} m"]
    return []


def judge(r: dict) -> list[str]:
    """All failed checks of a run: safety and hand-back, replay, the encounter and the takeoff."""
    return judge_safety(r) + judge_replay(r) + judge_encounter(r) + judge_takeoff(r)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default=str(REPO / "configs" / "antipodal_px4.toml"))
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--work", default="/tmp/px4-flight")
    ap.add_argument("extra", nargs="*", help="extra companion arguments (after --)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO)
    return fly_runs(lambda i: fly_once(Path(args.work) / f"run{i}", Path(args.scenario), seed=i, extra=tuple(args.extra)),
                    judge, args.runs)


if __name__ == "__main__":
    sys.exit(main())
