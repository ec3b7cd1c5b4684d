"""The compiled hot loops (companion.core.jit): each gives its Python original's bits."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.core import jit
from companion.core.planner import scp


def _clip_reference(v: np.ndarray, v0: np.ndarray, vmax: np.ndarray, da: np.ndarray) -> np.ndarray:
    """The forward projection written with np.clip, row by row (independent of the kernel)."""
    out, prev = v.copy(), v0.copy()
    for i in range(len(out)):
        out[i] = np.clip(np.clip(out[i], prev - da, prev + da), -vmax, vmax)
        prev = out[i]
    return out


@settings(max_examples=40, deadline=None, derandomize=True)
@given(st.integers(0, 2**32 - 1))
def test_that_the_compiled_forward_projection_gives_the_python_bits(seed):
    if not jit.available():
        pytest.fail("numba is a runtime dependency: the compiled kernels must be available")
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


def test_that_warm_up_loads_every_registered_kernel():
    jit.warm_up()
    for compiled in jit._REGISTERED:
        assert compiled.cache_info().currsize == 1


def test_that_a_numba_that_does_not_import_leaves_the_numpy_code_with_the_same_answers(monkeypatch, caplog):
    from companion.core import overlap

    rng = np.random.default_rng(5)
    q = np.linalg.qr(rng.standard_normal((8, 3, 3)))[0]
    covs = np.einsum("nij,nj,nkj->nik", q, 10.0 ** rng.uniform(-2, 2, (8, 3)), q)
    mu1, mu2 = rng.standard_normal((4, 3)), rng.standard_normal((4, 3)) * 3.0
    compiled = overlap.minmax(mu1, covs[:4], mu2, covs[4:])
    v, v0, vmax, da = rng.normal(0.0, 3.0, (6, 3)), np.zeros(3), np.full(3, 2.0), np.full(3, 0.6)
    jit.available.cache_clear()
    monkeypatch.setitem(sys.modules, "numba", None)    # "import numba" now raises ImportError
    try:
        assert not jit.available()
        assert "numba does not import" in caplog.text
        jit.warm_up()                                  # a no-op, not an error
        fallback = overlap.minmax(mu1, covs[:4], mu2, covs[4:])
    finally:
        monkeypatch.undo()
        jit.available.cache_clear()
    assert jit.available()
    for field in ("lam", "eta", "alpha", "beta", "normal", "s1", "s2"):
        np.testing.assert_allclose(getattr(fallback, field), getattr(compiled, field), rtol=1e-12, atol=1e-15,
                                   err_msg=field)
    python = v.copy()
    scp._project_forward.py_func(python, v0, vmax, da)     # the projection's fallback is its Python original
    np.testing.assert_array_equal(python, _clip_reference(v, v0, vmax, da))


@pytest.mark.parametrize("formulation", ["hyperplane", "paper", "bhattacharyya"])
def test_that_plans_are_the_same_bits_with_and_without_the_compiled_kernels(formulation, monkeypatch):
    from companion.core.planner import Planner
    from tests.core.test_overlap_properties import _libm_transcendentals
    from tests.core.test_planner_scp import scenario_one

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
    jit.available.cache_clear()
    monkeypatch.setattr(jit, "COMPILED", False)     # as without numba: the numpy and Python code
    try:
        assert not jit.available()
        numpy_plans = fly()
    finally:
        monkeypatch.undo()
        jit.available.cache_clear()
    for a, b in zip(compiled, numpy_plans):
        assert a.status == b.status and a.iterations == b.iterations
        for field in ("velocities", "positions", "commands", "eta", "contour_of_touch"):
            assert np.asarray(getattr(a, field)).tobytes() == np.asarray(getattr(b, field)).tobytes(), field
