"""Record the planner's QPs of a representative set of flights (issue 40, the solver study).

    PYTHONPATH=$PWD python -m tests.benchmarks.qp_record OUT_DIR [--quick]

writes one ``.npz`` per set into ``OUT_DIR`` (format: :mod:`companion.core.planner.qp_record`):

- ``bench_scene{0..7}``: the planner benchmark's scenes (:mod:`tests.benchmarks.bench_planner`:
  N = 40, three obstacles, two walls, ``hyperplane``, 60 replans each, receding horizon);
- ``corridor_seed3``: ``configs/corridor.toml`` in lockstep, seed 3 (``c_max`` and its slack path);
- ``antipodal``: ``configs/antipodal.toml`` in lockstep (the default demo);
- ``antipodal_px4sim``: ``configs/antipodal_px4sim.toml`` in lockstep (the PX4 response model);
- ``mission_survey``: ``configs/mission_survey.toml`` in lockstep.

Every run is deterministic (lockstep, seeded), so the same command writes the same QPs.
``--quick`` records two benchmark scenes only (for a smoke test of the study).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from companion.core.planner.qp_record import QpRecorder, recording

ROOT = Path(__file__).resolve().parents[2]
#: (set name, scenario file, seed) flown in lockstep.
LOCKSTEP_SETS = (("corridor_seed3", "configs/corridor.toml", 3),
                 ("antipodal", "configs/antipodal.toml", 0),
                 ("antipodal_px4sim", "configs/antipodal_px4sim.toml", 0),
                 ("mission_survey", "configs/mission_survey.toml", 0))
BENCH_SCENES = 8


def record_bench(out: Path, scenes: range) -> list[Path]:
    from tests.benchmarks import bench_planner

    paths = []
    for index in scenes:
        name = f"bench_scene{index}"
        rec = QpRecorder(scene=name)
        with recording(rec):
            bench_planner.receding_horizon("hyperplane", bench_planner.scene(index))
        paths.append(rec.save(out / f"{name}.npz"))
        print(f"{name}: {len(rec)} QPs in {rec.replan} replans", flush=True)
    return paths


def record_lockstep(out: Path) -> list[Path]:
    from companion.offline.harness import run_lockstep

    paths = []
    for name, scenario, seed in LOCKSTEP_SETS:
        rec = QpRecorder(scene=name)
        with recording(rec):
            result = run_lockstep(ROOT / scenario, seed=seed)
        paths.append(rec.save(out / f"{name}.npz"))
        goal = result.summary().get("goal_reached")
        print(f"{name}: {len(rec)} QPs in {rec.replan} replans (goal reached: {goal})", flush=True)
    return paths


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", help="output directory (created)")
    ap.add_argument("--quick", action="store_true", help="two benchmark scenes only")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    if args.quick:
        record_bench(out, range(2))
    else:
        record_bench(out, range(BENCH_SCENES))
        record_lockstep(out)
    print(f"recorded in {time.perf_counter() - t0:.0f} s into {out}/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
