"""A request's QP constants: the template path gives the whole vectors' values, bit for bit.

:class:`RequestTemplate` keeps what depends on the configuration and the QP shape only,
and :meth:`RequestData.build` fills in the request's parts. Here every field is compared
with the vectors written out whole from the QP's definition (the layout's docstring), as
the planner built them before the template, so a plan cannot move by a bit because of it.
"""

from __future__ import annotations

import contextlib
import dataclasses

import numpy as np
import pytest

from companion.core.planner import Planner, PlannerConfig, PlanRequest
from companion.core.planner.qp_data import RequestData, RequestTemplate
from tests.core.test_jit import _numba_unimportable

N = 12
PX4_LIKE = {"horizontal": {"p_gain_per_s": 1.5, "i_gain_per_s2": 0.3, "drag_per_s": 0.8, "accel_lag_s": 0.2},
            "vertical": {"p_gain_per_s": 3.2, "i_gain_per_s2": 0.1, "drag_per_s": 0.5, "accel_lag_s": 0.02}}
CONFIGS = {
    "hyperplane": dict(),
    "lag": dict(velocity_time_constant_s=0.3),
    "response": dict(vehicle_response=PX4_LIKE),
    "paper, c_max": dict(formulation="paper", c_max=0.99),
    "no progress weight": dict(weight_progress=0.0, c_max=0.99),
    "progress weight": dict(weight_progress=2.0, velocity_time_constant_s=0.3),   # P's stage blocks nonzero
    "sensing range": dict(sensing_range_m=7.0, c_max=0.99, velocity_time_constant_s=0.3),   # the second obstacle out
    # the request's own ranges over the planner's: the first obstacle (6.6 m away) out, the second (9.9 m) in
    "ranges per obstacle": dict(sensing_range_m=7.0, c_max=0.99, velocity_time_constant_s=0.3, ranges=(5.0, np.inf)),
    "ranges per obstacle, response": dict(vehicle_response=PX4_LIKE, ranges=(5.0, 12.0)),
}
#: current velocities: signed zeros, one clipped axis, small and mixed values
VELOCITIES = ([0.0, -0.0, 0.0], [-0.0, 0.7, -0.0], [9.0, -2.5, 0.3], [1e-12, -3e-7, 0.2], [-1.3, 1.7, -0.4])


