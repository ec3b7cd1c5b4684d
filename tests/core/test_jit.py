"""The compiled hot loops (companion.core.jit): each gives its Python or numpy original's bits."""

from __future__ import annotations

import contextlib
import math
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import companion.core.small_matrix as K
from companion.core import jit, overlap
from companion.core.planner import Planner, PlanRequest, formulations, scp
from companion.errors import InputError
from tests.core.test_planner_scp import scenario_one


def _libm_transcendentals() -> bool:
    """Whether numpy's float64 exp and log give the C library's bits here (then the kernels agree bit for bit)."""
    x = np.random.default_rng(0).uniform(-30.0, 30.0, 20000)
    return (np.array_equal(np.exp(x), [math.exp(v) for v in x])
            and np.array_equal(np.log(np.exp(x)), [math.log(v) for v in np.exp(x)]))


def _require_compiled() -> None:
    if not jit.available():
        pytest.fail("numba is a runtime dependency: the compiled kernels must be available")


def _random_covariances(rng: np.random.Generator, n: int, decades: float) -> np.ndarray:
    """``n`` random 3x3 covariances, eigenvalues log-uniform over ``10**[-decades, decades]``."""
    q = np.linalg.qr(rng.standard_normal((n, 3, 3)))[0]
    return np.einsum("nij,nj,nkj->nik", q, 10.0 ** rng.uniform(-decades, decades, (n, 3)), q)


@contextlib.contextmanager
def _numba_unimportable():
    """Inside, ``import numba`` fails: the code runs as on a machine without a working numba."""
    jit.available.cache_clear()
    try:
        with pytest.MonkeyPatch.context() as mp:
            mp.setitem(sys.modules, "numba", None)    # "import numba" now raises ImportError
            yield
    finally:
        jit.available.cache_clear()


@pytest.fixture
def numpy_only():
    """From when it is requested, ``import numba`` fails (:func:`_numba_unimportable`)."""
    with _numba_unimportable():
        yield
    assert jit.available()


def _clip_reference(v: np.ndarray, v0: np.ndarray, vmax: np.ndarray, da: np.ndarray) -> np.ndarray:
    """The forward projection written with np.clip, row by row (independent of the kernel)."""
    out, prev = v.copy(), v0.copy()
    for i in range(len(out)):
        out[i] = np.clip(np.clip(out[i], prev - da, prev + da), -vmax, vmax)
        prev = out[i]
    return out


@settings(max_examples=25, deadline=None, derandomize=True)
@given(st.integers(0, 2**32 - 1))
def test_that_the_compiled_minmax_gives_the_numpy_kernels_bits(seed):
    _require_compiled()
    rng = np.random.default_rng(seed)
    n = 60
    covs = _random_covariances(rng, 2 * n, 3.0)
    covs[n + 1] = 2.5 * covs[1]      # S2 a multiple of S1: the start is the root
    mu1 = rng.standard_normal((n, 3)) * 10.0
    mu2 = mu1 + rng.standard_normal((n, 3)) * rng.uniform(1e-3, 50.0, (n, 1))
    mu2[0] = mu1[0]                  # coincident means: eta 0, a fixed direction
    pairs = overlap.CovariancePairs.from_arrays(covs[:n], covs[n:])
    m1, m2 = K.vectors_to_components(mu1), K.vectors_to_components(mu2)
    fast = overlap._minmax(m1, m2, pairs.s1, pairs.s2, pairs.lead, compiled=True)
    slow = overlap._minmax(m1, m2, pairs.s1, pairs.s2, pairs.lead, compiled=False)
    exact = _libm_transcendentals()
    for field in ("lam", "eta", "alpha", "beta", "normal", "s1", "s2", "eta_grad_mu1", "residual"):
        a, b = getattr(fast, field), getattr(slow, field)
        assert a.shape == b.shape, field
        # the same layout too: einsum's order of summation over a field follows its strides
        assert a.strides == b.strides, field
        if exact:
            np.testing.assert_array_equal(a, b, err_msg=field)
        elif field == "residual":
            # eta1 - eta2, zero to rounding: a difference of terms of the size of eta, so the last
            # bits of exp/log move it on that scale, not on its own
            np.testing.assert_array_less(np.abs(a - b), 1e-10 * np.maximum(np.abs(fast.eta), 1.0), err_msg=field)
        else:
            # numpy's own SIMD exp/log (AVX-512) differ from the C library's in the last bits, and
            # Newton then stops on other iterates. Measured with numpy 2.4.6 over 1,539 seeds: lam
            # within 2.5e-14, eta and alpha within 7.4e-8, beta 1.3e-7 relative. The largest are
            # pairs with eigenvalues over six decades whose residual stays near 1e-5 (both kernels
            # there end about 4e-8 of eta from the support ratio's maximum at their own normal)
            np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-14, err_msg=field)
    assert fast.eta[0] == 0.0 and np.all(fast.alpha[0] == 0.0)


