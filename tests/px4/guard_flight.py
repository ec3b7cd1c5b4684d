"""PX4 SITL flies its own mission through the antipodal traffic; the companion guards it (``--takeover guard|watch``).

Usage (measurements for the notes; not part of ``.ci/run``)::

    python -m tests.px4.guard_flight WORK_DIR [--takeover guard|watch] [--runs 5] [--json FILE]

Each run starts PX4 SIH in a fresh directory and mavsim's traffic player (the antipodal
obstacles on the companion's obstacle link, SIH's truth), then runs ``companion fly
--mission m.plan --takeover guard --arm`` (or ``watch``): the companion uploads the mission (a
take-off to 5 m, DO_CHANGE_SPEED 1.5 m/s, a waypoint 24 m north, a landing there), arms PX4,
starts the mission and guards it (takes over on a predicted conflict, gives back once clear)
or only watches it. The obstacles start moving when SIH's truth has the vehicle 4.3 m up (its
leg about to begin), so that they meet it mid-leg. Reported per run: the companion's exit and
report (conflicts announced, their lead, takeovers and their decision-to-OFFBOARD time, the
items PX4 reached, the smallest realised contour), the setpoints it sent (none when watching),
PX4's modes and failsafe texts, and the closest true approach (watching avoids nothing: the
vehicle flies through the virtual traffic). About 90 s a run.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from companion.mavlink.tlog import read_tlog
from mavsim.scenario import load_scenario
from mavsim.traffic import PlayerLinks, TrafficPlayer
from tests.px4.flight import OBSTACLE_PORT
from tests.px4.sitl import REPO, Sitl
from tests.px4.traffic_run import companion_report, fly_beside_traffic, px4_words, runs_main
from tests.support.missions import crossing_plan_text

SPEED_MPS = 1.5
COMPANION_TIMEOUT_S = 120.0


def _files(work: Path) -> tuple[Path, Path]:
    """The scenario (antipodal_px4 with the mission speed) and the mission plan, written into ``work``."""
    text = (REPO / "configs" / "antipodal_px4.toml").read_text()
    text = text.replace("[mission]\n", f"[mission]\nautopilot_speed_mps = {SPEED_MPS}\n", 1)
    scenario = work / "guard_px4.toml"
    scenario.write_text(text)
    path = work / "m.plan"
    path.write_text(crossing_plan_text([(24.0, 0.0, -5.0)], speed_mps=SPEED_MPS, final=21))
    return scenario, path


def guard_once(work: Path, seed: int = 0, takeover: str = "guard") -> dict:
    """One run (see the module docstring); its figures. Watching, PX4 flies the mission alone (the
    traffic cannot change its flight): the baseline of the mission's duration (``mission_s``)."""
    work.mkdir(parents=True, exist_ok=True)
    scenario, plan = _files(work)
    tlog = work / "flight.tlog"
    player = TrafficPlayer(load_scenario(scenario), PlayerLinks(obstacle_port=OBSTACLE_PORT), seed=seed,
                           start="manual", keep_samples=True)
    with player, Sitl(work / "sih"):
        proc = fly_beside_traffic(player, [
            "--connect", "udpin:127.0.0.1:14540", "--scenario", str(scenario), "--mission", str(plan),
            "--takeover", takeover, "--arm", "--obstacles", f"udpin:127.0.0.1:{OBSTACLE_PORT}",
            "--tlog", str(tlog), "--duration", str(COMPANION_TIMEOUT_S - 20), "--json"], timeout_s=COMPANION_TIMEOUT_S)
    result = {"work": str(work), **companion_report(proc, work, (
        "outcome", "phase", "watch_evaluations", "watch_min_predicted_contour", "watch_conflicts_count",
        "watch_conflicts", "autopilot_items_reached", "autopilot_items_reached_t_s", "replans", "takeovers_count",
        "takeovers", "min_realised_contour", "replans_with_slack", "failed_plans", "setpoint_gap_max_ms"))}
    sent = [m.get_type() for _, m in read_tlog(tlog) if m.get_srcComponent() == 191]
    result["setpoints_sent"] = sent.count("SET_POSITION_TARGET_LOCAL_NED")
    result.update(px4_words(player))
    # the mission's duration in PX4's words: from its first "Executing Mission" to "Mission finished, landed"
    started = [t for t, text in player.texts if "Executing Mission" in text]
    finished = [t for t, text in player.texts if "Mission finished" in text]
    result["mission_s"] = round(finished[0] - started[0], 2) if started and finished else None
    result["mode_switch_after_s"] = mode_switch_latency(work / "sih", tlog)
    return result


#: PX4's nav_state (vehicle_status) of the modes the companion requests, by (main, sub) mode:
#: OFFBOARD 14, AUTO.MISSION 3, AUTO.LOITER (Hold) 4
NAV_STATE = {(6, 0): 14, (4, 4): 3, (4, 3): 4}


def mode_switch_latency(sih_dir: Path, tlog: Path) -> list[tuple[int, float | None]] | None:
    """For each mode the companion requested (DO_SET_MODE, param2 and param3 the main and sub mode;
    reported by its main mode): how long after the
    request PX4 itself switched (s), from PX4's log (vehicle_status ``nav_state``) with PX4's boot
    clock mapped onto the tlog's by the least-delayed of PX4's stamped messages. None without a log
    (or without pyulog, the ``view`` extra)."""
    try:
        from pyulog import ULog
    except ImportError:
        return None
    logs = sorted(sih_dir.glob("**/*.ulg"))
    if not logs:
        return None
    status = ULog(str(logs[-1]), message_name_filter_list=["vehicle_status"]).get_dataset("vehicle_status").data
    changes = [(t * 1e-6, int(n)) for t, n, before in zip(status["timestamp"][1:], status["nav_state"][1:],
                                                           status["nav_state"][:-1]) if n != before]
    offsets, requests = [], []
    for t, m in read_tlog(tlog):
        if m.get_type() in ("ATTITUDE", "LOCAL_POSITION_NED") and m.get_srcComponent() == 1:
            offsets.append((t, t - m.time_boot_ms * 1e-3))
        elif m.get_type() == "COMMAND_LONG" and m.get_srcComponent() == 191 and m.command == 176:
            requests.append((t, (int(m.param2), int(m.param3))))
    if not offsets:
        return None
    out = []
    for t_req, mode in requests:
        main = mode[0]
        # unix = PX4 boot + offset, from the least-delayed message within 2 s of the request (SIH's
        # clock drifts from the wall clock by up to 1 % under load: one offset for the run is not enough)
        near = [o for t, o in offsets if abs(t - t_req) < 2.0]
        if not near:
            out.append((main, None))
            continue
        offset = min(near)
        after = [tb + offset - t_req for tb, n in changes if n == NAV_STATE.get(mode) and tb + offset > t_req - 0.05]
        out.append((main, round(float(after[0]), 3) if after else None))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--takeover", choices=("guard", "watch"), default="guard")
    return runs_main(p, lambda work, k, args: guard_once(work, seed=k, takeover=args.takeover), argv)


if __name__ == "__main__":
    sys.exit(main())
