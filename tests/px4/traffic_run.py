"""A companion run beside PX4 SITL and mavsim's traffic player: the part the mission flights share.

:mod:`tests.px4.guard_flight` (PX4's own mission through the antipodal traffic) and
:mod:`tests.px4.survey_flight` (the operator's survey) both play traffic that starts moving when
SIH's truth has the vehicle :data:`ENGAGE_HEIGHT_M` up, run ``companion fly`` as a subprocess
meanwhile, read PX4's words (modes, texts, failsafes) off the player, and offer the same
command line (``WORK_DIR [--runs N] [--json FILE]`` plus their own flags).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import threading
import time
from pathlib import Path
from typing import Callable

from mavsim.traffic import TrafficPlayer
from tests.px4.flight import companion_argv
from tests.px4.sitl import REPO

#: the traffic starts moving when the vehicle is this high above where it started (SIH's truth, m):
#: the take-off nearly done, the first leg about to begin
ENGAGE_HEIGHT_M = 4.3


def fly_beside_traffic(player: TrafficPlayer, fly_args: list[str], *, timeout_s: float, move_traffic: bool = True,
                       until_disarmed_s: float = 0.0) -> subprocess.CompletedProcess:
    """``companion fly *fly_args`` while ``player`` (already entered) plays; the finished process.

    The traffic is engaged once the vehicle is :data:`ENGAGE_HEIGHT_M` up (never without
    ``move_traffic``). After the companion exits, the player keeps listening up to
    ``until_disarmed_s`` for PX4's "Disarmed" (a landing handed to PX4 ends after the companion).
    The player stops within ``timeout_s + 60`` s whatever happens.
    """
    stop = threading.Event()

    def engage_when_up() -> None:
        while move_traffic and not stop.is_set():
            truth = player.samples["truth"]
            if truth and -(truth[-1][1][2] - truth[0][1][2]) > ENGAGE_HEIGHT_M:
                player.engage()
                return
            time.sleep(0.05)

    threads = [threading.Thread(target=lambda: player.run(timeout_s + 60.0, stop.is_set), daemon=True),
               threading.Thread(target=engage_when_up, daemon=True)]
    for t in threads:
        t.start()
    try:
        proc = subprocess.run(companion_argv("fly", *fly_args), capture_output=True, text=True, timeout=timeout_s,
                              cwd=REPO)
        deadline = time.monotonic() + until_disarmed_s
        while time.monotonic() < deadline and not any("Disarmed" in text for _, text in player.texts):
            time.sleep(0.2)
    finally:
        stop.set()
        for t in threads:
            t.join(timeout=5.0)
    return proc


def companion_report(proc: subprocess.CompletedProcess, work: Path, keys: tuple[str, ...]) -> dict:
    """The companion's exit, its ``--json`` report's ``keys`` and events; its stderr kept in ``work``."""
    (work / "companion.stderr").write_text(proc.stderr)
    report = json.loads(proc.stdout) if proc.stdout.strip().startswith("{") else {}
    return {"companion_rc": proc.returncode, "companion_traceback": "Traceback" in proc.stderr,
            "companion": {k: report.get(k) for k in keys}, "events": report.get("events")}


def px4_words(player: TrafficPlayer) -> dict:
    """What PX4 said on its ground link: its modes, its texts, the failsafe texts, and the closest
    true approach to the traffic (the player's referee, SIH's truth)."""
    summary = player.summary()
    return {"engaged_at_s": summary["engaged_at_s"], "min_true_clearance_m": summary["referee"]["truth"]["min_clearance_m"],
            "modes": [(round(t, 2), m) for t, m in player.mode_changes],
            "px4_texts": [(round(t, 2), text.strip()) for t, text in player.texts],
            "failsafe_texts": [text.strip() for _, text in player.texts if "ailsafe" in text]}


def runs_main(parser: argparse.ArgumentParser, fly_once: Callable[[Path, int, argparse.Namespace], dict],
              argv: list[str] | None = None) -> int:
    """``WORK_DIR [--runs N] [--json FILE]`` added to ``parser``; ``fly_once(WORK_DIR/runK, K, args)`` for
    each run; the results printed (and written to FILE) as JSON."""
    parser.add_argument("work", type=Path)
    parser.add_argument("--runs", type=int, default=1)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    results = [fly_once(args.work / f"run{k}", k, args) for k in range(args.runs)]
    text = json.dumps(results, indent=1, default=str)
    if args.json:
        args.json.write_text(text)
    print(text)
    return 0