@settings(max_examples=25, deadline=None, derandomize=True)
@given(st.integers(0, 2**32 - 1))
def test_that_minmax_of_batch_first_pairs_gives_the_batch_last_kernels_bits(seed):
    """``minmax`` of pairs with one leading shape runs the kernel on the arrays as given (checked
    in place, symmetrised as read); the general path lays them out batch last first. The same
    bits, shapes and strides, across the kernel's blocks of 64 pairs."""
    _require_compiled()
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 200))
    covs = _random_covariances(rng, 2 * n, 3.0)
    covs *= 1.0 + 1e-12 * rng.standard_normal(covs.shape)     # the last bits asymmetric, within the checks
    mu1 = rng.standard_normal((n, 3)) * 10.0
    mu2 = mu1 + rng.standard_normal((n, 3)) * rng.uniform(1e-3, 50.0, (n, 1))
    mu2[0] = mu1[0]                                     # coincident means
    lead = (2, n // 2) if n % 2 == 0 else (n,)
    args = (mu1.reshape(lead + (3,)), covs[:n].reshape(lead + (3, 3)), mu2.reshape(lead + (3,)),
            covs[n:].reshape(lead + (3, 3)))
    direct = overlap._minmax_batch_first3(*args)
    assert direct is not None
    m1, m2, pairs = overlap._validate_pair(*args)
    general = overlap._minmax(m1, m2, pairs.s1, pairs.s2, pairs.lead, compiled=True)
    public = overlap.minmax(*args)
    for field in ("lam", "eta", "alpha", "beta", "normal", "s1", "s2", "eta_grad_mu1", "residual"):
        for result in (direct, public):
            a, b = getattr(result, field), getattr(general, field)
            assert a.shape == b.shape and a.strides == b.strides, field
            np.testing.assert_array_equal(a, b, err_msg=field)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(st.integers(0, 2**32 - 1))
def test_that_the_compiled_forward_projection_gives_the_python_bits(seed):
    _require_compiled()
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 60))
    v = rng.normal(0.0, 3.0, (n, 3))
    v[rng.random((n, 3)) < 0.1] = 0.0                   # zeros and -0.0 as the planner meets them
    v[rng.random((n, 3)) < 0.05] = -0.0
    v0 = rng.normal(0.0, 2.0, 3)
    vmax, da = rng.uniform(0.5, 4.0, 3), rng.uniform(0.05, 1.5, 3)
    vmax.setflags(write=False)                          # read-only inputs, as a config's arrays are
    compiled, python = v.copy(), v.copy()
    scp._project_forward()(compiled, v0, vmax, da)
    scp._project_forward.py_func(python, v0, vmax, da)
    assert compiled.tobytes() == python.tobytes()       # bit for bit, signed zeros included
    np.testing.assert_array_equal(compiled, _clip_reference(v, v0, vmax, da))
    steps = np.abs(np.diff(np.vstack([v0, compiled]), axis=0))
    assert np.all(np.abs(compiled) <= vmax) and np.all((steps <= da + 1e-12) | (np.abs(compiled) == vmax))


