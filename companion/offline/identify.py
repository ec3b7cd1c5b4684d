"""Identify the vehicle's velocity response from a flight log (pure fitting, no I/O but the log read).

A tlog holds the velocity setpoints the companion streamed (SET_POSITION_TARGET_LOCAL_NED,
velocity or position + velocity feed-forward) and the vehicle's velocity
(LOCAL_POSITION_NED or ODOMETRY); a PX4 ULog the same as uORB topics
(:mod:`companion.offline.ulog`). Only stretches in OFFBOARD count. The model fitted per
axis group (horizontal: north and east together; vertical) is
:class:`~companion.core.planner.vehicle_model.AxisResponse`, a PI velocity loop with an
acceleration lag against linear drag; the first-order lag is its special case.

Figures of merit, in m/s:

- ``fit_rms``: the model driven by the logged commands from the first velocity of each
  OFFBOARD stretch, open loop, against the measured velocity.
- ``one_step_rms``: from every sample, the velocity one planner step (``horizon_s``,
  default 0.3 s) ahead, predicted from the measured velocity at the sample (the model's
  hidden states from the open-loop run) under the logged commands, against the measured
  velocity then. For a lag model this is the plain prediction from the measured velocity.

Units: seconds, metres, m/s, NED.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from companion.core.planner.vehicle_model import AxisResponse, discretise
from companion.errors import CompanionError
from companion.mavlink import messages
from companion.mavlink.tlog import read_tlog

logger = logging.getLogger(__name__)

#: Resampling period of the identification grid, seconds.
GRID_S = 0.05
#: PX4's default position gains (MPC_XY_P, MPC_Z_P), 1/s: with position + velocity setpoints,
#: the velocity loop's setpoint is ``v_ff + K (p_sp - p)``.
POSITION_GAIN_PER_S = (0.95, 0.95, 1.0)
#: At most this many log messages are read (bounded input).
MAX_MESSAGES = 5_000_000
#: Smallest velocity step (m/s, largest minus smallest command within one OFFBOARD stretch)
#: that each axis group needs for its response to be identified: without one the fit has
#: nothing to fit and returns whatever its start and bounds make of the noise (a log of
#: hover gave K_i 18.8). The identification flight steps by 1 to 3 m/s.
MIN_STEP_MPS = 0.5
#: Bounds of the prediction horizon, seconds: at least one step of the grid, at most a
#: planner step (``[planner] step_s`` is at most 5 s).
HORIZON_RANGE_S = (GRID_S, 5.0)
#: Bounds of the reference lag, seconds.
REFERENCE_LAG_RANGE_S = (0.01, 10.0)


class IdentifyError(CompanionError, ValueError):
    """A log cannot be identified (no OFFBOARD stretch, no setpoints, no velocity); the message names the file."""


def step_sequence() -> list[tuple[float, tuple[float, float, float]]]:
    """Velocity steps to fly for identification: (hold seconds, setpoint NED m/s) in order.

    North 0 -> 1 -> 0 -> 3 -> 0 (8 s each, long enough for PX4's slow horizontal tail),
    east 0 -> 2 -> 0, then up and down at 1 and 2 m/s. About 75 s, 45 m north.
    """
    hold = (0.0, 0.0, 0.0)
    return [
        (3.0, hold),
        (8.0, (1.0, 0.0, 0.0)), (8.0, hold), (8.0, (3.0, 0.0, 0.0)), (8.0, hold),
        (6.0, (0.0, 2.0, 0.0)), (6.0, hold),
        (3.0, (0.0, 0.0, -1.0)), (3.0, hold), (3.0, (0.0, 0.0, 1.0)), (3.0, hold),
        (2.0, (0.0, 0.0, -2.0)), (3.0, hold), (2.0, (0.0, 0.0, 2.0)), (4.0, hold),
    ]


# --------------------------------------------------------------------------- log extraction


@dataclass(frozen=True)
class ResponseLog:
    """Commands and measured velocities on a uniform grid, split into OFFBOARD stretches.

    ``segments`` is a list of ``(t (M,), command (M, 3), velocity (M, 3))`` in seconds
    since the first OFFBOARD sample and NED m/s; ``kinds`` counts the setpoint kinds seen.
    """

    segments: list[tuple[np.ndarray, np.ndarray, np.ndarray]]
    kinds: dict[str, int]

    @property
    def duration_s(self) -> float:
        return float(sum(t[-1] - t[0] for t, _, _ in self.segments))


def load_response_log(path: str | Path, grid_s: float = GRID_S) -> ResponseLog:
    """Read a flight log into OFFBOARD stretches of (command, measured velocity) on a ``grid_s`` grid.

    A tlog, or a PX4 ULog (recognised by its magic ``ULog``; read by
    :func:`companion.offline.ulog.load_ulog_series`, which needs the ``view`` extra).

    Raises
    ------
    IdentifyError
        When the log has no autopilot, no setpoints, no vehicle velocity or no OFFBOARD stretch.
    TlogError
        When the file is neither a ULog nor a tlog.
    """
    path = Path(path)
    from companion.offline.ulog import is_ulog, load_ulog_series

    if is_ulog(path):
        return response_log(path, load_ulog_series(path), grid_s)
    return response_log(path, _tlog_series(path), grid_s)


@dataclass(frozen=True)
class LogSeries:
    """What identification needs from a log, on the log's own clock (seconds).

    ``mode_t``/``mode_off``: the autopilot's mode reports and whether each said armed and in
    OFFBOARD; ``sp_t``/``sp_v``/``sp_p``: the velocity setpoints (NED m/s) and their position
    (NED m, NaN without one); ``vel_t``/``vel``/``pos``: the vehicle's velocity and position;
    ``kinds``: setpoints per kind.
    """

    mode_t: np.ndarray
    mode_off: np.ndarray
    sp_t: np.ndarray
    sp_v: np.ndarray
    sp_p: np.ndarray
    vel_t: np.ndarray
    vel: np.ndarray
    pos: np.ndarray
    kinds: dict


def _tlog_series(path: Path) -> LogSeries:
    """A tlog's HEARTBEATs, SET_POSITION_TARGET_LOCAL_NED and LOCAL_POSITION_NED (or ODOMETRY)."""
    series: dict[str, list] = {"LOCAL_POSITION_NED": [], "ODOMETRY": []}
    sp_t, sp_v, sp_p = [], [], []
    mode_t, mode_off = [], []
    target = None
    kinds = {"velocity": 0, "position+velocity": 0}
    for count, (t, msg) in enumerate(read_tlog(path)):
        if count >= MAX_MESSAGES:
            logger.warning("%s: stopped after %d messages", path, MAX_MESSAGES)
            break
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            hb = messages.decode_heartbeat(msg)
            if hb.is_autopilot and (target is None or hb.key == target):
                target = hb.key
                mode_t.append(t)
                mode_off.append(hb.offboard and hb.armed)
        elif kind == "SET_POSITION_TARGET_LOCAL_NED" and msg.coordinate_frame == messages.MAV_FRAME_LOCAL_NED:
            mask = int(msg.type_mask)
            if mask & (messages.TM_VX | messages.TM_VY | messages.TM_VZ):
                continue                                  # no velocity in it: not a velocity command
            with_pos = not mask & (messages.TM_X | messages.TM_Y | messages.TM_Z)
            kinds["position+velocity" if with_pos else "velocity"] += 1
            sp_t.append(t)
            sp_v.append((msg.vx, msg.vy, msg.vz))
            sp_p.append((msg.x, msg.y, msg.z) if with_pos else (math.nan,) * 3)
        elif kind in ("LOCAL_POSITION_NED", "ODOMETRY") and target is not None and \
                (msg.get_srcSystem(), msg.get_srcComponent()) == target:
            obs = messages.decode_odometry(msg) if kind == "ODOMETRY" else messages.decode_local_position_ned(msg)
            if isinstance(obs, messages.PoseObservation) and obs.velocity_ned is not None:
                series[kind].append((t, obs.velocity_ned, obs.position_ned))
    # one source of velocity (LOCAL_POSITION_NED when the log has it): two would interleave
    samples = series["LOCAL_POSITION_NED"] if len(series["LOCAL_POSITION_NED"]) >= 10 else series["ODOMETRY"]
    if target is None:
        raise IdentifyError(f"{path}: no autopilot HEARTBEAT (PX4 or ArduPilot) in the log")
    if not sp_t:
        raise IdentifyError(f"{path}: no velocity setpoints (SET_POSITION_TARGET_LOCAL_NED, LOCAL_NED) in the log")
    if len(samples) < 10:
        raise IdentifyError(f"{path}: no vehicle velocity (LOCAL_POSITION_NED or ODOMETRY of {target})")
    return LogSeries(np.asarray(mode_t), np.asarray(mode_off, dtype=bool), np.asarray(sp_t),
                     np.asarray(sp_v, dtype=float), np.asarray(sp_p, dtype=float),
                     np.asarray([s[0] for s in samples]), np.asarray([s[1] for s in samples], dtype=float),
                     np.asarray([s[2] for s in samples], dtype=float), kinds)


def response_log(path: Path, series: LogSeries, grid_s: float = GRID_S) -> ResponseLog:
    """Cut ``series`` into OFFBOARD stretches on a ``grid_s`` grid (the setpoints held, the velocity interpolated).

    With a position in a setpoint, the command is PX4's velocity-loop setpoint
    ``v_ff + K (p_sp - p)`` (:data:`POSITION_GAIN_PER_S`).
    """
    mode_t, mode_off = series.mode_t, series.mode_off
    sp_t, sp_v, sp_p = series.sp_t, series.sp_v, series.sp_p
    vel_t, vel, pos = series.vel_t, series.vel, series.pos
    # OFFBOARD stretches from the mode reports (a stretch ends at the first report out of it)
    segments = []
    t_origin = None
    starts = np.flatnonzero(mode_off & ~np.concatenate([[False], mode_off[:-1]]))
    for s in starts:
        e = s
        while e + 1 < len(mode_off) and mode_off[e + 1]:
            e += 1
        t0 = max(mode_t[s], sp_t[0], vel_t[0])
        t1 = min(mode_t[e + 1] if e + 1 < len(mode_t) else mode_t[e], sp_t[-1], vel_t[-1])
        if t1 - t0 < 20 * grid_s:
            continue
        t = np.arange(t0, t1, grid_s)
        idx = np.searchsorted(sp_t, t, side="right") - 1          # latest setpoint (zero-order hold)
        v_meas = np.column_stack([np.interp(t, vel_t, vel[:, k]) for k in range(3)])
        p_meas = np.column_stack([np.interp(t, vel_t, pos[:, k]) for k in range(3)])
        cmd = sp_v[idx].copy()
        with_pos = np.isfinite(sp_p[idx])
        cmd[with_pos] += (np.asarray(POSITION_GAIN_PER_S)[None] * (sp_p[idx] - p_meas))[with_pos]
        t_origin = t0 if t_origin is None else t_origin
        segments.append((t - t_origin, cmd, v_meas))
    if not segments:
        raise IdentifyError(f"{path}: no OFFBOARD stretch with setpoints and vehicle velocity (armed, main mode 6)")
    return ResponseLog(segments, dict(series.kinds))


# --------------------------------------------------------------------------- simulation


def _discrete(axis: AxisResponse, dt: float) -> tuple[np.ndarray, np.ndarray]:
    return discretise(*axis.matrices(), dt)


def _states(axis: AxisResponse, dt: float, cmd: np.ndarray, v0: float) -> np.ndarray:
    """Open-loop states (M, n) on the grid, from the steady state at ``v0``, under ``cmd`` (M,)."""
    ad, bd = _discrete(axis, dt)
    x = axis.steady_state(v0)
    out = np.empty((cmd.size, x.size))
    for i, u in enumerate(cmd):
        out[i] = x
        x = ad @ x + bd * u
    return out


def _one_step(axis: AxisResponse, dt: float, cmd: np.ndarray, v: np.ndarray, ahead: int) -> np.ndarray:
    """Velocity error (M - ahead,) of predictions ``ahead`` grid steps from each measured velocity."""
    ad, bd = _discrete(axis, dt)
    x = _states(axis, dt, cmd, v[0])
    x[:, 1] = v                                   # measured velocity, hidden states from the open-loop run
    m = cmd.size - ahead
    xs = x[:m].T.copy()
    for j in range(ahead):
        xs = ad @ xs + np.outer(bd, cmd[j:j + m])
    return xs[1] - v[ahead:]


def _axis_data(log: ResponseLog, axes: tuple[int, ...]) -> list[tuple[np.ndarray, np.ndarray]]:
    return [(cmd[:, k], vel[:, k]) for _, cmd, vel in log.segments for k in axes]


def fit_rms(axis: AxisResponse, data, dt: float = GRID_S) -> float:
    """Open-loop velocity rms (m/s) of ``axis`` on ``(command, velocity)`` series."""
    err = np.concatenate([_states(axis, dt, c, v[0])[:, 1] - v for c, v in data])
    return float(np.sqrt(np.mean(err**2)))


def one_step_rms(axis: AxisResponse, data, dt: float = GRID_S, horizon_s: float = 0.3) -> float:
    """Rms (m/s) of the velocity predicted ``horizon_s`` ahead from each measured velocity."""
    ahead = max(1, int(round(horizon_s / dt)))
    err = np.concatenate([_one_step(axis, dt, c, v, ahead) for c, v in data if c.size > ahead])
    return float(np.sqrt(np.mean(err**2)))


def fit_axis(data, dt: float = GRID_S, *, first_order: bool = False, horizon_s: float = 0.3) -> AxisResponse:
    """Fit an :class:`AxisResponse` (or a first-order lag) to ``(command, velocity)`` series.

    The criterion is the prediction error ``horizon_s`` ahead (the prediction-error method):
    on PX4 SITL it gave physically sensible gains (horizontal K_p 1.5, K_i 0.33 against
    PX4's 1.8 and 0.4) where the open-loop criterion traded the gains against each other
    at the same open-loop rms.
    """
    ahead = max(1, int(round(horizon_s / dt)))
    usable = [(c, v) for c, v in data if c.size > ahead]
    if not usable:
        raise IdentifyError(f"no stretch longer than {horizon_s} s to fit")

    def model(theta: np.ndarray) -> AxisResponse:
        if first_order:
            return AxisResponse(p_gain_per_s=float(theta[0]))
        return AxisResponse(*map(float, theta))

    def residual(theta: np.ndarray) -> np.ndarray:
        axis = model(theta)
        return np.concatenate([_one_step(axis, dt, c, v, ahead) for c, v in usable])

    if first_order:
        x0, lo, hi = [3.0], [0.05], [100.0]
    else:
        x0, lo, hi = [2.0, 0.5, 0.5, 0.1], [0.05, 0.0, 0.0, 0.0], [50.0, 50.0, 20.0, 2.0]
    best = None
    for scale in (1.0, 3.0):                      # two starts: PX4's slow horizontal and fast vertical
        start = np.clip(np.asarray(x0) * scale, lo, hi)
        sol = least_squares(residual, start, bounds=(lo, hi), x_scale="jac", max_nfev=100)
        if best is None or sol.cost < best.cost:
            best = sol
    return model(best.x).canonical()


def check_excitation(log: ResponseLog, min_step_mps: float = MIN_STEP_MPS) -> None:
    """Refuse a log whose commands do not step by ``min_step_mps`` on each axis group.

    Raises
    ------
    IdentifyError
        Naming the axis group without a step and the largest step it has.
    """
    for name, axes in (("horizontal (north or east)", (0, 1)), ("vertical (down)", (2,))):
        largest = max((float(np.ptp(cmd[:, k])) for _, cmd, _ in log.segments for k in axes), default=0.0)
        if largest < min_step_mps:
            raise IdentifyError(f"no velocity step of at least {min_step_mps:g} m/s on the {name} axis in OFFBOARD "
                                f"(largest {largest:.2f} m/s): the response cannot be identified; fly the "
                                f"identification steps (companion fly --identify)")


@dataclass(frozen=True)
class Identification:
    """The fitted responses and their figures of merit (m/s) beside a reference lag's."""

    horizontal: AxisResponse
    vertical: AxisResponse
    figures: dict[str, dict[str, float]]      # model name -> figure name -> value
    duration_s: float
    kinds: dict[str, int]


def identify(log: ResponseLog, *, reference_lag_s: float = 0.3, horizon_s: float = 0.3) -> Identification:
    """Fit the horizontal and vertical responses of ``log``; compare with first-order lags.

    Raises :class:`IdentifyError` when the log has no velocity step of :data:`MIN_STEP_MPS`
    on an axis group (:func:`check_excitation`), or when ``horizon_s`` or ``reference_lag_s``
    is outside its range. (A gain at its bound is not refused: a pure lag's response is
    the same for any ``K_i`` whose zero cancels a pole, so the fit may leave it anywhere.)

    ``figures`` has rows ``'model'`` (the fit), ``'first-order fit'`` and
    ``f'lag {reference_lag_s} s'`` with ``fit_rms`` and ``one_step_rms`` for
    ``horizontal``, ``vertical`` and ``all`` (the rms over the three axes).
    """
    lo, hi = HORIZON_RANGE_S
    if not lo <= horizon_s <= hi:
        raise IdentifyError(f"horizon_s = {horizon_s!r} must be from {lo:g} to {hi:g} s")
    lo, hi = REFERENCE_LAG_RANGE_S
    if not lo <= reference_lag_s <= hi:
        raise IdentifyError(f"reference_lag_s = {reference_lag_s!r} must be from {lo:g} to {hi:g} s")
    check_excitation(log)
    groups = {"horizontal": (0, 1), "vertical": (2,)}
    data = {name: _axis_data(log, axes) for name, axes in groups.items()}
    fitted = {name: fit_axis(d, horizon_s=horizon_s) for name, d in data.items()}
    first = {name: fit_axis(d, first_order=True, horizon_s=horizon_s) for name, d in data.items()}
    reference = AxisResponse(p_gain_per_s=1.0 / reference_lag_s)
    models = {"model": fitted, "first-order fit": first, f"lag {reference_lag_s:g} s": dict.fromkeys(groups, reference)}
    figures: dict[str, dict[str, float]] = {}
    for label, per_group in models.items():
        row: dict[str, float] = {}
        for what, fn in (("fit_rms", fit_rms), ("one_step_rms", one_step_rms)):
            kwargs = {"horizon_s": horizon_s} if fn is one_step_rms else {}
            sq, count = 0.0, 0
            for name in groups:
                value = fn(per_group[name], data[name], **kwargs)
                row[f"{what}_{name}"] = value
                weight = len(groups[name])
                sq, count = sq + weight * value**2, count + weight
            row[f"{what}_all"] = math.sqrt(sq / count)
        figures[label] = row
    return Identification(fitted["horizontal"], fitted["vertical"], figures, log.duration_s, log.kinds)


def modelled_velocity(axis: AxisResponse, cmd: np.ndarray, v0: float, dt: float = GRID_S) -> np.ndarray:
    """The open-loop velocity (M,) of ``axis`` under ``cmd`` (M,), for figures."""
    return axis.velocities(cmd, v0, dt)
