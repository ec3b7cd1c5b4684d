"""The response observer (companion/core/planner/response_observer.py) against vehicles with a known state."""

from __future__ import annotations

import numpy as np

from companion.core.planner import response_observer
from companion.core.planner.response_observer import ResponseObserver
from companion.core.planner.vehicle_model import AxisResponse, ResponseModel, discretise

HORIZONTAL, VERTICAL = AxisResponse(1.51, 0.3254, 0.8163, 0.2169), AxisResponse(3.211, 0.1386, 0.5217, 0.017)
MODEL = ResponseModel(0.3, HORIZONTAL, VERTICAL)


def _fly(x0: np.ndarray, setpoints: list[tuple[float, np.ndarray]], t_end: float, dt: float = 0.001):
    """The model's own vehicle (per axis state (p, v, xi, a)) from ``x0`` (3, 4) under the
    setpoints ``(t, u)`` held from their times: a function of time giving the state (3, 4)."""
    steps = [discretise(*axis.matrices(), dt) for axis in MODEL.axes]
    times = np.arange(0.0, t_end + dt, dt)
    states = np.empty((times.size, 3, 4))
    x = np.array(x0, dtype=float)
    k, u = 0, np.zeros(3)
    for i, t in enumerate(times):
        while k < len(setpoints) and setpoints[k][0] <= t + 1e-12:
            u = setpoints[k][1]
            k += 1
        states[i] = x
        x = np.array([ad @ x[axis] + bd * u[axis] for axis, (ad, bd) in enumerate(steps)])
    return lambda t: states[int(round(t / dt))]


def _wound_up_flight(seed: int = 0):
    """Setpoints at 20 Hz changing every second, from a vehicle at rest whose integral still
    holds 3 m north (its cruise's drag); velocity reports at about 30 Hz with jitter."""
    rng = np.random.default_rng(seed)
    each_second = rng.uniform(-1.5, 1.5, (20, 3))
    out = [(0.05 * i, each_second[i // 20]) for i in range(400)]
    x0 = np.zeros((3, 4))
    x0[0, 2] = 3.0
    state = _fly(x0, out, 20.0)
    reports = np.cumsum(rng.uniform(0.025, 0.04, 560))
    return out, state, reports[reports < 19.9]


def test_that_it_finds_the_integral_and_acceleration_of_the_models_own_vehicle():
    setpoints, state, reports = _wound_up_flight()
    observer = ResponseObserver(MODEL)
    sent = iter(setpoints)
    pending = next(sent)
    errors = []
    for t in reports:
        while pending is not None and pending[0] <= t:   # the loop sends before the report arrives
            observer.command(*pending)
            pending = next(sent, None)
        observer.observe(t, state(round(t, 3))[:, 1])
        if t > 10.0:
            errors.append(np.abs(observer.internal(t) - state(round(t, 3))[:, 2:]).max())
            # predicted to a plan's start 0.2 s ahead under the setpoint held (when it is held)
            if int(t) == int(t + 0.2):
                ahead = round(t + 0.2, 3)
                errors.append(np.abs(observer.internal(ahead) - state(ahead)[:, 2:]).max())
    assert observer.reports == reports.size
    assert max(errors) < 0.05                 # xi in m, a in m/s^2; the integral started 3 m off
    # without the observer the steady state would have said xi = k v / ki at the velocity
    assert abs(HORIZONTAL.steady_state(state(10.0)[0, 1])[2] - state(10.0)[0, 2]) > 0.3


def test_that_the_first_report_starts_at_the_steady_state_and_late_reports_are_ignored():
    observer = ResponseObserver(MODEL)
    assert observer.internal(1.0) is None and not observer.started
    observer.command(0.2, -np.ones(3))
    observer.command(0.5, np.array([1.0, 0.0, 0.0]))   # before the first report: the last is the one in force
    assert observer.observe(1.0, np.array([1.0, 0.0, 0.0]))
    np.testing.assert_allclose(observer.internal(1.0)[0], HORIZONTAL.steady_state(1.0)[2:])
    np.testing.assert_allclose(observer.internal(2.0)[0], HORIZONTAL.steady_state(1.0)[2:], atol=1e-12)  # it holds 1 m/s
    before = observer.internal(1.0)
    assert not observer.observe(1.0, np.array([5.0, 5.0, 5.0]))   # the same time: ignored
    assert not observer.observe(0.9, np.array([5.0, 5.0, 5.0]))   # earlier: ignored
    np.testing.assert_array_equal(observer.internal(1.0), before)
    observer.reset()
    assert observer.internal(1.0) is None


def test_that_waiting_setpoints_are_bounded_and_a_clock_step_back_replaces_them():
    observer = ResponseObserver(MODEL)
    observer.observe(0.0, np.zeros(3))
    for i in range(3 * response_observer.MAX_PENDING):
        observer.command(0.01 * (i + 1), np.full(3, 0.1))
    assert len(observer._pending) == response_observer.MAX_PENDING
    observer.command(0.5, np.full(3, -1.0))       # stamped before the last ones: they go
    assert observer._pending[-1][0] == 0.5 and all(t <= 0.5 for t, _ in observer._pending)
    assert observer.observe(1.0, np.zeros(3))
    assert not observer._pending


def test_that_a_vehicle_that_does_not_follow_is_explained_by_a_force_holding_it():
    """A vehicle held at rest against a setpoint of 1 m/s north: the observer puts the force
    that holds it into the integral, so the model from its state predicts it slow to move
    (the model's integral still grows with the error); from the steady state at rest the model
    predicts it speeds off."""
    observer = ResponseObserver(MODEL)
    observer.observe(0.0, np.zeros(3))
    push = np.array([1.0, 0.0, 0.0])
    for i in range(1, 61):
        observer.command(0.05 * (i - 1), push)
        observer.observe(0.05 * i, np.zeros(3))
    internal = observer.internal(3.0)
    ahead = MODEL.velocity_at(np.zeros(3), np.tile(push, (4, 1)), 1.0, internal)
    steady = MODEL.velocity_at(np.zeros(3), np.tile(push, (4, 1)), 1.0)
    assert steady[0] > 0.6 and 0.0 <= ahead[0] < 0.5 * steady[0]   # measured: 0.28 against 0.65 m/s
    np.testing.assert_array_equal(internal[1:], 0.0)        # nothing on the axes nobody pushed
