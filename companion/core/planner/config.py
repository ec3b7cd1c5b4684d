"""Planner configuration: a frozen, validated dataclass read from a ``[planner]`` table.

Units are in the field names (NED frame, metres, seconds). Every value is checked on
construction; a bad value raises :class:`companion.errors.ConfigError` naming the key and
the value, and :meth:`PlannerConfig.from_toml_table` adds the file and section.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from companion import validation as check
from companion.core.planner.vehicle_model import AxisResponse
from companion.errors import ConfigError

logger = logging.getLogger(__name__)

#: Selectable collision formulations (docs/METHOD.md section 2.6). ``hyperplane`` and ``paper`` bound
#: the overlap of Gaussians; ``deterministic`` and ``bhattacharyya`` are baselines.
FORMULATIONS: tuple[str, ...] = ("hyperplane", "paper", "deterministic", "bhattacharyya")

#: Selectable QP backends (docs/SOLVERS.md): OSQP (ADMM, warm-started) and PIQP (proximal
#: interior point; :mod:`companion.core.planner.piqp_qp`).
SOLVERS: tuple[str, ...] = ("osqp", "piqp")

#: Smallest ``replan_work_budget``: one QP solve plus a few dozen ADMM iterations.
MIN_WORK_BUDGET = 200

#: Spatial dimension of the planner (3-D NED); the overlap module also handles 2-D.
DIM = 3


#: Largest accepted ``horizon_steps`` and ``scp_max_iterations`` / ``solver_max_iter``: a
#: scenario file may not make one replan allocate or iterate without bound.
MAX_HORIZON_STEPS = 400
MAX_SCP_ITERATIONS = 100
MAX_SOLVER_ITERATIONS = 100_000
#: Largest ``replan_work_budget`` (ADMM iterations summed over a replan's QPs).
MAX_WORK_BUDGET = 10_000_000
#: Physical bounds of a multirotor, checked so that a typo flies nothing: the longest
#: ``step_s`` and ``replan_period_s`` (s; a velocity command held longer than this is not
#: a plan a vehicle can follow between obstacles: the shipped scenarios use 0.3 s, the
#: paper's scenario 1 1.0 s), the largest per-axis speed (m/s; fast racing quadrotors
#: reach 30 m/s, PX4's MPC_XY_VEL_MAX default is 12) and acceleration (m/s^2, about 2 g;
#: PX4's MPC_ACC_HOR_MAX is at most 15).
MAX_STEP_S = 5.0
MAX_SPEED_MPS = 30.0
MAX_ACCEL_MPS2 = 20.0


def _axis_vector(name: str, value: Any, hi: float | None = None, unit: str = "") -> tuple[float, float, float]:
    shown = list(value) if isinstance(value, tuple) else value
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value] * DIM
    arr = check.vector3(name, value, positive=True)
    if hi is not None and np.any(arr > hi):
        raise ConfigError(f"{name} = {shown!r} must be at most {hi:g} {unit} on every axis (a multirotor's)".rstrip())
    return (float(arr[0]), float(arr[1]), float(arr[2]))


def _vehicle_response(value: Any) -> tuple[AxisResponse, AxisResponse]:
    """``(horizontal, vertical)`` from a pair of AxisResponse or a table with those two keys."""
    if isinstance(value, Mapping):
        unknown = sorted(set(value) - {"horizontal", "vertical"})
        if unknown or set(value) != {"horizontal", "vertical"}:
            raise ConfigError(f"vehicle_response needs exactly the tables horizontal and vertical, got {sorted(value)}")
        return tuple(v if isinstance(v, AxisResponse) else AxisResponse.from_mapping(v, f"vehicle_response.{k}")
                     for k, v in ((k, value[k]) for k in ("horizontal", "vertical")))  # type: ignore[return-value]
    if isinstance(value, tuple) and len(value) == 2 and all(isinstance(v, AxisResponse) for v in value):
        return value
    raise ConfigError(f"vehicle_response must be a table with horizontal and vertical, got {value!r}")


@dataclass(frozen=True)
class PlannerConfig:
    """Configuration of the overlap-constrained MPC (docs/METHOD.md section 2).

    Parameters
    ----------
    formulation : str
        ``hyperplane`` (minmax normal per iterate, one row per obstacle and step),
        ``paper`` (joint ``(V, lam)`` with linearised overlap and admissibility),
        ``deterministic`` (means and radii only) or ``bhattacharyya`` (threshold on the
        Bhattacharyya distance).
    horizon_steps : int
        Number of velocity commands ``N``.
    step_s : float
        Duration ``tau`` each command is held, seconds, at most :data:`MAX_STEP_S` (5 s).
    replan_period_s : float
        Receding-horizon replanning period, seconds (used by the control loop only), at most 5 s.
    c_min : float
        Lower bound on the confidence contour of touch, in (0, 1). Maps to
        ``r_min = sqrt(chi2_3.ppf(c_min))`` and the overlap bound ``Y_max``.
    c_max : float or None
        Optional upper bound (corridor case: the ``c_max`` contours keep touching);
        must exceed ``c_min``. Enforced softly, only for obstacles within sensing range.
    velocity_max_mps : (3,) floats
        Per-axis speed bound (north, east, down), m/s: ``-v_max <= V <= v_max``; at most
        :data:`MAX_SPEED_MPS` (30 m/s).
    accel_max_mps2 : (3,) floats
        Per-axis acceleration bound, m/s^2: ``|V_i - V_{i-1}| <= a_max * tau``
        (``V_0`` is the current velocity); at most :data:`MAX_ACCEL_MPS2` (20 m/s^2), as is
        ``accel_emergency_mps2``.
    accel_emergency_mps2 : (3,) floats or None
        Per-axis acceleration bound of the least-violation QPs, m/s^2 (at least
        ``accel_max_mps2``): when no plan within ``accel_max_mps2`` keeps every safety
        row, the replan may brake or swerve up to this before it gives up safety (slack).
        ``accel_max_mps2`` is a comfort and tracking bound well inside what the vehicle
        can do; safety outranks it. ``None`` (the default): the least-violation QPs keep
        ``accel_max_mps2``. Bounds the velocity-lag and instantaneous models only (with a
        ``vehicle_response`` the autopilot limits acceleration and there are no such rows).
    velocity_time_constant_s : float
        Time constant ``T`` of the vehicle's first-order velocity response to a velocity
        setpoint, seconds (:mod:`companion.core.planner.vehicle_model`). 0 (default) is the
        paper's model: the velocity follows the command at once. With ``T > 0`` the plan's
        velocities are the vehicle's and the streamed commands lead them.
    vehicle_response : (AxisResponse, AxisResponse) or None
        The vehicle's (horizontal, vertical) velocity response to a setpoint, e.g. identified
        with ``companion identify`` (:class:`~companion.core.planner.vehicle_model.AxisResponse`).
        When given it replaces ``velocity_time_constant_s`` and the plan's velocities are the
        commands. In TOML: ``[planner.vehicle_response]`` with tables ``horizontal`` and
        ``vertical`` of ``p_gain_per_s``, ``i_gain_per_s2``, ``drag_per_s``, ``accel_lag_s``.
    drone_radius_m : float
        Physical radius of the drone, metres.
    sensing_range_m : float
        Obstacles whose mean at the first step is farther than this from the drone's
        current position are ignored (their rows are relaxed). ``inf`` disables it.
    weight_terminal : float
        Weight of the terminal Mahalanobis cost ``(p_N - g)' S_N^-1 (p_N - g)``.
    weight_jerk : float
        Weight of the jerk cost ``sum |(V_{i+1} - 2 V_i + V_{i-1}) / tau^2|^2``, s^6/m^2.
    weight_progress : float
        Weight of the progress cost ``(1/N) sum_i (p_i - g)' S_N^-1 (p_i - g)`` (same metric
        as the terminal cost): the drone gets to the target promptly instead of closing in
        asymptotically. 0 gives the paper's terminal-only cost.
    weight_velocity : float
        Weight of a small effort term ``sum |V_i|^2`` (regularisation), s^2/m^2.
    slack_penalty : float
        L1 penalty on every safety slack (obstacle rows in their own units, walls in
        metres); large so slack is used only when the constraints cannot all hold.
    c_max_penalty : float
        L1 penalty on the ``c_max`` slack (metres for ``hyperplane``). ``c_max`` is a
        performance bound, not a safety one, so it is priced well below ``slack_penalty``:
        an unreachable ``c_max`` then bends the plan towards the obstacle without fighting
        the safety rows (with the safety penalty the SCP oscillated, measured).
    scp_tolerance : float
        Convergence when the cost changes by less than ``scp_tolerance * max(1, |J|)``
        between SCP iterations (and the step is small).
    scp_tolerance_warm : float
        The same for a replan warm-started from the previous plan (receding horizon): it
        refines a solution the next replan continues from, so it stops earlier. Measured
        on the planner benchmark: 5e-3 instead of 1e-3 cut the p99 replan time from
        23 ms to 12 ms (at most 5 SCP iterations instead of 14) with the same smallest
        contour of touch; a cold start keeps the tighter ``scp_tolerance`` (with 5e-3 a
        cold ``paper`` plan under ``c_max`` stopped before its contours touched).
    scp_max_iterations : int
        Cap on SCP iterations (QP solves) per plan.
    trust_region_mps : float
        Box trust region on each velocity component around the previous iterate, m/s.
    trust_region_lam : float
        Box trust region on the overlap parameters ``lam`` (``paper`` only).
    solver : str
        The QP backend: ``osqp`` (the default; ADMM, warm-started from the previous QP) or
        ``piqp`` (proximal interior point, no warm start; a flatter time per QP, docs/SOLVERS.md).
    solver_eps : float
        ``eps_abs`` of the backend (its primal and dual residual tolerance).
    solver_eps_rel : float
        ``eps_rel`` of the backend. The dual tolerance is ``eps_abs + eps_rel * max(|Px|, |A'y|, |q|)``;
        when the slack penalty sits in ``q`` (soft re-solve only, see ``scp``) it loosens
        with the penalty. The rows carry a back-off (``formulations.BACKOFF_SIGMA``) that
        covers the primal tolerance, so returned plans meet ``c_min`` exactly.
    solver_polish : bool
        Whether OSQP polishes its solution (active-set refinement; OSQP only).
    solver_max_iter : int
        Work units (ADMM iterations for OSQP; PIQP's iterations cost
        :data:`companion.core.planner.piqp_qp.WORK_PER_ITERATION` each) allowed to the hard QP and to each least-violation QP before the
        planner moves on (the last-resort soft QP gets 10,000). Unscaled OSQP took 10,000
        iterations without declaring an infeasible hard QP infeasible (measured in closed
        loop); warm-started hard QPs that solve need a few hundred, cold ones about a
        thousand (planner benchmark). Tighter ``solver_eps`` needs more.
    solver_rho : float
        OSQP's initial ADMM step size (OSQP only), restored before every QP of the SCP (see
        :mod:`companion.core.planner.osqp_qp`, which gives why 0.4).
    replan_work_budget : int
        Compute budget of one replan in work units, never wall time, so a replan's
        result does not depend on the machine: one unit per ADMM iteration, summed over
        every QP of the replan (hard, least-slack, capped and last-resort soft QPs), plus
        :data:`companion.core.planner.budget.QP_SOLVE_WORK` units per QP solved (its
        linearisation, update, factorisation and exact recheck, which grow with the SCP
        iterations). When it runs out the planner returns its best safe iterate or fails
        (status ``'failed'``: the loop brakes). The default keeps the largest replan of
        the shipped scenes well under the 0.3 s replan period (docs/PLANNER_BUDGET.md).
    """

    formulation: str = "hyperplane"
    horizon_steps: int = 28
    step_s: float = 0.3
    replan_period_s: float = 0.3
    c_min: float = 0.90
    c_max: float | None = None
    velocity_max_mps: tuple[float, float, float] = (3.0, 3.0, 1.0)
    accel_max_mps2: tuple[float, float, float] = (0.5, 0.5, 0.5)
    accel_emergency_mps2: tuple[float, float, float] | None = None
    velocity_time_constant_s: float = 0.0
    vehicle_response: tuple[AxisResponse, AxisResponse] | None = None
    drone_radius_m: float = 0.5
    sensing_range_m: float = 10.0
    weight_terminal: float = 1.0
    weight_jerk: float = 0.05
    weight_velocity: float = 0.1
    weight_progress: float = 0.0
    slack_penalty: float = 1e3
    c_max_penalty: float = 100.0
    scp_tolerance: float = 1e-3
    scp_tolerance_warm: float = 5e-3
    scp_max_iterations: int = 15
    trust_region_mps: float = 1.0
    trust_region_lam: float = 0.25
    solver: str = "osqp"
    solver_eps: float = 1e-4
    solver_eps_rel: float = 1e-4
    solver_polish: bool = False
    solver_max_iter: int = 2000
    solver_rho: float = 0.4
    replan_work_budget: int = 12000

    def __post_init__(self) -> None:
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        check.choice("formulation", self.formulation, FORMULATIONS)
        check.choice("solver", self.solver, SOLVERS)
        set_("horizon_steps", check.integer("horizon_steps", self.horizon_steps, lo=2, hi=MAX_HORIZON_STEPS))
        for name in ("step_s", "replan_period_s"):
            value = check.number(name, getattr(self, name), positive=True)
            if value > MAX_STEP_S:
                raise ConfigError(f"{name} = {getattr(self, name)!r} must be at most {MAX_STEP_S:g} s")
            set_(name, value)
        for name in ("weight_terminal", "slack_penalty", "c_max_penalty", "scp_tolerance",
                     "scp_tolerance_warm", "trust_region_mps", "trust_region_lam", "solver_eps", "solver_rho"):
            set_(name, check.number(name, getattr(self, name), positive=True))
        for name in ("velocity_time_constant_s", "drone_radius_m", "weight_jerk", "weight_velocity", "weight_progress",
                     "solver_eps_rel"):
            set_(name, check.number(name, getattr(self, name), lo=0.0))
        set_("sensing_range_m", check.number("sensing_range_m", self.sensing_range_m, positive=True, allow_inf=True))
        set_("c_min", check.number("c_min", self.c_min, positive=True, below=1.0))
        if self.c_max is not None:
            set_("c_max", check.number("c_max", self.c_max, positive=True, below=1.0))
            if self.c_max <= self.c_min:
                raise ConfigError(f"c_max = {self.c_max!r} must be greater than c_min = {self.c_min!r}")
        set_("velocity_max_mps", _axis_vector("velocity_max_mps", self.velocity_max_mps, MAX_SPEED_MPS, "m/s"))
        set_("accel_max_mps2", _axis_vector("accel_max_mps2", self.accel_max_mps2, MAX_ACCEL_MPS2, "m/s^2"))
        if self.accel_emergency_mps2 is not None:
            set_("accel_emergency_mps2", _axis_vector("accel_emergency_mps2", self.accel_emergency_mps2,
                                                      MAX_ACCEL_MPS2, "m/s^2"))
            if any(e < a for e, a in zip(self.accel_emergency_mps2, self.accel_max_mps2)):
                raise ConfigError(f"accel_emergency_mps2 = {list(self.accel_emergency_mps2)} must be at least "
                                  f"accel_max_mps2 = {list(self.accel_max_mps2)} on every axis")
        set_("scp_max_iterations", check.integer("scp_max_iterations", self.scp_max_iterations, lo=1, hi=MAX_SCP_ITERATIONS))
        set_("solver_max_iter", check.integer("solver_max_iter", self.solver_max_iter, lo=1, hi=MAX_SOLVER_ITERATIONS))
        check.boolean("solver_polish", self.solver_polish)
        if self.vehicle_response is not None:
            set_("vehicle_response", _vehicle_response(self.vehicle_response))
        set_("replan_work_budget", check.integer("replan_work_budget", self.replan_work_budget, lo=MIN_WORK_BUDGET,
                                                 hi=MAX_WORK_BUDGET))

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        """Names accepted as keys of a ``[planner]`` table."""
        return tuple(f.name for f in dataclasses.fields(cls))

    @classmethod
    def from_toml_table(cls, table: Mapping[str, Any], source: str = "[planner]", **overrides: Any) -> PlannerConfig:
        """Build a configuration from a parsed TOML table.

        Parameters
        ----------
        table : mapping
            The ``[planner]`` table (keys are field names; lists become tuples).
        source : str
            Where the table came from, e.g. ``"configs/x.toml [planner]"``; prefixes errors.
        **overrides
            Values that take precedence over the table (e.g. ``drone_radius_m`` from
            ``[vehicle] radius_m``); also checked against the field names.

        Raises
        ------
        ConfigError
            On an unknown key or an invalid value; the message names source, key and value.
        """
        lists_as_tuples = {k: tuple(v) if isinstance(v, list) else v for k, v in check.table(source, table).items()}
        return check.build_section(cls, lists_as_tuples, source, **overrides)

    @property
    def velocity_max(self) -> np.ndarray:
        """Per-axis speed bound as an array (3,), m/s."""
        return np.asarray(self.velocity_max_mps, dtype=float)

    @property
    def accel_max(self) -> np.ndarray:
        """Per-axis acceleration bound as an array (3,), m/s^2."""
        return np.asarray(self.accel_max_mps2, dtype=float)
