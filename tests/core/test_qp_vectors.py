"""An SCP iteration's writes into its QP and reads from its solution (companion.core.planner.qp_vectors):
the compiled passes give numpy's bytes, and mean what they say."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.core import jit
from companion.core.planner.formulations import ObstacleRows
from companion.core.planner.qp_layout import QpLayout
from companion.core.planner.qp_vectors import read_solution, write_rows
from companion.core.planner.vehicle_model import model_from_config
from tests.core.test_jit import _numba_unimportable, _require_compiled


def _layout(rng: np.random.Generator, upper: bool) -> QpLayout:
    N, P, W = int(rng.integers(1, 12)), int(rng.integers(0, 5)), int(rng.integers(0, 3))
    lag = model_from_config(0.3, float(rng.choice([0.0, 0.3])), None)
    return QpLayout(N, P, W, paper=False, upper=upper, step_s=0.3, lag=lag)


def _signed(rng: np.random.Generator, shape: tuple[int, ...], scale: float) -> np.ndarray:
    """Random values with some signed zeros and infinities."""
    a = rng.normal(0.0, scale, shape)
    pick = rng.random(shape)
    a[pick < 0.1] = 0.0
    a[(pick >= 0.1) & (pick < 0.2)] = -0.0
    a[(pick >= 0.2) & (pick < 0.25)] = np.inf
    a[(pick >= 0.25) & (pick < 0.3)] = -np.inf
    return a


def _case(rng: np.random.Generator, layout: QpLayout):
    """Rows, masks, an iterate with ties against the box (signed zeros too) and NaN, the box (NaN
    too), the trust radius."""
    P, N = layout.P, layout.N
    rows = ObstacleRows(coef_p=_signed(rng, (P, N, 3), 1.0), lower=_signed(rng, (P, N), 5.0),
                        upper=_signed(rng, (P, N), 5.0))
    in_range, upper_active = rng.random(P) < 0.7, rng.random(P) < 0.5
    trust = float(rng.choice([0.5, 1.0]))
    v_low, v_high = rng.choice([-3.0, -0.0, 0.0, -1.0, np.nan], 3), rng.choice([3.0, 0.0, -0.0, 1.0, np.nan], 3)
    v_bar = rng.normal(0.0, 2.0, (N, 3))
    tie = rng.random((N, 3))
    v_bar[tie < 0.15] = trust                               # v_bar - trust = +0 against a zero bound
    v_bar[(tie >= 0.15) & (tie < 0.3)] = -trust             # v_bar + trust = +0 likewise
    v_bar[(tie >= 0.3) & (tie < 0.4)] = (v_low + trust)[np.nonzero((tie >= 0.3) & (tie < 0.4))[1]]
    v_bar[(tie >= 0.4) & (tie < 0.45)] = np.nan
    return rows, in_range, upper_active, v_bar, trust, v_low, v_high


def _written(layout: QpLayout, case, seed: int):
    """The QP's vectors after :func:`write_rows` from the same start (random, so untouched entries count too)."""
    rng = np.random.default_rng(seed)
    a_slot, l, u = rng.normal(size=layout.a_data0.size), rng.normal(size=layout.m), rng.normal(size=layout.m)
    v_lo, v_hi = write_rows(layout, *case[:2], case[2], case[3], case[4], case[5], case[6], a_slot, l, u)
    return [a.tobytes() for a in (a_slot, l, u, v_lo, v_hi)]


@settings(max_examples=60, deadline=None, derandomize=True)
@given(st.integers(0, 2**32 - 1), st.booleans())
def test_that_the_compiled_writes_give_numpys_bytes(seed, upper):
    """Obstacle rows (inactive out of range, c_max released where masked), the velocity box with
    numpy's maximum and minimum (ties give the second operand, NaN propagates) and the slack
    bounds: every byte of A's slots, l, u and the box the same from the compiled pass and numpy."""
    _require_compiled()
    rng = np.random.default_rng(seed)
    layout = _layout(rng, upper)
    case = _case(rng, layout)
    compiled = _written(layout, case, seed)
    with _numba_unimportable():
        assert not jit.available()
        reference = _written(layout, case, seed)
    assert compiled == reference


