"""The planner's vehicle models: velocity commands held for ``tau`` and the vehicle's response to them.

Two models, both keeping the QP linear with a fixed sparsity pattern (:mod:`qp_layout`'s
``dyn`` rows ``p_i - p_{i-1} - sum_k h_k V_{i-k} = f_i v_0``):

- :class:`LagModel`, a first-order lag ``T`` (below; ``T = 0`` is the paper's model);
  the variables ``V`` are the vehicle's velocities and the commands are derived.
- :class:`ResponseModel`, per axis an :class:`AxisResponse` (a PI velocity loop with an
  acceleration lag against linear drag: PX4's two-part response, identified from a log
  by ``companion identify``); the variables ``V`` are the commands, the positions the
  discretised response to them (``N (N + 1) / 2`` nonzeros per axis). The lag is its
  special case ``K_p = 1/T``.

The lag in detail:

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
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.linalg import expm

from companion.core import jit
from companion.errors import ConfigError


def _with_previous(v0: np.ndarray, velocities: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``V_1..V_N`` (N, 3) as floats and ``V_0..V_{N-1}`` (N, 3) beside them."""
    velocities = np.asarray(velocities, dtype=float)
    previous = np.empty(velocities.shape)
    previous[0] = v0
    previous[1:] = velocities[:-1]
    return velocities, previous


def _lag_signature(t):
    """``p_0`` or ``V_0`` (3,), ``V_1..V_N`` (N, 3), the model's coefficients; (N, 3) out."""
    r1, r2 = jit.readonly(t, 1), jit.readonly(t, 2)
    return t.void(r1, r1, r2, t.float64, t.float64, t.float64, t.boolean, r1, t.float64[:, ::1], t.float64[:, ::1])


@jit.lazy(_lag_signature)
def _lag_pass(p0, v0, velocities, b, c, alpha, clip, limit, positions, commands):
    """:meth:`LagModel.positions` and :meth:`LagModel.commands` (clipped to ``+-limit`` if ``clip``)
    in one loop, with numpy's operations in its order: the increment ``b V_i + c V_{i-1}``, the
    running sum from the first step (``cumsum``), then ``p_0 +``; the command
    ``(V_i - alpha V_{i-1}) / (1 - alpha)``; the clip as ``np.clip`` (NaN kept, else the bound
    when beyond it)."""
    keep = 1.0 - alpha
    for k in range(3):
        total = 0.0
        lo, hi = -limit[k], limit[k]
        for i in range(velocities.shape[0]):
            v, prev = velocities[i, k], v0[k] if i == 0 else velocities[i - 1, k]
            step = b * v + c * prev
            total = step if i == 0 else total + step
            positions[i, k] = p0[k] + total
            u = (v - alpha * prev) / keep
            if clip and u == u:
                u = u if u > lo else lo
                u = u if u < hi else hi
            commands[i, k] = u


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

    #: The ``accel`` rows bound ``V_i - V_{i-1}``: the vehicle's own acceleration for the lag.
    bounds_command_steps = True

    @property
    def instantaneous(self) -> bool:
        """Whether the velocity follows the command at once (``T = 0``, the paper's model)."""
        return self.time_constant_s <= 0.0

    def increment_coefficients(self, n_steps: int) -> np.ndarray:
        """``h_k`` (2, 3) of ``p_i - p_{i-1} = sum_k h_k V_{i-k}``: ``b`` on ``V_i``, ``c`` on ``V_{i-1}``, seconds."""
        return np.array([[self.b] * 3, [self.c] * 3])

    def free_increments(self, v0: np.ndarray, n_steps: int, internal: np.ndarray | None = None) -> np.ndarray:
        """Position increments (n_steps, 3) from ``v_0`` alone: ``c v_0`` in the first step, metres.

        ``internal`` must be ``None``: the lag's only state is its velocity."""
        _no_internal(internal)
        out = np.zeros((n_steps, 3))
        out[0] = self.c * np.asarray(v0, dtype=float)
        return out

    def positions(self, p0: np.ndarray, v0: np.ndarray, velocities: np.ndarray,
                  internal: np.ndarray | None = None) -> np.ndarray:
        """Positions ``p_1..p_N`` (N, 3) from ``p_0`` (3,), ``v_0`` (3,) and ``V_1..V_N`` (N, 3)
        (``internal`` must be ``None``)."""
        _no_internal(internal)
        if jit.available():
            return self._compiled(p0, v0, velocities, None)[0]
        velocities, previous = _with_previous(v0, velocities)
        return np.asarray(p0, dtype=float) + np.cumsum(self.b * velocities + self.c * previous, axis=0)

    def commands(self, v0: np.ndarray, velocities: np.ndarray, limit: np.ndarray | None = None) -> np.ndarray:
        """Velocity commands ``u_1..u_N`` (N, 3) that make the vehicle reach ``V_1..V_N``.

        ``limit`` (3,), m/s: the commands clipped to ``+-limit`` as ``np.clip`` clips them.
        """
        if jit.available():
            return self._compiled(np.zeros(3), v0, velocities, limit)[1]
        velocities, previous = _with_previous(v0, velocities)
        commands = (velocities - self.alpha * previous) / (1.0 - self.alpha)
        return commands if limit is None else np.clip(commands, -limit, limit)

    def _compiled(self, p0, v0, velocities, limit) -> tuple[np.ndarray, np.ndarray]:
        """:func:`_lag_pass`: positions and commands (N, 3)."""
        velocities = np.ascontiguousarray(velocities, dtype=float)
        positions, commands = np.empty(velocities.shape), np.empty(velocities.shape)
        _lag_pass()(np.ascontiguousarray(p0, dtype=float), np.ascontiguousarray(v0, dtype=float), velocities,
                    float(self.b), float(self.c), float(self.alpha), limit is not None,
                    np.ascontiguousarray(np.zeros(3) if limit is None else limit, dtype=float), positions, commands)
        return positions, commands

    def velocity_at(self, v0: np.ndarray, commands: np.ndarray, elapsed_s: float,
                    internal: np.ndarray | None = None) -> np.ndarray:
        """Vehicle velocity (3,) ``elapsed_s`` seconds after ``v0`` (3,) under ``commands`` (N, 3).

        Each command is held ``tau``; past the last step the last command is held
        (``internal`` must be ``None``).
        """
        _no_internal(internal)
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


