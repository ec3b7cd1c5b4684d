"""``make flake-check``: run CI's real-time and SITL stages (PX4, ArduCopter) N times and say which tests are steady.

Each round runs every stage the way ``.ci/run`` does (one pytest process a stage, the stages one
after another, nothing in parallel), with a JUnit XML report a stage. At the end one table: each
test, its runs and passes, the smallest true clearance over its flights (m), and for every
failure the flight's one line (tests/support/flight_summary.py) or the failure's first line. A
real-time or SITL test belongs in ``.ci/run`` only with N of N on a quiet machine; one that
cannot reach that is marked ``quarantine`` (out of CI, ``make quarantine-test``) until it can.

    python -m tests.support.flake_check --runs 20                 # CI's stages (make flake-check)
    python -m tests.support.flake_check --runs 20 --stage quarantine   # the tests kept out of CI
    python -m tests.support.flake_check --runs 20 --stage quarantine -k clean_stop   # some of them

A stage run's temporary files (``tmp_path``: the flights' tlogs, truth traces and reports) go
to ``OUT/roundNN-STAGE-tmp``; a round whose stage passed has them removed, a failed one keeps
them, so a rare failure can be replayed and read (``companion replay``).

Exit status: 0 when every test passed every run, 1 otherwise, 2 on bad arguments. Every stage run
is bounded in time (``--stage-timeout``); its process group is ended when the time runs out.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import statistics
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from tests.ardupilot.sitl import present as ardupilot_present
from tests.px4.sitl import sitl_dir

REPO = Path(__file__).resolve().parents[2]

#: The stages of ``.ci/run`` that fly in wall-clock time, as pytest arguments, and the quarantine.
STAGES: dict[str, list[str]] = {
    "default": ["-n", "2"],   # `make test`: the lockstep and loopback tests on two xdist workers
    "realtime": ["-m", "realtime and not quarantine"],
    "px4": ["-s", "-m", "px4 and not quarantine", "tests/px4"],
    "quarantine": ["-m", "quarantine"],
    "ardupilot": ["-s", "-m", "ardupilot and not quarantine", "tests/ardupilot"],
    "ardupilot_adsb": ["-s", "-m", "ardupilot_adsb and not quarantine", "tests/ardupilot"],   # the ADS-B encounter alone
    "mavproxy": ["-m", "mavproxy"],   # `make mavproxy-test`'s flights (MAVPROXY, or out/mavproxy-venv)
}


@dataclass
class TestRuns:
    """What one test did over the rounds: outcomes, durations (s), flight lines of its failures."""

    test: str
    passes: int = 0
    runs: int = 0
    seconds: list[float] = field(default_factory=list)
    clearances_m: list[float] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)


def read_junit(xml_text: str) -> list[dict]:
    """One dict a test case of a JUnit XML report: test id, outcome, seconds, flight line, clearance (m)."""
    cases = []
    for case in ET.fromstring(xml_text).iter("testcase"):
        test = f"{case.get('classname', '')}::{case.get('name', '')}"
        problem = next((child for child in case if child.tag in ("failure", "error")), None)
        skipped = next((child for child in case if child.tag == "skipped"), None)
        props = {p.get("name"): p.get("value") for p in case.iter("property")}
        clearance = props.get("true_clearance_m")
        cases.append({
            "test": test,
            "outcome": "failed" if problem is not None else "skipped" if skipped is not None else "passed",
            "seconds": float(case.get("time", 0.0)),
            "flight": props.get("flight"),
            "true_clearance_m": float(clearance) if clearance not in (None, "", "None") else None,
            "message": (problem.get("message") or problem.text or "").strip().splitlines()[0][:300]
            if problem is not None and (problem.get("message") or problem.text) else "",
        })
    return cases


def tally(rounds: list[list[dict]]) -> dict[str, TestRuns]:
    """Fold the rounds' test cases into one :class:`TestRuns` a test, in the order first seen."""
    table: dict[str, TestRuns] = {}
    for k, cases in enumerate(rounds, start=1):
        for case in cases:
            if case["outcome"] == "skipped":
                continue
            runs = table.setdefault(case["test"], TestRuns(case["test"]))
            runs.runs += 1
            runs.seconds.append(case["seconds"])
            if case["true_clearance_m"] is not None:
                runs.clearances_m.append(case["true_clearance_m"])
            if case["outcome"] == "passed":
                runs.passes += 1
            else:
                kept = f" | files kept in {case['kept']}" if case.get("kept") else ""
                runs.failures.append(f"round {k}: " + (case["flight"] or case["message"] or "failed (no message)") + kept)
    return table


