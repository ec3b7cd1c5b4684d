"""Right of way between the drones of a fleet: keep right, and get out of a standoff.

Two drones that meet head-on and reason alike can both dodge to the same side, again and
again (the "reciprocal dance"), or stop nose to nose. Chance constraints keep them apart;
they do not say who goes which way. The fleet's tie-break is the rule of the road that
ships and aircraft use: **keep right**. When a peer is ahead, closing, and would pass
within ``reach_m`` of the drone on straight lines within the horizon, the drone's target
is moved ``reach_m`` to the right of its way (horizontally, perpendicular to the line to
the target). Every drone of the fleet does the same, so two that meet pass left side to
left side, and a circle of drones turns into a roundabout. Only peers (cooperative drones
that follow the same rule) count: traffic is avoided by the chance constraints alone.

Standoff. :class:`ProgressWatch` says when the drone has come no closer to its goal by
``progress_m`` in ``after_s`` seconds while a peer is near: a deadlock, counted. The
recovery is a wider move to the right (``recovery_offset`` times the reach) for
``recovery_s`` seconds.

Frames and units: NED metres, m/s, seconds. Pure.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

__all__ = ["right_of", "meets", "keep_right", "ProgressWatch", "RightOfWay"]


def right_of(heading: np.ndarray) -> np.ndarray:
    """The horizontal unit vector to the right of ``heading`` (NED; from above, north up, east right)."""
    h = np.array([heading[0], heading[1]], dtype=float)
    norm = math.hypot(h[0], h[1])
    if norm < 1e-9:
        return np.zeros(3)
    return np.array([-h[1] / norm, h[0] / norm, 0.0])


def meets(position: np.ndarray, velocity: np.ndarray, peer_position: np.ndarray, peer_velocity: np.ndarray,
          heading: np.ndarray, reach_m: float, horizon_s: float) -> bool:
    """Whether a peer is ahead of the drone (along ``heading``), closing, and on straight lines
    passes within ``reach_m`` of it (horizontally) within ``horizon_s``."""
    r = (np.asarray(peer_position, dtype=float) - position)[:2]
    if float(r @ np.asarray(heading, dtype=float)[:2]) <= 0.0:
        return False                                       # beside or behind
    w = (np.asarray(peer_velocity, dtype=float) - velocity)[:2]
    ww = float(w @ w)
    if float(np.hypot(*r)) <= reach_m:
        return True                                        # already within reach, ahead
    if ww < 1e-6 or float(r @ w) >= 0.0:
        return False                                       # not closing
    t_ca = -float(r @ w) / ww
    if t_ca > horizon_s:
        return False
    return float(np.hypot(*(r + w * t_ca))) < reach_m


def keep_right(position: np.ndarray, velocity: np.ndarray, target: np.ndarray, peers, horizon_s: float,
               offset_factor: float = 1.0) -> tuple[np.ndarray, int]:
    """The target moved to the right of the way when a peer is met, and how many peers were met.

    ``peers`` is an iterable of (position (3,), velocity (3,), reach m) NED: a peer is met when
    it passes within its reach (both bodies and both ``c_min`` reaches); the target moves
    right by ``offset_factor`` times the largest reach met.
    """
    position = np.asarray(position, dtype=float)
    velocity = np.asarray(velocity, dtype=float)
    target = np.asarray(target, dtype=float)
    way = target - position
    if math.hypot(way[0], way[1]) < 1e-3:
        return target, 0
    reaches = [r for p, v, r in peers if meets(position, velocity, p, v, way, r, horizon_s)]
    if not reaches:
        return target, 0
    return target + offset_factor * max(reaches) * right_of(way), len(reaches)


class RightOfWay:
    """The fleet's rules for one drone: keep right, and a wider move right out of a standoff.

    Parameters
    ----------
    horizon_s : how far ahead meetings count, s (the planner's horizon).
    after_s, progress_m, recovery_s, recovery_factor : :class:`ProgressWatch`'s settings and how
        many reaches right the target moves while recovering.
    near_factor : a peer within this many of its reaches is near (for the watch).
    """

    def __init__(self, horizon_s: float, *, after_s: float, progress_m: float, recovery_s: float,
                 recovery_factor: float = 2.0, near_factor: float = 3.0) -> None:
        self.horizon_s = float(horizon_s)
        self.watch = ProgressWatch(after_s, progress_m, recovery_s)
        self.recovery_factor = float(recovery_factor)
        self.near_factor = float(near_factor)
        #: replans whose target was moved right (met a peer), and of them while recovering
        self.kept_right = 0
        self.recovering = 0

    def target(self, t_v: float, position: np.ndarray, velocity: np.ndarray, target: np.ndarray,
               goal: np.ndarray | None, peers: list) -> np.ndarray:
        """The target for the replan at vehicle time ``t_v`` (see the module docstring)."""
        position = np.asarray(position, dtype=float)
        near = [r for p, _, r in peers if float(np.linalg.norm(np.asarray(p) - position)) <= self.near_factor * r]
        recovering = goal is not None and self.watch.update(t_v, float(np.linalg.norm(np.asarray(goal) - position)),
                                                            bool(near))
        factor = self.recovery_factor if recovering else 1.0
        moved, met = keep_right(position, velocity, target, peers, self.horizon_s, factor)
        if recovering:
            self.recovering += 1
            if not met and near:   # side by side, nobody closing: still out to the right
                moved = np.asarray(target, dtype=float) + factor * max(near) * right_of(np.asarray(target) - position)
        self.kept_right += int(bool(met))
        return moved

    def summary(self) -> dict:
        return {"kept_right": self.kept_right, "deadlocks": self.watch.deadlocks, "recovering": self.recovering,
                "deadlocks_t_s": [round(t, 2) for t in self.watch.detected_t_s]}


@dataclass
class _Sample:
    t_s: float
    distance_m: float


class ProgressWatch:
    """Deadlock detector: no progress toward the goal by ``progress_m`` over ``after_s`` with a peer near.

    Call :meth:`update` at each replan (vehicle time, distance to the goal, whether a peer is
    near); it returns True while a recovery runs (``recovery_s`` from the detection). Each
    detection is counted in :attr:`deadlocks`; the history is cleared after one, so the next
    needs another ``after_s`` without progress.
    """

    def __init__(self, after_s: float, progress_m: float, recovery_s: float) -> None:
        self.after_s, self.progress_m, self.recovery_s = float(after_s), float(progress_m), float(recovery_s)
        self._samples: deque[_Sample] = deque(maxlen=4096)
        self._recover_until = -math.inf
        self.deadlocks = 0
        #: vehicle times of the detections (the first 100)
        self.detected_t_s: list[float] = []

    def update(self, t_s: float, distance_m: float, peer_near: bool) -> bool:
        if t_s < self._recover_until:
            return True
        if not peer_near:
            self._samples.clear()
            return False
        self._samples.append(_Sample(float(t_s), float(distance_m)))
        while len(self._samples) > 1 and t_s - self._samples[1].t_s >= self.after_s:
            self._samples.popleft()
        first = self._samples[0]
        if t_s - first.t_s >= self.after_s and first.distance_m - distance_m < self.progress_m:
            self.deadlocks += 1
            if len(self.detected_t_s) < 100:
                self.detected_t_s.append(float(t_s))
            self._samples.clear()
            self._recover_until = t_s + self.recovery_s
            return True
        return False
