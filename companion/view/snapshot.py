"""What the loop shows after one tick, copied out of the :class:`~companion.loop.app.Companion`.

:func:`take` runs on the loop's thread right after :meth:`Companion.tick` and only copies: the
drone's estimate (position, velocity, covariance), every track's estimate, the loop's mode,
the setpoint the tick sent (its outbox's last SET_POSITION_TARGET_LOCAL_NED) and the replans
recorded since the last snapshot, each with the drone's predicted covariance along its plan
(the horizon ellipsoids, the one computation here: a few 6x6 products per step, once per
replan). Everything after that (the Foxglove messages, the MCAP file, the WebSocket) works
on the copy, on another thread when live (:mod:`companion.view.publisher`).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from companion.loop.records import ReplanRecord

_SETPOINT = "SET_POSITION_TARGET_LOCAL_NED"
# type_mask bits of SET_POSITION_TARGET_LOCAL_NED: position x, y, z ignored
_IGNORE_POSITION = 0b111


@dataclass(frozen=True)
class Estimate:
    """One Gaussian position estimate, NED m and m^2 (velocity NED m/s when known)."""

    key: str
    position: np.ndarray
    cov: np.ndarray
    velocity: np.ndarray | None = None


@dataclass(frozen=True)
class Replan:
    """A replan recorded at this tick and its horizon: the drone's covariance at each plan step (N, 3, 3)."""

    record: ReplanRecord
    horizon_covs: np.ndarray | None
    step_s: float


@dataclass(frozen=True)
class TickSnapshot:
    """The loop after one tick (link time ``t_s``; vehicle time when the clock is known)."""

    t_s: float
    t_vehicle_s: float | None
    mode: str
    drone: Estimate | None
    tracks: tuple[Estimate, ...]
    setpoint: dict | None
    replans: tuple[Replan, ...]
    scenario: object = None     # the CompanionScenario (walls, static obstacles, goal): frozen, not copied


def _setpoint(outbox) -> dict | None:
    """The tick's setpoint (its last message when streaming), as plain numbers."""
    if not outbox or outbox[-1].get_type() != _SETPOINT:
        return None
    msg = outbox[-1]
    with_position = not (int(msg.type_mask) & _IGNORE_POSITION)
    return {"vx": float(msg.vx), "vy": float(msg.vy), "vz": float(msg.vz),
            "x": float(msg.x) if with_position else None, "y": float(msg.y) if with_position else None,
            "z": float(msg.z) if with_position else None}


class Snapshots:
    """Takes :class:`TickSnapshot` s of one companion; remembers which replans it has shown."""

    def __init__(self) -> None:
        self._records_seen = 0

    def take(self, companion, t_s: float, outbox) -> TickSnapshot:
        """The copy of ``companion`` after its tick at link time ``t_s`` that sent ``outbox``."""
        drone = None
        state = companion.drone.state
        if state is not None:
            drone = Estimate("drone", np.array(state.position), np.array(state.position_cov), np.array(state.velocity))
        tracker = companion.tracker
        tracks = []
        for key in tracker.keys():
            st = tracker.state(key)
            tracks.append(Estimate(_track_name(key), np.array(st.position), np.array(st.position_cov)))
        replans = []
        new = companion.tally.count - self._records_seen   # records may keep only the latest (a live flight)
        if new > 0:
            step_s = companion.planner_config.step_s
            records = companion.records
            for record in itertools.islice(records, max(0, len(records) - new), None):
                replans.append(Replan(record, _horizon(companion, record, step_s), step_s))
            self._records_seen = companion.tally.count
        return TickSnapshot(t_s=t_s, t_vehicle_s=companion.vehicle_time(t_s), mode=str(companion.state.mode.value),
                            drone=drone, tracks=tuple(tracks), setpoint=_setpoint(outbox), replans=tuple(replans),
                            scenario=companion.scenario)


def _track_name(key) -> str:
    """A track's key as a short id: ``(system, component)`` as ``"sys:comp"``, else its text."""
    if isinstance(key, tuple):
        return ":".join(str(k) for k in key)
    return str(key)


def _horizon(companion, record: ReplanRecord, step_s: float) -> np.ndarray | None:
    """The drone's predicted position covariance at each step of ``record``'s plan (None without an estimate)."""
    positions = np.asarray(record.plan_positions)
    if positions.ndim != 2 or positions.shape[0] == 0 or companion.drone.state is None or not math.isfinite(step_s):
        return None
    # the velocities only fix N (the covariance of a linear filter does not depend on them)
    return companion.drone.predict_position_covariances(record.t_vehicle_s, np.zeros_like(positions), step_s)