@settings(max_examples=40, deadline=None, derandomize=True)
@given(st.integers(0, 2**32 - 1))
def test_that_the_compiled_iterate_pairs_give_the_numpy_nudge_and_layout_bits(seed):
    """The SCP's minmax inputs: the iterate against every obstacle mean, nudged off any it is
    within 1e-6 m of, laid out as components; the same bytes as numpy's _coincident, _nudge
    and vectors_to_components, at the nudge radius's edge and with signed zeros included."""
    _require_compiled()
    rng = np.random.default_rng(seed)
    n_obs, n_steps = int(rng.integers(0, 5)), int(rng.integers(1, 41))
    p_bar = rng.normal(0.0, 5.0, (n_steps, 3))
    p_bar[rng.random((n_steps, 3)) < 0.1] = -0.0
    means = p_bar[None] + rng.normal(0.0, 3.0, (n_obs, n_steps, 3))
    kind = rng.integers(0, 4, (n_obs, n_steps))      # far, on the iterate, just inside, just outside 1e-6 m
    direction = rng.normal(size=(n_obs, n_steps, 3))
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    for code, scale in ((1, 0.0), (2, 1e-6 * (1.0 - 1e-12)), (3, 1e-6 * (1.0 + 1e-12))):
        means[kind == code] = (p_bar[None] + scale * direction)[kind == code]
    means.setflags(write=False)
    m1, m2 = np.empty((3, n_obs * n_steps)), np.empty((3, n_obs * n_steps))
    nudged = formulations._iterate_pairs()(p_bar, means, formulations._NUDGE_M, m1, m2)
    close = formulations._coincident(p_bar, means)
    assert nudged == bool(np.any(close))
    reference = K.vectors_to_components(formulations._nudge(p_bar, means, close))
    assert m1.tobytes() == reference.tobytes() and m2.tobytes() == K.vectors_to_components(means).tobytes()


@settings(max_examples=30, deadline=None, derandomize=True)
@given(st.integers(0, 2**32 - 1))
def test_that_the_compiled_pair_layout_gives_the_numpy_bits(seed):
    """A request's covariance pairs (drone against each obstacle, symmetrised, batch-last):
    the same bytes from the compiled pass and from numpy's layout, symmetrisation and tile."""
    _require_compiled()
    rng = np.random.default_rng(seed)
    n_obs, n_steps = int(rng.integers(0, 5)), int(rng.integers(1, 41))
    c1 = _random_covariances(rng, n_steps, 2.0)
    c2 = _random_covariances(rng, max(n_obs, 1) * n_steps, 3.0)[: n_obs * n_steps].reshape(n_obs, n_steps, 3, 3)
    c1 += 1e-12 * rng.standard_normal(c1.shape)       # the last bits asymmetric, as products leave them
    c2 = c2 + 1e-12 * rng.standard_normal(c2.shape)

    def layout():
        p = overlap.CovariancePairs.shared_first(c1, c2)
        return p.lead, p.s1.tobytes(), p.s2.tobytes()

    compiled, reference = _compiled_and_numpy(layout)
    assert compiled[0] == (n_obs, n_steps)
    assert compiled == reference


def _separator_fields(rng: np.random.Generator, n_obs: int, n_steps: int):
    """A separator's normal (P, N, 3) in the kernel's strided layout, s1, s2 (P, N), with signed zeros."""
    comp = rng.normal(size=(3, n_obs * n_steps)) * 10.0 ** rng.uniform(-3.0, 1.0)
    comp[rng.random(comp.shape) < 0.1] = rng.choice([0.0, -0.0])
    normal = comp.T.reshape(n_obs, n_steps, 3)           # what MinmaxResult holds: a strided view
    s1, s2 = (rng.uniform(0.05, 2.0, n_obs * n_steps).reshape(n_obs, n_steps) for _ in range(2))
    return normal, s1, s2