def test_that_the_writes_make_out_of_range_rows_inactive_and_pin_the_safety_slacks():
    """What the writes mean, on a small case: an obstacle out of range has zero coefficients and
    (-inf, inf) bounds; c_max is released where it does not apply; safety slacks are pinned to 0
    and the c_max slack is free; the box is the bounds within the trust radius of the iterate."""
    layout = QpLayout(2, 2, 1, paper=False, upper=True, step_s=0.3, lag=model_from_config(0.3, 0.0, None))
    rows = ObstacleRows(coef_p=np.full((2, 2, 3), 0.5), lower=np.full((2, 2), 1.0), upper=np.full((2, 2), 2.0))
    a_slot, l, u = np.zeros(layout.a_data0.size), np.zeros(layout.m), np.zeros(layout.m)
    v_bar = np.array([[0.0, 2.5, -1.0], [1.0, 1.0, 1.0]])
    v_lo, v_hi = write_rows(layout, rows, np.array([True, False]), np.array([False, True]), v_bar, 1.0,
                            np.full(3, -3.0), np.full(3, 3.0), a_slot, l, u)
    obs_p = a_slot[layout.slot["obs_p"].slice].reshape(2, 2, 3)
    assert np.all(obs_p[0] == 0.5) and np.all(obs_p[1] == 0.0)
    obs_l, obs_u = l[layout.row["obs"].slice].reshape(2, 2), u[layout.row["obs"].slice].reshape(2, 2)
    assert np.all(obs_l[0] == 1.0) and np.all(obs_l[1] == -np.inf) and np.all(obs_u == np.inf)
    hi_l, hi_u = l[layout.row["obs_hi"].slice], u[layout.row["obs_hi"].slice].reshape(2, 2)
    assert np.all(hi_l == -np.inf) and np.all(hi_u == np.inf)    # obstacle 0: masked; 1: out of range
    np.testing.assert_array_equal(v_lo, [[-1.0, 1.5, -2.0], [0.0, 0.0, 0.0]])
    np.testing.assert_array_equal(v_hi, [[1.0, 3.0, 0.0], [2.0, 2.0, 2.0]])
    slack_u = u[layout.row["slack"].slice]
    safety = np.zeros(slack_u.size, dtype=bool)
    safety[layout.safety_slacks] = True
    assert np.all(slack_u[safety] == 0.0) and np.all(slack_u[~safety] == np.inf) and (~safety).any()


@pytest.mark.parametrize("upper", [False, True])
def test_that_the_writes_leave_the_rest_of_the_qp_alone(upper):
    """Entries outside the obstacle rows, the box and the slack rows keep what they held."""
    rng = np.random.default_rng(3)
    layout = QpLayout(4, 2, 2, paper=False, upper=upper, step_s=0.3, lag=model_from_config(0.3, 0.3, None))
    case = _case(rng, layout)
    a_slot, l, u = rng.normal(size=layout.a_data0.size), rng.normal(size=layout.m), rng.normal(size=layout.m)
    before = a_slot.copy(), l.copy(), u.copy()
    write_rows(layout, *case[:2], case[2], case[3], case[4], case[5], case[6], a_slot, l, u)
    touched_slots = np.zeros(a_slot.size, dtype=bool)
    touched_slots[layout.slot["obs_p"].slice] = True
    rows_l, rows_u = np.zeros(layout.m, dtype=bool), np.zeros(layout.m, dtype=bool)
    for name in ("obs", "vbox") + (("obs_hi",) if upper else ()):
        rows_l[layout.row[name].slice] = rows_u[layout.row[name].slice] = True
    if upper:
        touched_slots[layout.slot["obs_hi_p"].slice] = True
    rows_u[layout.row["slack"].slice] = True
    np.testing.assert_array_equal(a_slot[~touched_slots], before[0][~touched_slots])
    np.testing.assert_array_equal(l[~rows_l], before[1][~rows_l])
    np.testing.assert_array_equal(u[~rows_u], before[2][~rows_u])