@dataclass(frozen=True)
class AxisResponse:
    """Continuous-time velocity response of one axis to a velocity setpoint ``u`` (m/s).

    PX4's velocity loop is a PI controller on the velocity error whose acceleration
    setpoint the vehicle reaches after a short attitude lag, against linear drag::

        xi' = u - v                                  integral of the error, m
        a_sp = K_p (u - v) + K_i xi                  acceleration setpoint, m/s^2
        a'  = (a_sp - a) / T_a                        (a = a_sp when T_a = 0)
        v'  = a - k v                                 linear drag k, 1/s

    A first-order lag of time constant ``T`` is ``K_p = 1/T``, ``K_i = k = T_a = 0``.
    Attributes are ``p_gain_per_s`` (K_p, 1/s), ``i_gain_per_s2`` (K_i, 1/s^2),
    ``drag_per_s`` (k, 1/s) and ``accel_lag_s`` (T_a, s).
    """

    p_gain_per_s: float
    i_gain_per_s2: float = 0.0
    drag_per_s: float = 0.0
    accel_lag_s: float = 0.0

    FIELDS = ("p_gain_per_s", "i_gain_per_s2", "drag_per_s", "accel_lag_s")

    def __post_init__(self) -> None:
        for name in self.FIELDS:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
                raise ConfigError(f"{name} = {value!r} must be a finite number >= 0")
            object.__setattr__(self, name, float(value))
        if self.p_gain_per_s <= 0.0:
            raise ConfigError(f"p_gain_per_s = {self.p_gain_per_s!r} must be > 0")

    @classmethod
    def from_mapping(cls, table: Mapping[str, Any], where: str) -> AxisResponse:
        """From a TOML table with keys :attr:`FIELDS`; errors name ``where`` and the key."""
        if not isinstance(table, Mapping):
            raise ConfigError(f"{where} must be a table with keys {', '.join(cls.FIELDS)}, got {table!r}")
        unknown = sorted(set(table) - set(cls.FIELDS))
        if unknown:
            raise ConfigError(f"{where}: unknown key {unknown[0]!r}; expected {', '.join(cls.FIELDS)}")
        if "p_gain_per_s" not in table:
            raise ConfigError(f"{where}: p_gain_per_s is required")
        try:
            return cls(**dict(table))
        except ConfigError as exc:
            raise ConfigError(f"{where}.{exc}") from None

    def canonical(self) -> AxisResponse:
        """The same input-output response with the acceleration lag as the faster of its two poles.

        The velocity's transfer function ``(K_p s + K_i) / (T_a s^3 + (1 + T_a k) s^2 + (k + K_p) s + K_i)``
        is unchanged when ``1/T_a`` and ``k`` swap (with ``K_p``, ``K_i`` scaled by the ratio of
        the lags): a fit cannot tell them apart, physics can (the attitude settles faster than drag).
        """
        ta, k = self.accel_lag_s, self.drag_per_s
        if ta <= 0.0 or k <= 0.0 or 1.0 / ta >= k:
            return self
        ta_new = 1.0 / k
        scale = ta_new / ta
        return AxisResponse(self.p_gain_per_s * scale, self.i_gain_per_s2 * scale, 1.0 / ta, ta_new)

    def velocities(self, commands: np.ndarray, v0: float, dt: float) -> np.ndarray:
        """Velocity (M,) at the start of each of ``M`` steps of ``dt`` seconds under ``commands`` (M,), m/s,
        from the steady state at ``v0``."""
        ad, bd = discretise(*self.matrices(), dt)
        x = self.steady_state(float(v0))
        out = np.empty(len(commands))
        for i, u in enumerate(np.asarray(commands, dtype=float)):
            out[i] = x[1]
            x = ad @ x + bd * u
        return out

    def as_dict(self) -> dict[str, float]:
        return {name: getattr(self, name) for name in self.FIELDS}

    def matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """``(A, B)`` of ``x' = A x + B u`` with ``x = (p, v, xi[, a])`` (``a`` only when ``T_a > 0``)."""
        kp, ki, k, ta = self.p_gain_per_s, self.i_gain_per_s2, self.drag_per_s, self.accel_lag_s
        if ta > 0.0:
            a = np.array([[0, 1, 0, 0], [0, -k, 0, 1], [0, -1, 0, 0], [0, -kp / ta, ki / ta, -1 / ta]], dtype=float)
            b = np.array([0, 0, 1, kp / ta], dtype=float)
        else:
            a = np.array([[0, 1, 0], [0, -kp - k, ki], [0, -1, 0]], dtype=float)
            b = np.array([0, kp, 1], dtype=float)
        return a, b

    def steady_state(self, v: float) -> np.ndarray:
        """State holding velocity ``v`` under the command ``u = v`` (``xi`` carries the drag), position 0.

        Without an integrator (``K_i = 0``) ``xi`` stays 0 and the state is the one reached
        under the constant command that holds ``v``.
        """
        ki, k, ta = self.i_gain_per_s2, self.drag_per_s, self.accel_lag_s
        xi = k * v / ki if ki > 0.0 else 0.0
        x = [0.0, v, xi] + ([k * v] if ta > 0.0 else [])
        return np.asarray(x, dtype=float)


