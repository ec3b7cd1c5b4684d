"""The fault campaign: every lockstep fault of docs/FAULTS.md, flown on many seeds, judged in truth.

Each fault is flown on ``configs/antipodal.toml`` in lockstep with mavsim (PX4 personality), one
run per seed; the seed sets mavsim's noise and the fault's start, drawn uniformly in 7 to 10 s
(the encounter is at 8 s). Counted per run, from mavsim's truth and the vehicle's side of the
link (:mod:`tests.support.lockstep_faults`):

- ``collided``: a collision in truth; ``collided_in_control``: one that began while the vehicle
  was still in OFFBOARD (the companion commanding), not after a failsafe or an operator took it;
- ``setpoints_after_left``: setpoints the vehicle received after it left OFFBOARD on its own
  (a failsafe or an operator), and ``setpoints_after_seen``: those after the first HEARTBEAT
  showing it got through (the companion's only evidence of the mode);
- ``mode_requests_after_left``: requests for a mode after it left OFFBOARD (taking it back);
- ``stale_frame_ticks``: ticks flying a plan built from an estimate older than the autopilot's
  last estimator reset;
- ``outcome``: ``companion fly``'s outcome for the run, against the one docs/FAULTS.md defines.

A case flown with ``--reengage`` (the operator's opt-in to take the vehicle back after a
failsafe) asks for OFFBOARD again and streams after it saw the failsafe, by design: its
setpoints and mode requests after the vehicle left are counted, not held to zero.

Run: ``python -m tests.support.fault_campaign --runs 20 [--json out.json]`` (about 3 minutes on
one core); ``tests/loop/test_fault_campaign.py`` (marker ``faults``, ``make fault-campaign``)
runs it and asserts the zeros. The restart row is real time only (tests/realtime/test_restart.py).
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
import time
import tomllib
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from companion.mavlink.offboard import OffboardConfig
from companion.offline.harness import run_lockstep
from companion.realtime.run_end import RunEnd
from tests.support.lockstep_faults import Cut, PlanOrigins, VehicleSide, gcs_mode_switch, left_offboard_t

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "configs" / "antipodal.toml"
DURATION_S = 30.0


@dataclass(frozen=True)
class FaultCase:
    """One fault: its cuts, injections and scenario changes for a start time ``t0`` (s), the
    outcomes docs/FAULTS.md allows for it, and whether the companion flies with ``--reengage``."""

    name: str
    build: Callable[[float], dict]
    outcomes: tuple[str, ...]
    reengage: bool = False


def _cut(start: float, length: float, what: str = "autopilot", sysid: int | None = None) -> dict:
    return {"cuts": [Cut(start, start + length, what, sysid)]}


FAULTS: tuple[FaultCase, ...] = (
    FaultCase("autopilot link 0.5 s", lambda t0: _cut(t0, 0.5), ("goal reached",)),
    FaultCase("autopilot link 2 s", lambda t0: _cut(t0, 2.0), ("autopilot failsafe",)),
    FaultCase("autopilot link 10 s", lambda t0: _cut(t0, 10.0), ("autopilot failsafe",)),
    FaultCase("uplink only 2 s", lambda t0: _cut(t0, 2.0, "autopilot_up"), ("autopilot failsafe",)),
    FaultCase("operator mode switch", lambda t0: {"inject_vehicle": gcs_mode_switch(t0, 3, 0)}, ("pilot took over",)),
    FaultCase("obstacle link 4 s", lambda t0: _cut(t0, 4.0, "obstacles"), ("goal reached",)),
    FaultCase("obstacle source dies", lambda t0: _cut(t0 - 2.0, 1e9, "obstacles", 102), ("goal reached",)),
    FaultCase("estimator reset and back", lambda t0: {"resets": [[t0, 1.5, 1.0, 0.0], [t0 + 4.0, -1.5, -1.0, 0.0]]},
              ("goal reached",)),
    # 4 s of dead reckoning ending at t0 + 2 s, through the encounter (under PX4's 5 s EKF2_NOAID_TOUT)
    FaultCase("GPS outage 4 s", lambda t0: {"sim": {"gps_outages": [[t0 - 2.0, 4.0]]}}, ("goal reached",)),
    # a noisy GPS still fused, 6 s from t0 - 2 s: 1 m more per horizontal axis, honestly reported
    FaultCase("GPS degraded 1 m 6 s", lambda t0: {"sim": {"gps_degradations": [[t0 - 2.0, 6.0, 1.0]]}},
              ("goal reached",)),
    # 8 s from t0 - 2 s: 5 s in, PX4 declares its position invalid and fails safe to ALTCTL
    FaultCase("GPS outage 8 s", lambda t0: {"sim": {"gps_outages": [[t0 - 2.0, 8.0]]}}, ("autopilot failsafe",)),
    # the same with --reengage: the vehicle taken back once PX4's position is valid again (its
    # return), unless PX4's blind land has put it down by then (not flown off again)
    FaultCase("GPS outage 8 s, --reengage", lambda t0: {"sim": {"gps_outages": [[t0 - 2.0, 8.0]]}},
              ("goal reached", "autopilot failsafe"), reengage=True),
)


@dataclass
class RunRow:
    fault: str
    seed: int
    t0_s: float
    outcome: str
    outcome_ok: bool
    collided: bool
    collided_in_control: bool
    min_true_clearance_m: float
    setpoints_after_left: int
    setpoints_after_seen: int
    mode_requests_after_left: int
    stale_frame_ticks: int
    wall_s: float


def _scenario(resets: list | None, sim: dict | None = None) -> dict:
    """The antipodal scenario's tables with the case's estimator resets and ``[sim]`` changes."""
    with open(SCENARIO, "rb") as f:
        data = tomllib.load(f)
    if resets or sim:
        data = copy.deepcopy(data)
        data["sim"].update(sim or {})
        if resets:
            data["sim"]["estimator_resets"] = resets
    return data


def fly_one(case: FaultCase, seed: int) -> RunRow:
    """Fly ``case`` on ``seed`` and judge it."""
    t0 = round(float(np.random.default_rng([seed, 38]).uniform(7.0, 10.0)), 2)
    spec = case.build(t0)
    side = VehicleSide(list(spec.get("cuts", [])))
    origins = PlanOrigins()
    started = time.perf_counter()
    result = run_lockstep(_scenario(spec.get("resets"), spec.get("sim")), seed=seed, drop=side, duration_s=DURATION_S,
                          after_tick=origins, inject_vehicle=spec.get("inject_vehicle"),
                          offboard=OffboardConfig(reengage=True) if case.reengage else None)
    wall = time.perf_counter() - started
    s = result.summary()
    left = left_offboard_t(result.truth)
    outcome = RunEnd().outcome(result.companion).text
    return RunRow(
        fault=case.name, seed=seed, t0_s=t0, outcome=outcome, outcome_ok=outcome in case.outcomes,
        collided=bool(s["collided"]),
        collided_in_control=any(left is None or c["t_start_s"] < left for c in result.truth["collisions"]),
        min_true_clearance_m=round(float(s["min_true_clearance_m"]), 3),
        setpoints_after_left=side.setpoints_after(left),
        setpoints_after_seen=side.setpoints_after(side.left_offboard_seen_t),
        mode_requests_after_left=side.mode_requests_after(left),
        stale_frame_ticks=len(origins.stale_frame_ticks), wall_s=round(wall, 2))


def summarise(rows: list[RunRow]) -> list[dict]:
    """One line per fault: runs, and the counts docs/FAULTS.md reports."""
    out = []
    for case in FAULTS:
        mine = [r for r in rows if r.fault == case.name]
        if not mine:
            continue
        out.append({
            "fault": case.name, "runs": len(mine),
            "collisions": sum(r.collided for r in mine),
            "collisions_in_control": sum(r.collided_in_control for r in mine),
            "min_true_clearance_m": min(r.min_true_clearance_m for r in mine),
            "outcome_as_documented": sum(r.outcome_ok for r in mine),
            "runs_with_setpoints_after_left": sum(r.setpoints_after_left > 0 for r in mine),
            "setpoints_after_left_max": max(r.setpoints_after_left for r in mine),
            "setpoints_after_seen": sum(r.setpoints_after_seen for r in mine),
            "mode_requests_after_left": sum(r.mode_requests_after_left for r in mine),
            "stale_frame_ticks": sum(r.stale_frame_ticks for r in mine),
            "wall_s": round(sum(r.wall_s for r in mine), 1),
        })
    return out


def run_campaign(runs: int, faults: tuple[FaultCase, ...] = FAULTS, first_seed: int = 0) -> list[RunRow]:
    return [fly_one(case, seed) for case in faults for seed in range(first_seed, first_seed + runs)]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tests.support.fault_campaign", description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=20, help="seeded runs per fault (default 20)")
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument("--json", type=Path, default=None, help="write every run and the summary here")
    p.add_argument("--fault", action="append", choices=[case.name for case in FAULTS], default=None,
                   help="fly only this fault (repeatable; default every one)")
    args = p.parse_args(argv)
    import logging
    logging.disable(logging.WARNING)   # each run's collisions and transitions are in the rows
    faults = FAULTS if not args.fault else tuple(case for case in FAULTS if case.name in args.fault)
    rows = run_campaign(args.runs, faults=faults, first_seed=args.first_seed)
    table = summarise(rows)
    cols = ["fault", "runs", "collisions", "collisions_in_control", "min_true_clearance_m", "outcome_as_documented",
            "runs_with_setpoints_after_left", "setpoints_after_left_max", "setpoints_after_seen",
            "mode_requests_after_left", "stale_frame_ticks", "wall_s"]
    print(" | ".join(cols))
    for line in table:
        print(" | ".join(str(line[c]) for c in cols))
    if args.json is not None:
        args.json.write_text(json.dumps({"summary": table, "runs": [asdict(r) for r in rows]}, indent=1))
    retakes = {case.name for case in FAULTS if case.reengage}
    bad = [r for r in rows if r.collided_in_control or not r.outcome_ok or r.stale_frame_ticks
           or (r.fault not in retakes and (r.setpoints_after_seen or r.mode_requests_after_left))]
    for r in bad:
        print("FAILED", asdict(r), file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