def render(table: dict[str, TestRuns], rounds_asked: int) -> str:
    """The table: test, runs, passes, median seconds, smallest true clearance (m), then each failure."""
    lines = [f"{'passes':>7} {'runs':>5} {'median s':>9} {'min clear m':>12}  test"]
    for runs in table.values():
        clear = f"{min(runs.clearances_m):.3f}" if runs.clearances_m else "-"
        median = f"{statistics.median(runs.seconds):.1f}" if runs.seconds else "-"
        lines.append(f"{runs.passes:>7} {runs.runs:>5} {median:>9} {clear:>12}  {runs.test}")
        lines += [f"{'':>36}{failure}" for failure in runs.failures]
    steady = [r for r in table.values() if r.passes == r.runs == rounds_asked]
    lines.append(f"{len(steady)} of {len(table)} tests passed {rounds_asked} of {rounds_asked} rounds")
    return "\n".join(lines)


def stage_argv(stage: str, xml: Path, keyword: str | None = None, basetemp: Path | None = None) -> list[str]:
    """The pytest command of one stage run, its JUnit report to ``xml``, narrowed by ``-k keyword``,
    its temporary files under ``basetemp`` (default: pytest's own, of which it keeps three)."""
    narrow = ["-k", keyword] if keyword else []
    temp = [f"--basetemp={basetemp}"] if basetemp is not None else []
    return [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", f"--junitxml={xml}", *temp,
            *STAGES[stage], *narrow]


def _run_stage(argv: list[str], timeout_s: float, env: dict) -> int:
    proc = subprocess.Popen(argv, cwd=REPO, env=env, start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        return proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        return -1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="flake_check", description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=20, help="rounds (default 20)")
    parser.add_argument("--stage", action="append", choices=sorted(STAGES),
                        help="a stage to run (repeatable; default: realtime, then px4 and ardupilot when their SITL "
                             "builds are present, as .ci/run)")
    parser.add_argument("--stage-timeout", type=float, default=1800.0, help="seconds one stage run may take (default 1800)")
    parser.add_argument("-k", dest="keyword", metavar="EXPR",
                        help="only the stage's tests pytest's -k EXPR selects (to prove some tests of a stage)")
    parser.add_argument("--out", type=Path, default=REPO / "out" / "flake-check", help="where the reports go")
    args = parser.parse_args(argv)
    if args.runs < 1:
        parser.error("--runs must be at least 1")
    env = dict(os.environ)
    stages = args.stage or (["realtime"] + (["px4"] if sitl_dir() is not None else [])
                            + (["ardupilot"] if ardupilot_present() else []))
    args.out.mkdir(parents=True, exist_ok=True)
    rounds: list[list[dict]] = []
    for k in range(1, args.runs + 1):
        cases: list[dict] = []
        for stage in stages:
            xml = args.out / f"round{k:02d}-{stage}.xml"
            xml.unlink(missing_ok=True)
            temp = args.out / f"round{k:02d}-{stage}-tmp"
            shutil.rmtree(temp, ignore_errors=True)
            t0 = time.monotonic()
            rc = _run_stage(stage_argv(stage, xml, args.keyword, temp), args.stage_timeout, env)
            got = read_junit(xml.read_text()) if xml.exists() else []
            if rc == -1 or not got:
                got.append({"test": f"<stage {stage}>", "outcome": "failed", "seconds": time.monotonic() - t0,
                            "flight": None, "true_clearance_m": None,
                            "message": "timed out" if rc == -1 else f"pytest exit {rc}, no report"})
            cases += got
            failed = sum(c["outcome"] == "failed" for c in got)
            if failed:
                for case in got:
                    if case["outcome"] == "failed":
                        case["kept"] = str(temp)
            else:
                shutil.rmtree(temp, ignore_errors=True)
            print(f"round {k}/{args.runs} {stage}: {len(got) - failed} passed, {failed} failed, "
                  f"{time.monotonic() - t0:.0f} s", flush=True)
        rounds.append(cases)
    table = tally(rounds)
    text = render(table, args.runs)
    print(text)
    (args.out / "table.txt").write_text(text + "\n")
    (args.out / "rounds.json").write_text(json.dumps(rounds, indent=1))
    return 0 if all(r.passes == r.runs == args.runs for r in table.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
