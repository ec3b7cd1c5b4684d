"""PX4's velocity controller acting on a SIH-like airframe: the ``vehicle = "px4"`` profile (pure, no clock).

The PX4 personality (:mod:`mavsim.personalities.px4`) brings it as a
:class:`mavsim.vehicle.VelocityResponse`.

PX4's multicopter velocity loop (``mc_pos_control``, ``PositionControl::_velocityControl``)
turns the velocity error into an acceleration setpoint with a PID per axis group::

    e      = v_sp - v                                   velocity error (NED, m/s)
    a_sp   = K_p e + xi - K_d v_dot                     acceleration setpoint (m/s^2)
    xi'    = K_i e        (held while a_sp is saturated against e: anti-windup)

with PX4's defaults MPC_XY_VEL_P_ACC 1.8, MPC_XY_VEL_I_ACC 0.4, MPC_XY_VEL_D_ACC 0.2
(horizontal) and MPC_Z_VEL_P_ACC 4, MPC_Z_VEL_I_ACC 2, MPC_Z_VEL_D_ACC 0 (vertical). The
horizontal acceleration is bounded by the tilt limit (MPC_TILTMAX_AIR 45 deg: g tan 45),
the vertical one by the thrust range around hover (MPC_THR_MIN 0.12, MPC_THR_MAX 1 at a
hover thrust of 0.5). The airframe reaches the acceleration setpoint after a short lag
(the attitude loop tilts the thrust: ``accel_lag_s`` horizontally; the motors change
thrust: ``thrust_lag_s`` vertically) and feels SIH's linear drag (SIH_KDV 1 N s/m on a
1 kg vehicle: 1/s)::

    a'     = (a_sp - a) / T_axis                        thrust acceleration (m/s^2)
    v'     = a - k v                                    linear drag k (1/s)

Against the drag, the P term alone settles at ``K_p / (K_p + k)`` of a horizontal step
(about 60 %): the integral removes the rest slowly (5 to 7 s to 90 %). That is the
two-part response measured on PX4 SITL (SIH quadrotor); the lags were chosen to match
that measured table (``python -m tests.benchmarks.step_response``), the gains and drag are
PX4's and SIH's defaults. Units: NED, metres, seconds.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

logger = logging.getLogger(__name__)

__all__ = ["Px4Response", "ControllerState", "controller_step"]

_G = 9.80665


@dataclass(frozen=True)
class Px4Response:
    """Gains, limits, lags and drag of the PX4 profile (PX4 / SIH parameter names in brackets).

    Attributes
    ----------
    xy_p_per_s, xy_i_per_s2, xy_d : float
        Horizontal velocity PID (MPC_XY_VEL_P_ACC 1/s, MPC_XY_VEL_I_ACC 1/s^2, MPC_XY_VEL_D_ACC).
    z_p_per_s, z_i_per_s2, z_d : float
        Vertical velocity PID (MPC_Z_VEL_P_ACC, MPC_Z_VEL_I_ACC, MPC_Z_VEL_D_ACC).
    tilt_max_rad : float
        Largest tilt (MPC_TILTMAX_AIR): horizontal acceleration <= g tan(tilt_max).
    accel_up_max_mps2, accel_down_max_mps2 : float
        Vertical acceleration bounds from the thrust range around hover (m/s^2).
    accel_lag_s : float
        Time constant of the horizontal acceleration (the attitude loop), seconds.
    thrust_lag_s : float
        Time constant of the vertical acceleration (motors), seconds.
    drag_per_s : float
        Linear drag per unit mass (SIH_KDV / SIH_MASS), 1/s, on all three axes.
    """

    xy_p_per_s: float = 1.8
    xy_i_per_s2: float = 0.4
    xy_d: float = 0.2
    z_p_per_s: float = 4.0
    z_i_per_s2: float = 2.0
    z_d: float = 0.0
    tilt_max_rad: float = math.radians(45.0)
    accel_up_max_mps2: float = _G * (1.0 / 0.5 - 1.0)       # MPC_THR_MAX 1 at hover thrust 0.5
    accel_down_max_mps2: float = _G * (1.0 - 0.12 / 0.5)    # MPC_THR_MIN 0.12 at hover thrust 0.5
    accel_lag_s: float = 0.25
    thrust_lag_s: float = 0.04
    drag_per_s: float = 1.0

    def step(self, hidden: ControllerState | None, velocity_mps: np.ndarray, velocity_dot_mps2: np.ndarray,
             setpoint_mps: np.ndarray, dt: float) -> tuple[ControllerState, np.ndarray]:
        """:func:`controller_step` from ``hidden`` (None: at rest), the
        :class:`mavsim.vehicle.VelocityResponse` the vehicle steps with."""
        return controller_step(_ZERO if hidden is None else hidden, velocity_mps, velocity_dot_mps2,
                               setpoint_mps, dt, self)


@dataclass(frozen=True)
class ControllerState:
    """Hidden state of the PX4 profile (NED).

    Attributes
    ----------
    integral_mps2 : ndarray (3,)
        The velocity integral term ``xi`` (m/s^2).
    thrust_accel_mps2 : ndarray (3,)
        The acceleration the tilted thrust gives (before drag), m/s^2.
    """

    integral_mps2: np.ndarray
    thrust_accel_mps2: np.ndarray

    @classmethod
    def zero(cls) -> ControllerState:
        """The state at rest: one shared instance with read-only arrays (nothing writes into a state)."""
        return _ZERO


def _read_only_zeros() -> np.ndarray:
    z = np.zeros(3)
    z.flags.writeable = False
    return z


_ZERO = ControllerState(_read_only_zeros(), _read_only_zeros())


def _clamp(a_sp: np.ndarray, r: Px4Response) -> tuple[np.ndarray, np.ndarray]:
    """``a_sp`` within the tilt and thrust limits, and which axes were saturated (bool (3,))."""
    out = a_sp.copy()
    sat = np.zeros(3, dtype=bool)
    h_max = _G * math.tan(r.tilt_max_rad)
    h = math.hypot(out[0], out[1])
    if h > h_max:
        out[:2] *= h_max / h
        sat[:2] = True
    lo, hi = -r.accel_up_max_mps2, r.accel_down_max_mps2      # NED: up is negative
    if not lo <= out[2] <= hi:
        out[2] = min(max(out[2], lo), hi)
        sat[2] = True
    return out, sat


def controller_step(ctrl: ControllerState, velocity_mps: np.ndarray, velocity_dot_mps2: np.ndarray,
                    setpoint_mps: np.ndarray, dt: float, r: Px4Response) -> tuple[ControllerState, np.ndarray]:
    """One step of ``dt`` seconds: the new controller state and the new velocity (NED, m/s).

    Parameters
    ----------
    ctrl : ControllerState
    velocity_mps, velocity_dot_mps2 : ndarray (3,)
        Velocity now and its last derivative (the D term's input), NED.
    setpoint_mps : ndarray (3,)
        Velocity setpoint, NED m/s.
    dt : float
        Step, seconds (> 0).
    r : Px4Response
    """
    kp = np.array([r.xy_p_per_s, r.xy_p_per_s, r.z_p_per_s])
    ki = np.array([r.xy_i_per_s2, r.xy_i_per_s2, r.z_i_per_s2])
    kd = np.array([r.xy_d, r.xy_d, r.z_d])
    err = setpoint_mps - velocity_mps
    a_sp, sat = _clamp(kp * err + ctrl.integral_mps2 - kd * velocity_dot_mps2, r)
    # anti-windup: do not integrate further into a saturated direction
    grow = ~sat | (np.sign(err) != np.sign(a_sp))
    integral = ctrl.integral_mps2 + np.where(grow, ki * err * dt, 0.0)
    lags = np.array([r.accel_lag_s, r.accel_lag_s, r.thrust_lag_s])
    carried = np.exp(-dt / np.maximum(lags, 1e-9))
    thrust = a_sp + (ctrl.thrust_accel_mps2 - a_sp) * carried
    # linear drag, exact over the step for the held thrust acceleration
    k = r.drag_per_s
    if k > 0.0:
        decay = math.exp(-k * dt)
        v_new = velocity_mps * decay + thrust / k * (1.0 - decay)
    else:
        v_new = velocity_mps + thrust * dt
    return ControllerState(integral, thrust), v_new
