"""The vehicle response's internal state, observed from the velocity estimate and the setpoints sent.

The planner's response model (:class:`~companion.core.planner.vehicle_model.AxisResponse`)
has, per axis, states besides the velocity: the velocity loop's error integral ``xi`` (m)
and, with an acceleration lag, the acceleration ``a`` (m/s^2). A plan started from their
steady state at the current velocity assumes the loop has settled at that speed. After a
cruise it has not: PX4's velocity integral keeps pushing along the cruise for seconds after
the vehicle has stopped, and the vehicle overshoots and comes back slowly (measured on PX4
SITL, docs/PX4.md, "The response's internal state").

:class:`ResponseObserver` runs a Kalman filter on the model itself, per NED axis, over the
state ``(v, xi[, a])``: between velocity reports the model predicts under the setpoints in
force (each held from its time until the next), each report corrects, and white noise of
spectral density :data:`NOISE_PSD` drives the acceleration. The model's parameters are the
scenario's identified ones; nothing of the autopilot's own gains is assumed.

Pure: times are the caller's (vehicle seconds, from message stamps), no clock inside; the
setpoints waiting for the next report are bounded (:data:`MAX_PENDING`).
"""

from __future__ import annotations

from collections import deque

import numpy as np

from companion.core.planner.vehicle_model import AxisResponse, ResponseModel, discretise

#: White noise on the acceleration, (m/s^2)^2 / s: what the model does not explain (wind, the
#: autopilot's own limits, parameter error). With 0.05 and :data:`VELOCITY_VAR` 0.01 the
#: model's 3 s-ahead velocity error on four PX4 SITL flights fell from 0.09-0.18 to
#: 0.08-0.13 m/s rms per axis (`python -m tests.px4.approach --model`, docs/PX4.md).
NOISE_PSD = 0.05
#: The velocity estimate's variance to the observer, (m/s)^2.
VELOCITY_VAR = 0.01
#: Setpoints held for the next report at most; older ones are folded into the estimate.
MAX_PENDING = 64
_CACHE = 64   # discretisations kept per axis response (north and east share theirs; a fixed rate repeats its steps)