def _solution(rng: np.random.Generator, layout: QpLayout) -> np.ndarray:
    """A solution vector with negative, signed-zero, infinite and NaN entries, slack columns included."""
    x = _signed(rng, (layout.n,), 1.0)
    x[rng.random(layout.n) < 0.03] = np.nan
    return x


@settings(max_examples=60, deadline=None, derandomize=True)
@given(st.integers(0, 2**32 - 1), st.booleans(), st.booleans())
def test_that_the_compiled_reading_gives_numpys_bytes(seed, upper, paper):
    """The solution with its slacks clipped at 0, the clipped slacks, the slacks per row scaled by
    the layout's slack scale, the largest safety slack (NaN, ties of +0 and -0, none at all) and the
    largest velocity change from the iterate: the same bytes from the compiled pass and numpy."""
    _require_compiled()
    rng = np.random.default_rng(seed)
    N, P, W = int(rng.integers(1, 12)), int(rng.integers(0, 5)), int(rng.integers(0, 3))
    layout = QpLayout(N, P, W, paper=paper, upper=upper, step_s=0.3, lag=model_from_config(0.3, 0.0, None),
                      slack_scale=float(rng.choice([1.0, 0.25])))
    x = _solution(rng, layout)
    if rng.random() < 0.3:       # slacks at or below zero: the largest is a zero or negative, or NaN
        x[layout.slack_cols] = rng.choice([0.0, -0.0, -1e-9, -2.0, np.nan], layout.slack_cols.size,
                                          p=[0.3, 0.3, 0.2, 0.15, 0.05])
    in_range = rng.random(P) < 0.7
    v_bar = x[layout.col["V"].slice].reshape(N, 3) + rng.choice([0.0, -0.0, 1e-3, -2.0], (N, 3))
    v_bar[rng.random((N, 3)) < 0.02] = np.nan

    def read():
        with np.errstate(invalid="ignore"):         # inf - inf in numpy's velocity change: NaN, as compiled
            *arrays, largest, moved = read_solution(layout, x, in_range, v_bar)
        return [a.tobytes() for a in arrays] + [np.float64(largest).tobytes(), np.float64(moved).tobytes()]

    compiled = read()
    with _numba_unimportable():
        reference = read()
    assert compiled == reference


def test_that_the_reading_clips_only_the_slacks():
    """``xc`` is ``x`` except at the slack columns, which are ``max(x, 0)`` (-0 becomes +0); the
    slacks per row are the columns times the slack scale; ``s_hi`` is zero without c_max rows; the
    largest safety slack leaves out obstacles out of range; the velocity change is the largest."""
    layout = QpLayout(3, 2, 1, paper=False, upper=False, step_s=0.3, lag=model_from_config(0.3, 0.0, None),
                      slack_scale=0.5)
    x = np.linspace(-1.0, 1.0, layout.n)
    x[layout.slack_cols[0]] = -0.0
    v_bar = x[layout.col["V"].slice].reshape(3, 3) + np.array([[0.0, 0.2, 0.0], [-0.5, 0.0, 0.1], [0.0, 0.0, 0.0]])
    xc, xs, s_lo, s_hi, s_wall, largest, moved = read_solution(layout, x, np.array([True, False]), v_bar)
    other = np.ones(layout.n, dtype=bool)
    other[layout.slack_cols] = False
    np.testing.assert_array_equal(xc[other], x[other])
    np.testing.assert_array_equal(xs, np.maximum(x[layout.slack_cols], 0.0))
    assert not np.signbit(xs[0]) and xc[layout.slack_cols[0]] == 0.0
    np.testing.assert_array_equal(s_lo, 0.5 * x[layout.col["s_lo"].slice].reshape(2, 3))
    np.testing.assert_array_equal(s_wall, 0.5 * x[layout.col["s_wall"].slice].reshape(1, 3))
    assert s_hi.shape == (2, 3) and not s_hi.any()
    assert largest == max(s_lo[0].max(), s_wall.max())      # obstacle 1 is out of range
    assert moved == 0.5
