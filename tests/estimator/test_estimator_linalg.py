"""estimator.linalg.inverse: np.linalg.inv's bits and errors without its Python layer."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from estimator import ObstacleTracker, TrackerConfig
from estimator.linalg import DIRECT, inverse


def _spd(rng: np.random.Generator, shape: tuple[int, ...], n: int) -> np.ndarray:
    a = rng.standard_normal(shape + (n, n)) * 10.0 ** rng.uniform(-3, 2)
    return a @ np.swapaxes(a, -1, -2) + 1e-6 * np.eye(n)


def test_that_the_direct_call_is_the_one_numpy_makes():
    if not DIRECT:
        pytest.skip("this numpy has no numpy.linalg._umath_linalg.inv: inverse() is np.linalg.inv")
    rng = np.random.default_rng(3)
    for _ in range(2000):
        n = int(rng.integers(1, 7))
        shape = () if rng.random() < 0.7 else tuple(int(k) for k in rng.integers(1, 4, size=int(rng.integers(1, 3))))
        s = _spd(rng, shape, n)
        if rng.random() < 0.3:    # a non-contiguous view
            s = np.swapaxes(s, -1, -2)
        assert inverse(s).tobytes() == np.linalg.inv(s).tobytes()


@pytest.mark.parametrize("singular", [
    np.zeros((3, 3)),
    np.ones((3, 3)),
    np.stack([np.eye(3), np.zeros((3, 3)), np.eye(3)]),
])
def test_that_a_singular_matrix_raises_as_numpy_does(singular):
    with pytest.raises(np.linalg.LinAlgError, match="Singular matrix"):
        np.linalg.inv(singular)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)    # numpy warns first on the direct call (documented)
        with pytest.raises(np.linalg.LinAlgError, match="Singular matrix"):
            inverse(singular)


@pytest.mark.parametrize("a", [
    np.full((3, 3), np.nan),
    np.eye(3, dtype=np.float32) * 2.0,
    np.eye(3, dtype=int),
    np.zeros((0, 0)),
    np.zeros((2, 0, 0)),
    np.matrix([[2.0, 0.5], [0.5, 1.0]]),
])
def test_that_other_inputs_get_what_np_linalg_inv_gives(a):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        want, got = np.linalg.inv(a), inverse(a)
    assert type(got) is type(want) and got.dtype == want.dtype and got.shape == want.shape
    assert got.tobytes() == want.tobytes()


def test_that_a_track_fuses_the_same_bits_with_numpys_inverse():
    rng = np.random.default_rng(5)
    trackers = [ObstacleTracker(TrackerConfig()) for _ in range(2)]
    for k in range(200):
        z = np.array([1.0, -2.0, -5.0]) + 0.3 * k * np.array([0.5, 0.2, 0.0]) + 0.1 * rng.standard_normal(3)
        v = None if k % 3 else np.array([0.15, 0.06, 0.0]) + 0.05 * rng.standard_normal(3)
        cov = np.diag(rng.uniform(0.005, 0.05, 3))
        for i, tr in enumerate(trackers):
            tr.update("a", 0.1 * k, z, v, cov, None if v is None else 0.01 * np.eye(3))
            if i == 1 and k == 0:
                tr._tracks["a"].kf.inv = np.linalg.inv      # the filter of record's own default
    a, b = (tr.state("a") for tr in trackers)
    assert trackers[0]._tracks["a"].kf.inv is inverse
    assert a.mean.tobytes() == b.mean.tobytes() and a.cov.tobytes() == b.cov.tobytes()