def whole_vectors(cfg: PlannerConfig, form, layout, request: PlanRequest) -> dict:
    """The constants written out whole: every vector from zeros, as the QP defines it."""
    N_, tau = layout.N, cfg.step_s
    vmax, amax = cfg.velocity_max, cfg.accel_max
    v0 = np.clip(request.velocity, -vmax - amax * tau, vmax + amax * tau)
    m = np.linalg.inv(request.drone_covs[-1])
    m = 0.5 * (m + m.T)
    wt, wj, wv, wp = cfg.weight_terminal, cfg.weight_jerk, cfg.weight_velocity, cfg.weight_progress / N_
    jerk_scale = 2.0 * wj / tau**4
    c = np.zeros((N_ - 1, 3))
    c[0] = v0
    q = np.zeros(layout.n)
    q[layout.col["V"].slice] = (jerk_scale * (layout.d2_t @ c)).ravel()
    q[layout.col["p"].slice] = np.tile(-2.0 * wp * (m @ request.target), N_)
    pn = layout.col["p"].start + 3 * (N_ - 1)
    q[pn:pn + 3] += -2.0 * wt * (m @ request.target)
    for name in ("s_lo", "e_pos", "e_neg", "s_wall"):
        q[layout.col[name].slice] = cfg.slack_penalty * layout.slack_scale
    q[layout.col["s_hi"].slice] = cfg.c_max_penalty * layout.slack_scale
    q_hard = q.copy()
    q_hard[layout.slack_cols[layout.safety_slacks]] = 0.0
    a_slot = layout.a_data0.copy()
    a_slot[layout.slot["wall_p"].slice] = np.broadcast_to(request.walls_normal[:, None, :], (layout.W, N_, 3)).ravel()
    l, u = np.zeros(layout.m), np.zeros(layout.m)
    dyn = layout.lag.free_increments(v0, N_)
    dyn[0] += request.position
    l[layout.row["dyn"].slice] = u[layout.row["dyn"].slice] = dyn.ravel()
    acc = np.broadcast_to(amax * tau, (N_, 3)).copy()
    lo_acc, hi_acc = -acc, acc.copy()
    lo_acc[0] += v0
    hi_acc[0] += v0
    if not layout.lag.bounds_command_steps:
        lo_acc[:], hi_acc[:] = -np.inf, np.inf
    l[layout.row["accel"].slice], u[layout.row["accel"].slice] = lo_acc.ravel(), hi_acc.ravel()
    if layout.row["cmd"].size:
        alpha = layout.lag.alpha
        cmd = np.broadcast_to((1.0 - alpha) * vmax, (N_, 3)).copy()
        lo_cmd, hi_cmd = -cmd, cmd.copy()
        lo_cmd[0] += alpha * v0
        hi_cmd[0] += alpha * v0
        l[layout.row["cmd"].slice], u[layout.row["cmd"].slice] = lo_cmd.ravel(), hi_cmd.ravel()
    l[layout.row["wall"].slice] = -np.inf
    u[layout.row["wall"].slice] = form.wall_upper(request).ravel()
    l[layout.row["slack"].slice], u[layout.row["slack"].slice] = 0.0, np.inf
    # P: the velocity block and the N position blocks concatenated, then permuted into CSC order
    blocks = np.broadcast_to(2.0 * wp * m, (N_, 3, 3)).copy()
    blocks[-1] += 2.0 * wt * m
    tr, tc = layout.p_term_idx
    vel = jerk_scale * layout.p_vel_jerk + 2.0 * wv * layout.p_vel_diag
    p_data = np.concatenate([vel, blocks[:, tr, tc].ravel()])[layout.p_perm]
    ranges = cfg.sensing_range_m if request.obstacle_ranges_m is None else request.obstacle_ranges_m
    in_range = np.linalg.norm(request.obstacle_means[:, 0, :] - request.position, axis=-1) <= ranges
    return dict(v0=v0, p_data=p_data, q=q, q_hard=q_hard,
                a_slot=a_slot, l=l, u=u, in_range=in_range, upper_active=in_range & request.upper_bound_mask,
                constant=(wt + wp * N_) * request.target @ m @ request.target + wj / tau**4 * float(np.sum(c * c)))


def request(velocity, ranges=None) -> PlanRequest:
    steps = np.arange(1, N + 1)[:, None, None]
    drone = np.array([[0.03, 0.004, -0.002], [0.004, 0.02, 0.001], [-0.002, 0.001, 0.015]]) * (1.0 + 0.05 * steps)
    means = np.array([[6.0, -4.0, -5.0], [9.0, 3.0, -4.5]])[:, None] + steps[None, :, :, 0] * np.array([0.0, 0.9, 0.05])
    return PlanRequest(position=[0.3, -0.2, -5.0], velocity=velocity, drone_covs=drone, target=[20.0, 1.0, -5.5],
                       obstacle_means=means, obstacle_covs=np.broadcast_to(0.02 * np.eye(3), (2, N, 3, 3)),
                       obstacle_radii=[0.5, 0.4], walls_normal=[[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]],
                       walls_offset=[6.0, 6.0], obstacle_ranges_m=ranges)


@pytest.mark.parametrize("name", sorted(CONFIGS))
@pytest.mark.parametrize("compiled", [True, False], ids=["compiled", "numpy"])
def test_that_the_template_gives_the_whole_vectors_bit_for_bit(name, compiled):
    """Both forms of build (the compiled pass for a lag model, and numpy's operations without
    numba or for a response model) give the whole vectors' bytes."""
    with contextlib.nullcontext() if compiled else _numba_unimportable():
        _compare_with_whole_vectors(name)


