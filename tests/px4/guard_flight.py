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
import json
import subprocess
import sys
import threading
import time
from pathlib import Path

from mavsim.scenario import load_scenario
from mavsim.traffic import PlayerLinks, TrafficPlayer
from tests.px4.flight import OBSTACLE_PORT, companion_argv
from tests.px4.sitl import REPO, Sitl
from tests.support.missions import crossing_plan_text

SPEED_MPS = 1.5
ENGAGE_HEIGHT_M = 4.3
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
    """One run (see the module docstring); its figures."""
    work.mkdir(parents=True, exist_ok=True)
    scenario, plan = _files(work)
    tlog = work / "flight.tlog"
    player = TrafficPlayer(load_scenario(scenario), PlayerLinks(obstacle_port=OBSTACLE_PORT), seed=seed,
                           start="manual", keep_samples=True)
    stop = threading.Event()

    def play() -> None:
        player.run(COMPANION_TIMEOUT_S + 60.0, stop.is_set)

    def engage_when_up() -> None:
        while not stop.is_set():
            truth = player.samples["truth"]
            if truth and -(truth[-1][1][2] - truth[0][1][2]) > ENGAGE_HEIGHT_M:
                player.engage()
                return
            time.sleep(0.05)

    result: dict = {"work": str(work)}
    with player, Sitl(work / "sih"):
        threads = [threading.Thread(target=play, daemon=True), threading.Thread(target=engage_when_up, daemon=True)]
        for t in threads:
            t.start()
        try:
            proc = subprocess.run(companion_argv(
                "fly", "--connect", "udpin:127.0.0.1:14540", "--scenario", str(scenario), "--mission", str(plan),
                "--takeover", takeover, "--arm", "--obstacles", f"udpin:127.0.0.1:{OBSTACLE_PORT}",
                "--tlog", str(tlog), "--duration", str(COMPANION_TIMEOUT_S - 20), "--json"),
                capture_output=True, text=True, timeout=COMPANION_TIMEOUT_S, cwd=REPO)
        finally:
            stop.set()
            for t in threads:
                t.join(timeout=5.0)
    (work / "companion.stderr").write_text(proc.stderr)
    report = json.loads(proc.stdout) if proc.stdout.strip().startswith("{") else {}
    result["companion_rc"] = proc.returncode
    result["companion"] = {k: report.get(k) for k in (
        "outcome", "phase", "watch_evaluations", "watch_min_predicted_contour", "watch_conflicts_count",
        "watch_conflicts", "autopilot_items_reached", "autopilot_items_reached_t_s", "replans", "takeovers_count",
        "takeovers", "min_realised_contour", "replans_with_slack", "failed_plans", "setpoint_gap_max_ms")}
    result["events"] = report.get("events")
    from companion.mavlink.tlog import read_tlog
    sent = [m.get_type() for _, m in read_tlog(tlog) if m.get_srcComponent() == 191]
    result["setpoints_sent"] = sent.count("SET_POSITION_TARGET_LOCAL_NED")
    summary = player.summary()
    result["engaged_at_s"] = summary["engaged_at_s"]
    result["min_true_clearance_m"] = summary["referee"]["truth"]["min_clearance_m"]
    result["modes"] = [(round(t, 2), m) for t, m in player.mode_changes]
    result["px4_texts"] = [(round(t, 2), text.strip()) for t, text in player.texts]
    result["failsafe_texts"] = [text.strip() for _, text in player.texts if "ailsafe" in text]
    return result


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("work", type=Path)
    p.add_argument("--runs", type=int, default=1)
    p.add_argument("--takeover", choices=("guard", "watch"), default="guard")
    p.add_argument("--json", type=Path, default=None)
    args = p.parse_args(argv)
    results = [guard_once(args.work / f"run{k}", seed=k, takeover=args.takeover) for k in range(args.runs)]
    text = json.dumps(results, indent=1, default=str)
    if args.json:
        args.json.write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
