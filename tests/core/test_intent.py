"""A plan as knots and back (companion/core/intent.py)."""

import numpy as np
import pytest

from companion.core.intent import Intent, intent_covariances, intent_from_plan, intent_means


def _smooth_plan(seed: int, n: int = 20, tau: float = 0.3):
    """A double-integrator path: velocity from accelerations held per step, |a| <= 1 m/s^2 per axis."""
    rng = np.random.default_rng(seed)
    acc = rng.uniform(-1.0, 1.0, size=(n, 3))
    v0 = rng.uniform(-2.0, 2.0, size=3)
    p0 = rng.uniform(-10.0, 10.0, size=3)
    p, v = [p0], [v0]
    for a in acc:
        p.append(p[-1] + v[-1] * tau + 0.5 * a * tau * tau)
        v.append(v[-1] + a * tau)
    return np.array(p), np.array(v), acc


def _exact(p, v, acc, tau, t):
    """The double integrator's position at plan time t (s)."""
    k = np.minimum((t / tau).astype(int), len(acc) - 1)
    dt = t - k * tau
    return p[k] + v[k] * dt[:, None] + 0.5 * acc[k] * (dt * dt)[:, None]


@pytest.mark.parametrize("seed", range(5))
def test_that_five_knots_rebuild_a_six_second_plan_to_within_a_few_centimetres(seed):
    tau = 0.3
    p, v, acc = _smooth_plan(seed, tau=tau)
    intent = intent_from_plan(10.0, tau, p[0], v[0], p[1:], v[1:], spacing_s=1.5)
    assert intent.knots == 5 and intent.end_s == pytest.approx(16.0)
    # knots on the plan's steps are the plan's own points
    assert np.allclose(intent.positions, p[::5]) and np.allclose(intent.velocities, v[::5])
    t = np.linspace(0.0, 6.0, 121)
    err = np.linalg.norm(intent_means(intent, 10.0 + t) - _exact(p, v, acc, tau, t), axis=1)
    # a cubic through pos/vel 1.5 s apart against accelerations that switch every 0.3 s within +-1:
    # bounded by (1.5^2 / 8) * 2 m/s^2 * sqrt(3) ~ 0.97 m in the worst case; random switching averages out
    assert err.max() < 0.15
    assert err[::30].max() < 1e-9           # exact at the knots (every 1.5 s)


def test_that_knots_between_the_plans_steps_lie_on_its_path():
    tau = 0.3
    p, v, acc = _smooth_plan(7, tau=tau)
    intent = intent_from_plan(0.0, tau, p[0], v[0], p[1:], v[1:], spacing_s=1.0)   # 1.0 s is 3.33 steps
    assert intent.knots == 5
    exact = _exact(p, v, acc, tau, intent.knot_times())
    assert np.abs(intent.positions - exact).max() < 0.01


def test_that_a_short_plan_gives_fewer_knots_and_the_path_goes_on_at_the_last_velocity():
    p = np.array([[1.0, 0.0, -5.0], [2.0, 0.0, -5.0], [3.0, 0.0, -5.0], [4.0, 0.0, -5.0]])
    v = np.tile([1.0, 0.0, 0.0], (4, 1))
    intent = intent_from_plan(0.0, 1.0, [0.0, 0.0, -5.0], [1.0, 0.0, 0.0], p, v, spacing_s=1.5)
    assert intent.knots == 3                                           # 0, 1.5, 3.0 of a 4 s plan
    got = intent_means(intent, np.array([-1.0, 0.5, 2.2, 6.0, 10.0]))
    assert np.allclose(got[:, 0], [-1.0, 0.5, 2.2, 6.0, 10.0]) and np.allclose(got[:, 1:], [0.0, -5.0])


def test_that_covariances_grow_from_the_intents_time_only():
    c0 = np.diag([0.01, 0.02, 0.03])
    covs = intent_covariances(c0, 5.0, np.array([4.0, 5.0, 7.0]), growth_m2ps=0.1)
    assert np.allclose(covs[0], c0) and np.allclose(covs[1], c0)
    assert np.allclose(covs[2], c0 + 0.2 * np.eye(3))


@pytest.mark.parametrize("bad", [
    dict(positions=np.zeros((6, 3)), velocities=np.zeros((6, 3))),
    dict(positions=np.zeros((0, 3)), velocities=np.zeros((0, 3))),
    dict(positions=np.zeros((2, 3)), velocities=np.zeros((3, 3))),
    dict(positions=np.full((2, 3), np.nan), velocities=np.zeros((2, 3))),
    dict(positions=np.zeros((2, 3)), velocities=np.zeros((2, 3)), spacing_s=0.0),
])
def test_that_a_malformed_intent_is_refused(bad):
    kwargs = dict(t0_s=0.0, spacing_s=1.5) | bad
    with pytest.raises(ValueError):
        Intent(**kwargs)