@settings(max_examples=40, deadline=None, derandomize=True)
@given(st.integers(0, 2**32 - 1))
def test_that_the_compiled_hyperplane_rows_and_exact_figures_give_the_numpy_bits(seed):
    """The rows and the exact touch radius and distance per (obstacle, step): the same bytes
    compiled and with numpy, for the separator's strided normal and a contiguous copy of it,
    with signed zeros, zero radii and positions on the obstacle means."""
    _require_compiled()
    rng = np.random.default_rng(seed)
    n_obs, n_steps = int(rng.integers(0, 5)), int(rng.integers(1, 41))
    normal, s1, s2 = _separator_fields(rng, n_obs, n_steps)
    if rng.random() < 0.3:
        normal = np.ascontiguousarray(normal)
    positions = rng.normal(0.0, 5.0, (n_steps, 3))
    means = positions[None] + rng.normal(0.0, 3.0, (n_obs, n_steps, 3)) * (rng.random((n_obs, n_steps, 1)) < 0.8)
    means[rng.random(means.shape) < 0.05] = -0.0
    radii = rng.choice([0.0, 0.3, 0.5], n_obs)
    drone = float(rng.choice([0.0, 0.4]))
    upper = None if rng.random() < 0.5 else 3.5

    def both():
        rows = formulations.pair_kernels.hyperplane_rows(normal, s1, s2, means, radii + drone, 2.5, upper)
        figs = formulations.pair_kernels.exact_figures(normal, s1, s2, means, positions, radii, drone)
        return [a.tobytes() for a in rows + figs]

    compiled, reference = _compiled_and_numpy(both)
    assert compiled == reference


def test_that_the_pair_kernels_sum_as_einsum_did_on_the_separators_layout():
    """The planner's rows and figures were einsum's sums over the axes; on the separator's
    strided normal (the only layout the planner passes) einsum sums in the axes' order from
    +0, which is what dot3 and the kernels do, so the change from einsum moved no bit."""
    rng = np.random.default_rng(11)
    normal, s1, s2 = _separator_fields(rng, 3, 40)
    means = rng.normal(0.0, 10.0, (3, 40, 3))
    means[0, :5] = -0.0
    got, want = formulations.pair_kernels.dot3(normal, means), np.einsum("pnk,pnk->pn", normal, means)
    assert got.tobytes() == want.tobytes()
    rows = formulations.pair_kernels.hyperplane_rows(normal, s1, s2, means, np.full(3, 0.9), 2.5, None)
    assert rows[1].tobytes() == (2.5 * (s1 + s2) + 0.9 - want).tobytes()


def _spoil(rng: np.random.Generator, batches: list[np.ndarray], tolerance: float) -> None:
    """Now and then (0 to 2 times) spoil a matrix of one of ``batches`` (each (n, 3, 3), in place), or
    nearly: a NaN or infinite entry, asymmetry at about ``tolerance`` of the largest entry, eigenvalues
    through zero (semidefinite, indefinite with a positive determinant, just definite), a leading minor
    at or below zero."""
    for _ in range(int(rng.integers(0, 3))):
        c = batches[rng.integers(len(batches))]
        k, (r, q) = rng.integers(len(c)), rng.choice(3, 2, replace=False)
        kind = rng.integers(4)
        if kind == 0:
            c[k, r, q] = (np.nan, np.inf, -np.inf)[rng.integers(3)]
        elif kind == 1:
            c[k, r, q] += rng.choice([0.5, 0.999, 1.001, 2.0]) * tolerance * np.max(np.abs(c[k]))
        elif kind == 2:
            if not np.isfinite(c[k]).all():     # spoilt already: no eigenvalues to move
                continue
            w, v = np.linalg.eigh(0.5 * (c[k] + c[k].T))
            w *= rng.permutation([(1.0, 1.0, 0.0), (1.0, 1.0, -1.0), (-1.0, -1.0, 1.0), (1.0, 1.0, 1e-14)][rng.integers(4)])
            c[k] = (v * w) @ v.T
        else:
            c[k, 0, 0] = -abs(c[k, 0, 0]) if rng.random() < 0.5 else c[k, 0, 0]
            c[k, 1, 1] = c[k, 0, 1] ** 2 / max(abs(c[k, 0, 0]), 1e-300) * rng.choice([0.5, 1.0, 2.0])


def _outcome(build):
    """``build()``'s result, or the text of the InputError it raised."""
    try:
        return build()
    except InputError as exc:
        return str(exc)


