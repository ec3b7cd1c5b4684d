"""The compiled hot loops (companion.core.jit): each gives its Python original's bits."""

from __future__ import annotations

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
    if not jit.COMPILED:
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
