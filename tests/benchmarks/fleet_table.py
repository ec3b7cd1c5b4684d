"""The fleet table of docs/FLEET.md: the swap in lockstep, seed 0, per size and coordination mode.

    PYTHONPATH=$PWD python -m tests.benchmarks.fleet_table      # about 40 s

One row per (drones, mode): collision, all goals, the last goal's time, the smallest true
clearance between two drones, the smallest realised contour between a drone's estimate and
a peer's, and the slack replans of the whole fleet.
"""

from __future__ import annotations

from companion.offline.fleet_harness import run_fleet_lockstep
from companion.offline.swap import swap_scenarios

SIZES = ((2, False), (4, True), (8, True))
MODES = ("decentralised", "distributed", "prioritised")


def main() -> None:
    for n, traffic in SIZES:
        for mode in MODES:
            s = run_fleet_lockstep(swap_scenarios(n, traffic=traffic), seed=0, coordination=mode).summary()
            print(f"| {n} | {'two aircraft' if traffic else 'none'} | {mode} | {s['collided']} | {s['goal_reached']} | "
                  f"{s['time_to_all_goals_s']} | {s['min_pair_clearance_m']:.2f} | {s['min_peer_realised_contour']:.4f} | "
                  f"{sum(d['replans_with_slack'] for d in s['per_drone'])} |", flush=True)


if __name__ == "__main__":
    main()