def _compiled_and_numpy(build):
    """``_outcome(build)`` with the compiled passes, then as without numba."""
    compiled = _outcome(build)
    with _numba_unimportable():      # a hypothesis test cannot take the numpy_only fixture per example
        return compiled, _outcome(build)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(st.integers(0, 2**32 - 1))
def test_that_the_compiled_covariance_checks_give_the_numpy_bits_and_errors(seed):
    """Checked pairs (finite, symmetric to 1e-9, positive definite, symmetrised): the same bytes,
    or the same error naming the same covariance and index, from the compiled pass and from numpy;
    asymmetry and minors are drawn on both sides of the tests' edges."""
    _require_compiled()
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 30))
    c1, c2 = _random_covariances(rng, n, 2.0), _random_covariances(rng, n, 3.0)
    c1 += 1e-12 * rng.standard_normal(c1.shape)       # the last bits asymmetric
    _spoil(rng, [c1, c2], 1e-9)
    a = c1[0] if rng.random() < 0.25 else c1          # now and then one covariance against the batch

    def pairs():
        p = overlap.CovariancePairs.from_arrays(a, c2)
        return p.lead, p.s1.tobytes(), p.s2.tobytes()

    compiled, reference = _compiled_and_numpy(pairs)
    assert compiled == reference


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.integers(0, 2**32 - 1))
def test_that_minmax_checks_pairs_given_batch_first_as_the_numpy_checks_do(seed):
    """The kernel checks pairs given batch first as it reads them: it refuses exactly the
    batches the numpy checks refuse (NaN or infinite means or entries, asymmetry and minors
    on both sides of the tests' edges), and ``minmax`` then words the same error."""
    _require_compiled()
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 150))
    c1, c2 = _random_covariances(rng, n, 2.0), _random_covariances(rng, n, 3.0)
    c1 *= 1.0 + 1e-12 * rng.standard_normal(c1.shape)      # the last bits asymmetric
    mu1, mu2 = rng.standard_normal((n, 3)), rng.standard_normal((n, 3))
    bad = (np.nan, np.inf, -np.inf)[rng.integers(3)]
    spoil = rng.integers(4)     # one kind of fault (or none) per example, so that each check decides alone
    if spoil == 0:
        _spoil(rng, [c1, c2], 1e-9)
    elif spoil == 1:            # a diagonal entry, which _spoil leaves finite
        i = rng.integers(3)
        (c1, c2)[rng.integers(2)][rng.integers(n), i, i] = bad
    elif spoil == 2:
        (mu1, mu2)[rng.integers(2)][rng.integers(n), rng.integers(3)] = bad
    # the reference: the numpy checks (the general path's compiled pass shares the kernel's)
    with _numba_unimportable():
        refused = _outcome(lambda: overlap._validate_pair(mu1, c1, mu2, c2))
    refused = refused if isinstance(refused, str) else None
    assert (overlap._minmax_batch_first3(mu1, c1, mu2, c2) is None) == (refused is not None)

    def public() -> None:
        overlap.minmax(mu1, c1, mu2, c2)

    assert _outcome(public) == refused     # None when accepted, else the same words


@settings(max_examples=40, deadline=None, derandomize=True)
@given(st.integers(0, 2**32 - 1))
def test_that_a_plan_request_checks_its_covariances_compiled_as_with_numpy(seed):
    """A request's drone, obstacle and margin covariances: accepted with the same arrays, or
    refused with the same error naming the same field and index, compiled and with numpy."""
    _require_compiled()
    rng = np.random.default_rng(seed)
    n, p = int(rng.integers(1, 20)), int(rng.integers(0, 4))
    drone, obstacles = _random_covariances(rng, n, 1.0), _random_covariances(rng, max(p, 1) * n, 2.0)
    margin = _random_covariances(rng, 1, 1.0)
    _spoil(rng, [drone, obstacles, margin], 1e-9)
    obstacles, means = obstacles[: p * n].reshape(p, n, 3, 3), rng.standard_normal((p, n, 3))

    def request():
        r = PlanRequest(position=np.zeros(3), velocity=np.zeros(3), drone_covs=drone, target=np.ones(3),
                        obstacle_means=means, obstacle_covs=obstacles, obstacle_radii=np.full(p, 0.5),
                        margin_cov=margin[0])
        return r.drone_covs.tobytes(), r.obstacle_covs.tobytes(), r.safety_covs.tobytes()

    compiled, reference = _compiled_and_numpy(request)
    assert compiled == reference


