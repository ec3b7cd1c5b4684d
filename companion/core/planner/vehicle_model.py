"""The planner's vehicle model: velocity commands held for ``tau``, followed with a first-order lag.

The autopilot does not jump to a commanded velocity: PX4's velocity controller (and
mavsim's model of it) approaches the setpoint with roughly a first-order lag of time
constant ``T`` (seconds). With the command ``u_i`` held over step ``i`` and the vehicle
velocity ``v_{i-1}`` at its start, exactly::

    v_i = alpha v_{i-1} + (1 - alpha) u_i,                  alpha = exp(-tau / T)
    p_i = p_{i-1} + tau u_i + T (1 - alpha) (v_{i-1} - u_i)

The planner's velocity variables ``V_i`` are the vehicle's velocities ``v_i`` at the step
ends (so its speed, acceleration and jerk terms are about the vehicle), and the command
is derived from them: ``u_i = (V_i - alpha V_{i-1}) / (1 - alpha)``. Eliminating ``u``,
the position update stays linear in ``V``::

    p_i = p_{i-1} + b V_i + c V_{i-1},   b = (tau - T (1 - alpha)) / (1 - alpha),  c = tau - b

``T = 0`` is the paper's model (the velocity follows the command at once): ``alpha = 0``,
``b = tau``, ``c = 0``, ``u_i = V_i``. Units: seconds, metres, m/s, NED.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def _with_previous(v0: np.ndarray, velocities: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``V_1..V_N`` (N, 3) as floats and ``V_0..V_{N-1}`` (N, 3) beside them."""
    velocities = np.asarray(velocities, dtype=float)
    return velocities, np.vstack([np.asarray(v0, dtype=float)[None], velocities[:-1]])


@dataclass(frozen=True)
class LagModel:
    """Discretised first-order velocity lag for one step ``tau``.

    Attributes
    ----------
    alpha : velocity carried over one step, ``exp(-tau / T)`` (0 for ``T = 0``).
    b, c : position coefficients on ``V_i`` and ``V_{i-1}``, seconds (``b + c = tau``).
    step_s, time_constant_s : ``tau`` and ``T``, seconds.
    """

    alpha: float
    b: float
    c: float
    step_s: float
    time_constant_s: float

    @classmethod
    def from_time_constant(cls, step_s: float, time_constant_s: float) -> LagModel:
        """The model for step ``tau = step_s`` and lag ``T = time_constant_s`` (>= 0), seconds."""
        if time_constant_s <= 0.0:
            return cls(alpha=0.0, b=float(step_s), c=0.0, step_s=float(step_s), time_constant_s=0.0)
        alpha = math.exp(-step_s / time_constant_s)
        b = (step_s - time_constant_s * (1.0 - alpha)) / (1.0 - alpha)
        return cls(alpha=alpha, b=b, c=step_s - b, step_s=float(step_s), time_constant_s=float(time_constant_s))

    def positions(self, p0: np.ndarray, v0: np.ndarray, velocities: np.ndarray) -> np.ndarray:
        """Positions ``p_1..p_N`` (N, 3) from ``p_0`` (3,), ``v_0`` (3,) and ``V_1..V_N`` (N, 3)."""
        velocities, previous = _with_previous(v0, velocities)
        return np.asarray(p0, dtype=float) + np.cumsum(self.b * velocities + self.c * previous, axis=0)

    def commands(self, v0: np.ndarray, velocities: np.ndarray) -> np.ndarray:
        """Velocity commands ``u_1..u_N`` (N, 3) that make the vehicle reach ``V_1..V_N``."""
        velocities, previous = _with_previous(v0, velocities)
        return (velocities - self.alpha * previous) / (1.0 - self.alpha)

    def velocity_at(self, v0: np.ndarray, commands: np.ndarray, elapsed_s: float) -> np.ndarray:
        """Vehicle velocity (3,) ``elapsed_s`` seconds after ``v0`` (3,) under ``commands`` (N, 3).

        Each command is held ``tau``; past the last step the last command is held.
        """
        commands = np.asarray(commands, dtype=float)
        v = np.asarray(v0, dtype=float).copy()
        remaining = max(0.0, float(elapsed_s))
        for i, u in enumerate(commands):
            if remaining <= 0.0:
                break
            dt = remaining if i == len(commands) - 1 else min(remaining, self.step_s)
            carried = math.exp(-dt / self.time_constant_s) if self.time_constant_s > 0.0 else 0.0
            v = u + (v - u) * carried
            remaining -= dt
        return v