def discretise(a: np.ndarray, b: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold ``(Ad, Bd)`` of ``x' = A x + B u`` over ``dt`` seconds."""
    n = a.shape[0]
    m = np.zeros((n + 1, n + 1))
    m[:n, :n], m[:n, n] = a * dt, b * dt
    e = expm(m)
    return e[:n, :n], e[:n, n]


class ResponseModel:
    """The vehicle's velocity response per axis (north, east share ``horizontal``; down ``vertical``).

    The planner's variables ``V_i`` are the velocity *commands* held over step ``i`` (as in
    the paper's model); positions are a linear map of them. With the initial state the
    steady state at ``v_0`` (:meth:`AxisResponse.steady_state`), per axis::

        p_i - p_{i-1} = f_i v_0 + sum_{k=0}^{i-1} h_k V_{i-k}

    with the free response ``f`` and the increment response ``h`` of the discretised
    model (:meth:`increment_coefficients`, :meth:`free_increments`). The QP keeps this
    as ``N (N+1) / 2`` fixed nonzeros per axis in its ``dyn`` rows.

    Parameters
    ----------
    step_s : float
        ``tau``, seconds.
    horizontal, vertical : AxisResponse
    """

    alpha = 0.0          # no command rows: the variables are the commands (bounded by vbox)
    instantaneous = False
    #: The ``accel`` rows do not apply: the variables are commands, whose steps the autopilot
    #: smooths itself (the model's response is the vehicle's acceleration); bounding them at
    #: ``a_max tau`` made plans from speed overshoot the goal by 8 m in closed loop (measured).
    bounds_command_steps = False

    def __init__(self, step_s: float, horizontal: AxisResponse, vertical: AxisResponse) -> None:
        self.step_s = float(step_s)
        self.horizontal, self.vertical = horizontal, vertical
        self.axes = (horizontal, horizontal, vertical)
        self._continuous = [ax.matrices() for ax in self.axes]
        self._discrete = [discretise(a, b, self.step_s) for a, b in self._continuous]

    def _state0(self, v0: np.ndarray, internal: np.ndarray | None = None) -> list[np.ndarray]:
        """Per axis the start state ``(0, v, xi[, a])``: the steady state at ``v0`` (3,), or
        ``v0`` with the internal states ``internal`` (3, 2) (``xi`` m, ``a`` m/s^2 per axis;
        ``a`` unused on an axis without an acceleration lag)."""
        if internal is None:
            return [ax.steady_state(float(v)) for ax, v in zip(self.axes, np.asarray(v0, dtype=float))]
        internal = np.asarray(internal, dtype=float)
        return [np.array([0.0, float(v), float(xi), float(a)][:self._discrete[k][0].shape[0]])
                for k, (v, (xi, a)) in enumerate(zip(np.asarray(v0, dtype=float), internal))]

    def steady_internal(self, v: np.ndarray) -> np.ndarray:
        """The internal state (3, 2), ``(xi, a)`` per axis, that holds velocity ``v`` (3,) m/s against
        drag (:meth:`AxisResponse.steady_state`; ``a`` 0 without an acceleration lag). Linear in ``v``:
        added to another state, it shifts the velocity that state holds by ``v``."""
        out = np.zeros((3, 2))
        for k, (axis, vk) in enumerate(zip(self.axes, np.asarray(v, dtype=float))):
            x = axis.steady_state(float(vk))
            out[k, :x.size - 2] = x[2:]
        return out

    def increment_coefficients(self, n_steps: int) -> np.ndarray:
        """``h_k`` (n_steps, 3): position increment of step ``i`` per m/s of command ``V_{i-k}``, seconds."""
        out = np.zeros((n_steps, 3))
        for axis, (ad, bd) in enumerate(self._discrete):
            x = bd.copy()
            p_prev = 0.0
            for k in range(n_steps):
                out[k, axis] = x[0] - p_prev
                p_prev = x[0]
                x = ad @ x
        return out

    def free_increments(self, v0: np.ndarray, n_steps: int, internal: np.ndarray | None = None) -> np.ndarray:
        """``f_i v_0`` (n_steps, 3): position increments from the initial state under zero commands, metres
        (the initial state: :meth:`_state0`)."""
        out = np.zeros((n_steps, 3))
        for axis, ((ad, _), x) in enumerate(zip(self._discrete, self._state0(v0, internal))):
            for i in range(n_steps):
                x_next = ad @ x
                out[i, axis] = x_next[0] - x[0]
                x = x_next
        return out

    def simulate(self, v0: np.ndarray, commands: np.ndarray,
                 internal: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Position offsets and velocities (N, 3) at the step ends under ``commands`` (N, 3), from the
        steady state at ``v0`` or from ``v0`` and ``internal`` (:meth:`_state0`)."""
        commands = np.asarray(commands, dtype=float)
        pos, vel = np.zeros(commands.shape), np.zeros(commands.shape)
        for axis, ((ad, bd), x) in enumerate(zip(self._discrete, self._state0(v0, internal))):
            for i, u in enumerate(commands[:, axis]):
                x = ad @ x + bd * u
                pos[i, axis], vel[i, axis] = x[0], x[1]
        return pos, vel

    def positions(self, p0: np.ndarray, v0: np.ndarray, velocities: np.ndarray,
                  internal: np.ndarray | None = None) -> np.ndarray:
        """Positions ``p_1..p_N`` (N, 3) from ``p_0``, ``v_0`` (and ``internal``) and the commands ``V_1..V_N`` (N, 3)."""
        return np.asarray(p0, dtype=float) + self.simulate(v0, velocities, internal)[0]

    def commands(self, v0: np.ndarray, velocities: np.ndarray, limit: np.ndarray | None = None) -> np.ndarray:
        """The commands: the planner's variables themselves (N, 3), clipped to ``+-limit`` (3,) if given."""
        commands = np.asarray(velocities, dtype=float).copy()
        return commands if limit is None else np.clip(commands, -limit, limit)

    def velocity_at(self, v0: np.ndarray, commands: np.ndarray, elapsed_s: float,
                    internal: np.ndarray | None = None) -> np.ndarray:
        """Vehicle velocity (3,) ``elapsed_s`` seconds after the start state (:meth:`_state0` of
        ``v0`` and ``internal``) under ``commands``.

        Each command is held ``tau``; past the last step the last command is held.
        """
        commands = np.asarray(commands, dtype=float)
        remaining = max(0.0, float(elapsed_s))
        full = min(int(remaining // self.step_s), len(commands) - 1)
        out = np.zeros(3)
        for axis, ((ad, bd), (a, b), x) in enumerate(zip(self._discrete, self._continuous, self._state0(v0, internal))):
            for u in commands[:full, axis]:
                x = ad @ x + bd * u
            rest = remaining - full * self.step_s
            if rest > 0.0:
                ad_r, bd_r = discretise(a, b, rest)
                x = ad_r @ x + bd_r * commands[full, axis]
            out[axis] = x[1]
        return out


VehicleModel = LagModel | ResponseModel


def _no_internal(internal: np.ndarray | None) -> None:
    """The lag has no internal state: refuse one (a caller mixing up the models)."""
    if internal is not None:
        raise ValueError("the lag model has no internal state: internal must be None")


def model_from_config(step_s: float, time_constant_s: float,
                      response: tuple[AxisResponse, AxisResponse] | None = None) -> VehicleModel:
    """The planner's vehicle model: the (horizontal, vertical) ``response`` when given, else the lag ``T``."""
    if response is not None:
        return ResponseModel(step_s, *response)
    return LagModel.from_time_constant(step_s, time_constant_s)