class _Axis:
    """One axis's filter: state ``(v, xi[, a])`` (m/s, m, m/s^2) and its covariance."""

    def __init__(self, response: AxisResponse, steps: dict[float, tuple[np.ndarray, np.ndarray]]) -> None:
        a, b = response.matrices()
        self.a, self.b = a[1:, 1:], b[1:]          # the position is not observed: dropped
        self.n = self.b.size
        self.noise = np.zeros(self.n)
        self.noise[-1 if self.n == 3 else 0] = 1.0   # into the acceleration (v' without a lag)
        self.response = response
        self._steps = steps          # shared by the axes of one response (north and east)
        self.x = np.zeros(self.n)
        self.cov = np.eye(self.n)

    def start(self, v: float) -> None:
        """At the steady state holding ``v``, uncertain by one unit per state."""
        self.x = self.response.steady_state(v)[1:].copy()
        self.cov = np.eye(self.n)

    def step(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """``(Ad, Bd)`` over ``dt`` seconds (cached)."""
        got = self._steps.get(dt)
        if got is None:
            if len(self._steps) >= _CACHE:
                self._steps.clear()
            got = self._steps[dt] = discretise(self.a, self.b, dt)
        return got

    def predict(self, x: np.ndarray, cov: np.ndarray, dt: float, u: float) -> tuple[np.ndarray, np.ndarray]:
        ad, bd = self.step(dt)
        return ad @ x + bd * u, ad @ cov @ ad.T + (NOISE_PSD * dt) * np.outer(self.noise, self.noise)

    def correct(self, v: float) -> None:
        gain = self.cov[:, 0] / (self.cov[0, 0] + VELOCITY_VAR)
        self.x = self.x + gain * (v - self.x[0])
        self.cov = self.cov - np.outer(gain, self.cov[0])
        self.cov = 0.5 * (self.cov + self.cov.T)

    def internal(self, x: np.ndarray) -> tuple[float, float]:
        """``(xi, a)`` of state ``x`` (``a`` 0 without a lag)."""
        return float(x[1]), float(x[2]) if self.n == 3 else 0.0


class ResponseObserver:
    """Kalman filter of the response model's internal state, per NED axis (see the module docstring).

    Parameters
    ----------
    model : ResponseModel
        The planner's response model (north and east share its horizontal response).
    """

    def __init__(self, model: ResponseModel) -> None:
        self.model = model
        steps: dict[AxisResponse, dict] = {}
        self._axes = tuple(_Axis(axis, steps.setdefault(axis, {})) for axis in model.axes)
        self._pending: deque[tuple[float, np.ndarray]] = deque(maxlen=MAX_PENDING)
        self._t: float | None = None
        self._u = np.zeros(3)
        self.reports = 0
        """Velocity reports taken."""

    def reset(self) -> None:
        """Forget the state and the setpoints (the autopilot left the setpoint's control)."""
        self._pending.clear()
        self._t = None
        self._u = np.zeros(3)

    @property
    def started(self) -> bool:
        """Whether a velocity report has been taken since the last reset."""
        return self._t is not None

    def command(self, t_s: float, setpoint: np.ndarray) -> None:
        """The velocity setpoint (3,) NED m/s sent at vehicle time ``t_s``, held until the next.

        A setpoint stamped before one already waiting replaces the later ones (the vehicle
        clock was re-estimated). Before the first report only the last is kept: the one in
        force when the filter starts.
        """
        if self._t is None:
            self._u = np.array(setpoint, dtype=float)
            return
        while self._pending and self._pending[-1][0] > t_s:
            self._pending.pop()
        if len(self._pending) == MAX_PENDING:     # the oldest would fall out: fold it in as held from now on
            _, self._u = self._pending.popleft()
        self._pending.append((float(t_s), np.array(setpoint, dtype=float)))

    def observe(self, t_s: float, velocity: np.ndarray) -> bool:
        """Correct with the velocity estimate (3,) NED m/s at vehicle time ``t_s``; False if not
        after the last report (ignored). The first report starts the filter at its steady state."""
        velocity = np.asarray(velocity, dtype=float)
        if self._t is None:
            for axis, v in zip(self._axes, velocity):
                axis.start(float(v))
            self._t = float(t_s)
            self.reports += 1
            return True
        if not t_s > self._t:
            return False
        for k, axis in enumerate(self._axes):
            x, cov = axis.x, axis.cov
            for t0, t1, u in self._segments(t_s):
                x, cov = axis.predict(x, cov, t1 - t0, u[k])
            axis.x, axis.cov = x, cov
            axis.correct(float(velocity[k]))
        while self._pending and self._pending[0][0] <= t_s:
            _, self._u = self._pending.popleft()
        self._t = float(t_s)
        self.reports += 1
        return True

    def internal(self, t_s: float) -> np.ndarray | None:
        """The internal state (3, 2), ``(xi, a)`` per NED axis (m, m/s^2), predicted to vehicle
        time ``t_s`` under the setpoints sent (no correction); ``None`` before the first report."""
        if self._t is None:
            return None
        out = np.zeros((3, 2))
        for k, axis in enumerate(self._axes):
            x, cov = axis.x, axis.cov
            for t0, t1, u in self._segments(t_s):
                x, cov = axis.predict(x, cov, t1 - t0, u[k])
            out[k] = axis.internal(x)
        return out

    def _segments(self, t_s: float) -> list[tuple[float, float, np.ndarray]]:
        """``(from, to, setpoint)`` from the last report to ``t_s``: each setpoint from its time."""
        out = []
        t, u = self._t, self._u
        for t_cmd, setpoint in self._pending:
            if t_cmd >= t_s:
                break
            if t_cmd > t:
                out.append((t, t_cmd, u))
                t = t_cmd
            u = setpoint
        if t_s > t:
            out.append((t, t_s, u))
        return out