def _compare_with_whole_vectors(name):
    settings = dict(CONFIGS[name])
    ranges = settings.pop("ranges", None)
    cfg = PlannerConfig(horizon_steps=N, step_s=0.3, velocity_max_mps=(3.0, 3.0, 1.0),
                        accel_max_mps2=(2.0, 2.0, 1.0), **settings)
    planner = Planner(cfg)
    for velocity in VELOCITIES:
        req = request(velocity, ranges)
        planner.solve(req)                                  # makes the workspace of this shape
        ws = planner.workspaces[(N, req.num_obstacles, req.num_walls)]
        data = RequestData.build(ws.template, planner.formulation, req)
        want = whole_vectors(cfg, planner.formulation, ws.layout, req)
        for field, value in want.items():
            got = getattr(data, field)
            assert np.asarray(got).tobytes() == np.asarray(value).tobytes(), (name, velocity, field)
        # every value is the same, down to the sign of its zeros (the jerk rows of a zero V_0)
        assert np.signbit(data.q).tolist() == np.signbit(want["q"]).tolist()


def test_that_the_template_is_read_only_and_each_request_gets_its_own_vectors():
    cfg = PlannerConfig(horizon_steps=N, step_s=0.3)
    planner = Planner(cfg)
    req = request([1.0, 0.0, 0.0])
    planner.solve(req)
    template: RequestTemplate = planner.workspaces[(N, 2, 2)].template
    for vec in (template.q, template.q_hard, template.l, template.u):
        with pytest.raises(ValueError):
            vec[0] = 1.0
    first = RequestData.build(template, planner.formulation, req)
    second = RequestData.build(template, planner.formulation, request([-1.0, 0.5, 0.0]))
    assert not np.shares_memory(first.q, template.q) and not np.shares_memory(first.l, second.l)
    for data in (first, RequestData.build(template, planner.formulation, req, y_warm=np.zeros(template.layout.m))):
        arrays = [f.name for f in dataclasses.fields(data) if isinstance(getattr(data, f.name), np.ndarray)]
        assert "y_warm" in arrays or data is first
        for name in arrays:          # every array of the request's constants, a new field too, is read-only
            assert not getattr(data, name).flags.writeable, name
    assert not template.q_slack.flags.writeable
    assert first.l[planner.layout((N, 2, 2)).row["accel"].start] != second.l[planner.layout((N, 2, 2)).row["accel"].start]


@pytest.mark.parametrize("compiled", [True, False], ids=["compiled", "numpy"])
def test_that_random_velocities_give_the_whole_vectors_bit_for_bit(compiled):
    with contextlib.nullcontext() if compiled else _numba_unimportable():
        _compare_random_velocities()


def _compare_random_velocities():
    # the cost constant adds |V_0|^2 (scaled) to a larger term, which absorbs most rounding
    # differences: many velocities are needed before a different order of the sum shows
    cfg = PlannerConfig(horizon_steps=N, step_s=0.3, velocity_max_mps=(3.0, 3.0, 1.0), accel_max_mps2=(2.0, 2.0, 1.0),
                        velocity_time_constant_s=0.3)
    planner = Planner(cfg)
    planner.solve(request([0.0, 0.0, 0.0]))
    ws = planner.workspaces[(N, 2, 2)]
    rng = np.random.default_rng(7)
    for velocity in rng.uniform(-1.0, 1.0, (2000, 3)) * [3.5, 3.5, 1.2]:
        req = request(velocity)
        data = RequestData.build(ws.template, planner.formulation, req)
        want = whole_vectors(cfg, planner.formulation, ws.layout, req)
        for field, value in want.items():
            assert np.asarray(getattr(data, field)).tobytes() == np.asarray(value).tobytes(), (velocity, field)
