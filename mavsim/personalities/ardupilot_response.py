"""ArduCopter's GUIDED velocity response: the ``vehicle = "ardupilot"`` profile (pure, no clock).

The ArduPilot personality (:mod:`mavsim.personalities.ardupilot`) brings it as a
:class:`mavsim.vehicle.VelocityResponse`.

ArduCopter does not hand a velocity target to its controllers as it is: its position
controller (``AC_PosControl``) first shapes it kinematically (``shape_vel_accel``,
``sqrt_controller``) into a desired velocity ``v_d``, acceleration ``a_d`` and position
``p_d`` that respect an acceleration bound and a jerk bound; then its position and
velocity loops make the airframe follow them, with the desired acceleration fed forward::

    e      = v_sp - v_d                                velocity error still to shape
    a_t    = sqrt_controller(e, j / a_max, j)          acceleration toward v_sp (linear near 0,
                                                       sqrt(2 j |e|) farther away)
    a_t    <- clamp(a_t, -a_max, a_max)                acceleration bound (WPNAV_ACCEL, WPNAV_ACCEL_Z)
    a_d'   = clamp((a_t - a_d) / dt, -j, j)            jerk bound (PSC_JERK_XY, PSC_JERK_Z)
    v_d'   = a_d,  p_d' = v_d                          the shaped target
    a_cmd  = a_d + K_v (v_d - v + K_p (p_d - p))       position and velocity loops (PSC_POS*_P,
                                                       PSC_VEL*_P), feed-forward a_d
    a'     = (a_cmd - a) / T                           the attitude loop (horizontal) or thrust
                                                       (vertical) reaching a_cmd after a lag T
    v'     = a

Horizontally the shaping acts on the 2-D vector (its norm bounded); vertically the bound
upward and downward may differ. The result is one smooth S-curve without the slow tail of
PX4's profile; the vertical one overshoots a little while the position loop catches up
with the shaped target. The bounds, gains and lags (:class:`ArduPilotResponse`) were fitted
to the step responses measured on ArduCopter SITL 4.7.0-dev (``docs/ARDUPILOT_SIM.md``);
the fit and its residuals are in ``tests/mavsim/test_ardupilot_personality.py``. Units:
NED, metres, seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["ArduPilotResponse", "ShapedState", "sqrt_controller"]


def sqrt_controller(error: float, p: float, second_ord_lim: float, dt: float) -> float:
    """ArduPilot's ``sqrt_controller``: ``p * error`` near zero, ``sqrt(2 lim (|error| - lim / 2 p^2))``
    beyond ``lim / p^2``, and never more than the error in one step (``|error| / dt``)."""
    if second_ord_lim <= 0.0 or p <= 0.0:
        out = error * p
    else:
        linear = second_ord_lim / (p * p)
        if error > linear:
            out = math.sqrt(2.0 * second_ord_lim * (error - linear / 2.0))
        elif error < -linear:
            out = -math.sqrt(2.0 * second_ord_lim * (-error - linear / 2.0))
        else:
            out = error * p
    if dt > 0.0:
        lim = abs(error) / dt
        out = max(-lim, min(lim, out))
    return out


@dataclass(frozen=True)
class ShapedState:
    """Hidden state of the ArduPilot profile (NED, each ndarray (3,)).

    Attributes
    ----------
    vel_desired_mps, accel_desired_mps2 : the shaped target's velocity and acceleration.
    pos_error_m : the shaped target's position minus the vehicle's.
    accel_mps2 : the acceleration the airframe gives now.
    """

    vel_desired_mps: np.ndarray
    accel_desired_mps2: np.ndarray
    pos_error_m: np.ndarray
    accel_mps2: np.ndarray


@dataclass(frozen=True)
class ArduPilotResponse:
    """Bounds, gains and lags of the ArduPilot profile (ArduCopter parameter names in brackets).

    Attributes
    ----------
    accel_xy_max_mps2, jerk_xy_mps3 : float
        Horizontal shaping bounds (WPNAV_ACCEL 2.5 m/s^2 and PSC_JERK_XY 5 m/s^3 in ArduCopter).
    accel_up_max_mps2, accel_down_max_mps2, jerk_z_mps3 : float
        Vertical shaping bounds (WPNAV_ACCEL_Z 1 m/s^2, PSC_JERK_Z 5 m/s^3).
    pos_xy_p_per_s, vel_xy_p_per_s, pos_z_p_per_s, vel_z_p_per_s : float
        Position and velocity loop gains (PSC_POSXY_P 1, PSC_VELXY_P 2, PSC_POSZ_P 1, PSC_VELZ_P 5).
    accel_xy_lag_s, accel_z_lag_s : float
        Time constants of the airframe's acceleration (attitude loop; thrust), seconds.
    """

    accel_xy_max_mps2: float = 2.5
    jerk_xy_mps3: float = 5.0
    accel_up_max_mps2: float = 1.0
    accel_down_max_mps2: float = 1.0
    jerk_z_mps3: float = 5.0
    pos_xy_p_per_s: float = 1.0
    vel_xy_p_per_s: float = 2.0
    pos_z_p_per_s: float = 1.0
    vel_z_p_per_s: float = 5.0
    accel_xy_lag_s: float = 0.2
    accel_z_lag_s: float = 0.2

    def step(self, hidden: ShapedState | None, velocity_mps: np.ndarray, velocity_dot_mps2: np.ndarray,
             setpoint_mps: np.ndarray, dt: float) -> tuple[ShapedState, np.ndarray]:
        """One step of ``dt`` seconds toward ``setpoint_mps`` from ``hidden`` (None: the shaped
        target at the vehicle's velocity, no acceleration): the new hidden state and velocity."""
        if hidden is None:
            z3 = np.zeros(3)
            hidden = ShapedState(np.array(velocity_mps, dtype=float), z3, z3, np.array(velocity_dot_mps2, dtype=float))
        vd, ad = hidden.vel_desired_mps, hidden.accel_desired_mps2
        # -- the shaped target: horizontal vector, then vertical
        ad_new = np.empty(3)
        e_xy = setpoint_mps[:2] - vd[:2]
        n = math.hypot(e_xy[0], e_xy[1])
        a_max, j = self.accel_xy_max_mps2, self.jerk_xy_mps3
        if n > 0.0:
            a_t = e_xy / n * min(a_max, sqrt_controller(n, j / a_max, j, dt))
        else:
            a_t = np.zeros(2)
        d = a_t - ad[:2]
        dn = math.hypot(d[0], d[1])
        if dn > j * dt:
            d = d * (j * dt / dn)
        ad_new[:2] = ad[:2] + d
        e_z = float(setpoint_mps[2] - vd[2])
        jz = self.jerk_z_mps3
        lim = self.accel_down_max_mps2 if e_z > 0.0 else self.accel_up_max_mps2    # NED: down is +
        a_tz = max(-self.accel_up_max_mps2, min(self.accel_down_max_mps2, sqrt_controller(e_z, jz / lim, jz, dt)))
        ad_new[2] = ad[2] + max(-jz * dt, min(jz * dt, a_tz - ad[2]))
        vd_new = vd + 0.5 * (ad + ad_new) * dt
        # -- the airframe following it
        kp = np.array([self.pos_xy_p_per_s, self.pos_xy_p_per_s, self.pos_z_p_per_s])
        kv = np.array([self.vel_xy_p_per_s, self.vel_xy_p_per_s, self.vel_z_p_per_s])
        lag = np.array([self.accel_xy_lag_s, self.accel_xy_lag_s, self.accel_z_lag_s])
        a_cmd = ad_new + kv * (vd_new - velocity_mps + kp * hidden.pos_error_m)
        a = a_cmd + (hidden.accel_mps2 - a_cmd) * np.exp(-dt / np.maximum(lag, 1e-9))
        v_new = velocity_mps + 0.5 * (hidden.accel_mps2 + a) * dt
        pos_error = hidden.pos_error_m + (0.5 * (vd + vd_new) - 0.5 * (velocity_mps + v_new)) * dt
        return ShapedState(vd_new, ad_new, pos_error, a), v_new
