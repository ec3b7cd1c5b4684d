"""Core-seconds per antipodal campaign episode: the figure that decides how many episodes a campaign affords.

Runs ``EPISODES`` episodes of the antipodal family (campaign seed 1, method ``hyperplane``)
one after the other in this process, as one campaign worker does (simulator, estimator,
planner, MAVLink encode and decode, scoring), and reads the process's CPU time
(``time.process_time``: every thread of the process, i.e. core-seconds) around each.
The planner's own share (the plans' ``solve_time_s`` summed, wall clock) is the peer
measured in the same run.
"""

from __future__ import annotations

import time

import numpy as np

from companion.offline.campaign.run import EpisodeTask, run_episode

EPISODES = 4
SEED = 1
#: A third of the 3.8 core-seconds per episode measured before the performance work (under load).
TARGET_CORE_S = 3.8 / 3.0


def run() -> list[dict]:
    core_s, wall_s, planner_s, replans = [], [], [], []
    for index in range(EPISODES):
        task = EpisodeTask(family="antipodal", seed=SEED, index=index, method="hyperplane")
        c0, w0 = time.process_time(), time.perf_counter()
        result = run_episode(task)
        core_s.append(time.process_time() - c0)
        wall_s.append(time.perf_counter() - w0)
        if result.error:
            raise RuntimeError(f"episode {index} failed: {result.error}")
        planner_s.append(float(np.sum(result.score.solve_times_s)))
        replans.append(len(result.score.solve_times_s))
    mean_core = float(np.mean(core_s))
    share = float(np.sum(planner_s) / np.sum(wall_s))
    return [
        {"name": "core-seconds per antipodal campaign episode (hyperplane)", "value": mean_core, "unit": "core-s",
         "target": f"<= {TARGET_CORE_S:.2f}", "peer": f"planner {np.mean(planner_s):.2f} s", "ratio": share,
         "note": f"mean of {EPISODES} episodes (seed {SEED}) on one worker; max {max(core_s):.2f}; "
                 f"{np.mean(replans):.0f} replans per episode; ratio = planner share of the wall time"},
    ]
