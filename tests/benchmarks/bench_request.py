"""The stream's share of a replan: building its request with a crowd of tracks.

In real time the setpoint stream builds each replan's request in its tick
(``RequestBuilder.build``: every track's estimate read, the tracks beyond the walls set
apart, the rest ranked by risk when more than ``max_constrained_tracks``, the chosen ones
predicted over the horizon, every track's estimate now and its realised contour of
touch), so this is the longest part of the longest tick. Rows: the median and the
largest build with 200 stationary tracks beside the route plus one leader, in the
corridor (the crowd beyond its walls) and in antipodal (no walls: ranked, 8
constrained), each against the same build with the leader alone (peer, same run).
"""

from __future__ import annotations

import time

import numpy as np

from companion.loop.config import load_scenario
from companion.loop.perception import Perception
from companion.loop.request_builder import RequestBuilder

CROWD = 200
BUILDS = 60
WARM_UP = 10       # builds not timed


def _perception(scene: str, crowd: int) -> tuple[object, Perception]:
    """The scene's perception with the drone at rest at (0, 0, -5) m NED, a leader 3 m ahead at 1 m/s,
    and ``crowd`` stationary tracks 6-10 m beside the route (seeded), all estimated at 0 s."""
    scenario = load_scenario(f"configs/{scene}.toml")
    perception = Perception(scenario)
    perception.drone.update(0.0, np.array([0.0, 0.0, -5.0]), np.zeros(3), np.full(3, 0.01), np.full(3, 0.01))
    rng = np.random.default_rng(5)
    side = rng.choice([-1.0, 1.0], crowd) * rng.uniform(6.0, 10.0, crowd)
    positions = np.column_stack([rng.uniform(-5.0, 30.0, crowd), side, np.full(crowd, -5.0)])
    for k, p in enumerate(positions):
        perception.tracker.update((30 + k, 198, "obstacles1"), 0.0, p, np.zeros(3), 0.04 * np.eye(3), 0.01 * np.eye(3))
    perception.tracker.update((2, 1, "obstacles1"), 0.0, np.array([3.0, 0.0, -5.0]), np.array([1.0, 0.0, 0.0]),
                              0.02 * np.eye(3), 0.01 * np.eye(3))
    return scenario, perception


def build_times_ms(scene: str, crowd: int) -> tuple[np.ndarray, object]:
    """Wall times (ms) of :data:`BUILDS` - :data:`WARM_UP` builds 0.1 s after the estimates, and the last job."""
    scenario, perception = _perception(scene, crowd)
    builder = RequestBuilder(scenario)
    times, job = [], None
    for seq in range(BUILDS):
        t0 = time.perf_counter()
        job = builder.build(seq=seq, t_s=0.1, t_v=0.1, perception=perception, initial_velocity=np.zeros(3),
                            warm_start=None)
        times.append(time.perf_counter() - t0)
    return 1e3 * np.array(times[WARM_UP:]), job


def run() -> list[dict]:
    rows = []
    for scene in ("corridor", "antipodal"):
        crowd, job = build_times_ms(scene, CROWD)
        alone, _ = build_times_ms(scene, 0)
        median, peer = float(np.median(crowd)), float(np.median(alone))
        rows.append({
            "name": f"request build, {CROWD + 1} tracks, {scene} (median)", "value": median, "unit": "ms",
            "peer": f"1 track {peer:.2f} ms", "ratio": median / peer,
            "note": f"largest {crowd.max():.2f} ms; {len(job.tracks_constrained)} constrained, "
                    f"{len(job.tracks_unconstrained)} left out, {len(job.tracks_beyond_walls)} beyond the walls",
        })
    return rows