def test_that_warm_up_loads_every_registered_kernel():
    jit.warm_up()
    for compiled in jit._REGISTERED:
        assert compiled.cache_info().currsize == 1


def test_that_an_inline_helper_is_compiled_into_its_callers_and_stays_python_in_its_module():
    """``jit.inline``: the compiled function calls the helper's numba version (a copy of the
    caller's globals holds it); the module keeps the plain function, which answers the same."""
    from companion.core import minmax_kernel

    _require_compiled()
    jit.warm_up()
    helper = minmax_kernel._checked_covariance
    assert type(helper).__name__ == "function" and helper.__jit_inline__
    entries = (2.0, 0.3, 0.1, 0.3 + 1e-12, 1.0, 0.2, 0.1, 0.2, 0.5)
    assert helper(*entries) == (True, 2.0, 0.5 * (0.3 + 0.3 + 1e-12), 0.1, 1.0, 0.2, 0.5)
    assert helper(*entries[:8], -0.5)[0] is False
    s = np.empty((3, 3, 1))
    assert minmax_kernel._checked_pairs3()(np.array(entries).reshape(1, 3, 3), s) == -1
    assert s[0, 1, 0] == s[1, 0, 0] == 0.5 * (0.3 + 0.3 + 1e-12)


def test_that_a_numba_that_does_not_import_leaves_the_numpy_code_with_the_same_answers(request, caplog):
    rng = np.random.default_rng(5)
    covs = _random_covariances(rng, 8, 2.0)
    mu1, mu2 = rng.standard_normal((4, 3)), rng.standard_normal((4, 3)) * 3.0
    compiled = overlap.minmax(mu1, covs[:4], mu2, covs[4:])
    v, v0, vmax, da = rng.normal(0.0, 3.0, (6, 3)), np.zeros(3), np.full(3, 2.0), np.full(3, 0.6)
    request.getfixturevalue("numpy_only")
    assert not jit.available()
    assert "numba does not import" in caplog.text
    jit.warm_up()                                  # a no-op, not an error
    fallback = overlap.minmax(mu1, covs[:4], mu2, covs[4:])
    for field in ("lam", "eta", "alpha", "beta", "normal", "s1", "s2"):
        np.testing.assert_allclose(getattr(fallback, field), getattr(compiled, field), rtol=1e-12, atol=1e-15,
                                   err_msg=field)
    python = v.copy()
    scp._project_forward.py_func(python, v0, vmax, da)     # the projection's fallback is its Python original
    np.testing.assert_array_equal(python, _clip_reference(v, v0, vmax, da))


@pytest.mark.parametrize("formulation", ["hyperplane", "paper", "bhattacharyya"])
def test_that_plans_are_the_same_bits_with_and_without_the_compiled_kernels(formulation, request):
    if not _libm_transcendentals():
        pytest.skip("numpy's own SIMD exp/log here: the numpy kernel's last bits differ from the C library's")
    cfg, req = scenario_one(formulation)

    def fly() -> list:
        planner, plans, warm = Planner(cfg), [], None
        for _ in range(3):                          # a cold plan, then two warm-started replans
            warm = planner.solve(req, warm_start=warm)
            plans.append(warm)
        return plans

    compiled = fly()
    request.getfixturevalue("numpy_only")           # as without numba: the numpy and Python code
    assert not jit.available()
    numpy_plans = fly()
    for a, b in zip(compiled, numpy_plans):
        assert a.status == b.status and a.iterations == b.iterations
        for field in ("velocities", "positions", "commands", "eta", "contour_of_touch"):
            assert np.asarray(getattr(a, field)).tobytes() == np.asarray(getattr(b, field)).tobytes(), field


@settings(max_examples=40, deadline=None, derandomize=True)
@given(st.integers(0, 2**32 - 1), st.sampled_from([0.0, 0.06, 0.4]))
def test_that_the_compiled_lag_gives_the_numpy_positions_and_commands(seed, time_constant_s):
    """The lag's positions (increments, running sum, ``p_0 +``) and commands, unclipped and clipped
    as np.clip clips (values at the bounds, beyond them, infinite, NaN, signed zeros): the same
    bytes from the compiled pass and from numpy."""
    _require_compiled()
    from companion.core.planner.vehicle_model import LagModel
    rng = np.random.default_rng(seed)
    lag = LagModel.from_time_constant(0.3, time_constant_s)
    n = int(rng.integers(1, 45))
    limit = rng.choice([0.5, 1.0, 3.0], 3)
    v = rng.normal(0.0, 2.0, (n, 3))
    pick = rng.random((n, 3))
    v[pick < 0.1] = -0.0
    v[(pick >= 0.1) & (pick < 0.2)] = 0.0
    v[(pick >= 0.2) & (pick < 0.3)] = np.broadcast_to(limit, (n, 3))[(pick >= 0.2) & (pick < 0.3)]
    v[(pick >= 0.3) & (pick < 0.33)] = np.inf
    v[(pick >= 0.33) & (pick < 0.35)] = np.nan
    v0 = rng.choice([-0.0, 0.0, 1.5, -2.0], 3)
    p0 = np.where(rng.random(3) < 0.5, rng.choice([-0.0, 0.0], 3), rng.normal(0.0, 10.0, 3))
    v[0, rng.random(3) < 0.5] = -0.0                # -0 increments: the running sum and p_0 + keep signs

    def figures():
        with np.errstate(invalid="ignore"):      # 0 * inf in numpy's products: NaN, as compiled
            return lag.positions(p0, v0, v), lag.commands(v0, v), lag.commands(v0, v, limit)

    compiled = figures()
    with _numba_unimportable():
        reference = figures()
    for a, b in zip(compiled, reference, strict=True):
        nan = np.isnan(a)        # NaN where numpy has NaN (its sign bit, from inf - inf, is the CPU's choice)
        assert np.array_equal(nan, np.isnan(b)) and a[~nan].tobytes() == b[~nan].tobytes()


@settings(max_examples=40, deadline=None, derandomize=True)
@given(st.integers(0, 2**32 - 1))
def test_that_the_compiled_touch_terms_give_the_numpy_contour_and_overlap(seed):
    """A plan's contour of touch and overlap from eta (negative, signed zeros, large, infinite; a
    NaN: the same error): the same bytes with the compiled pass and with numpy."""
    _require_compiled()
    from companion.core.planner.safety import SafetyFigures
    rng = np.random.default_rng(seed)
    shape = (int(rng.integers(0, 5)), int(rng.integers(1, 41)))
    eta = rng.normal(0.0, 3.0, shape)
    pick = rng.random(shape)
    eta[pick < 0.1], eta[(pick >= 0.1) & (pick < 0.2)] = -0.0, 0.0
    eta[(pick >= 0.2) & (pick < 0.22)] = np.inf
    eta[(pick >= 0.22) & (pick < 0.24)] = -np.inf
    eta[(pick >= 0.24) & (pick < 0.26)] = rng.uniform(30.0, 40.0)
    if rng.random() < 0.1 and eta.size:
        eta.flat[rng.integers(eta.size)] = np.nan
    if rng.random() < 0.3:
        eta = np.asfortranarray(eta)

    terms = formulations.pair_kernels.touch_terms(eta)
    if not np.isnan(eta).any():           # the special functions' arguments as numpy forms them
        m = np.maximum(eta, 0.0)
        assert terms[0].tobytes() == (0.5 * np.square(m)).tobytes() and terms[1].tobytes() == (-m).tobytes()

    def figures():
        figs = SafetyFigures(eta=eta, wall_margin=np.zeros((0, shape[1])), distance_margin=eta, lam=eta)
        try:
            return figs.contour_of_touch.tobytes(), figs.overlap.tobytes()
        except InputError as exc:
            return str(exc)

    compiled = figures()
    with _numba_unimportable():
        reference = figures()
    assert compiled == reference
