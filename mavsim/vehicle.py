"""Kinematic multicopter in local NED: pure functions, no clock.

Velocity responses, chosen per scenario by ``[sim] vehicle``: ``"lag"`` (below), or a
:class:`VelocityResponse` an autopilot personality brings (:mod:`mavsim.personalities`; PX4's
PID velocity loop against SIH's linear drag, ``"px4"``, responds like PX4 SITL does).

The lag model (per step ``dt``)::

    v_cmd  <- commanded velocity (NED, m/s)
    dv     = (v_cmd - v) (1 - exp(-dt / tau))      # exact first-order response
    dv     <- dv * min(1, a_max dt / |dv|)          # acceleration bound
    v'     = v + dv
    p'     = p + (v + v') dt / 2                    # trapezoid
    z' >= 0                                         # the ground (z down: airborne is z < 0)

With the motors off (disarmed) in the air the vehicle falls with g. On the ground it
stays put unless the motors are on and the command climbs (``v_cmd z < 0``). Roll and
pitch are the tilt needed for the horizontal acceleration; yaw follows a yaw setpoint
at a bounded rate or integrates a yaw-rate setpoint.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

logger = logging.getLogger(__name__)

__all__ = ["VelocityResponse", "VehicleParams", "VehicleState", "VehicleCommand", "step", "initial_state", "GRAVITY_MPS2"]

GRAVITY_MPS2 = 9.80665
YAW_RATE_MAX_RADPS = 1.5  # heading change rate toward a yaw setpoint (PX4 MPC_YAWRAUTO_MAX ~ 45 deg/s)


class VelocityResponse(Protocol):
    """A velocity loop and airframe other than the lag: one physics step of the velocity.

    Its hidden state (a controller's integral, the thrust's lag) rides in
    :attr:`VehicleState.controller`: None at rest (spawned, on the ground).
    """

    def step(self, hidden: Any, velocity_mps: np.ndarray, velocity_dot_mps2: np.ndarray,
             setpoint_mps: np.ndarray, dt: float) -> tuple[Any, np.ndarray]:
        """The new hidden state and velocity (NED, m/s) after ``dt`` seconds toward
        ``setpoint_mps`` (NED, m/s), from the velocity now and its last derivative (m/s^2)."""


@dataclass(frozen=True)
class VehicleParams:
    """Physical parameters.

    Attributes
    ----------
    time_constant_s : float
        First-order velocity time constant tau (s).
    accel_max_mps2 : float
        Bound on the acceleration norm while the motors are on (m/s^2).
    response : VelocityResponse or None
        None: the lag (the two values above); else this response (the two values unused).
    """

    time_constant_s: float = 0.3
    accel_max_mps2: float = 4.0
    response: VelocityResponse | None = None


@dataclass(frozen=True)
class VehicleState:
    """True kinematic state.

    Attributes
    ----------
    position_ned_m, velocity_ned_mps, accel_ned_mps2 : ndarray (3,)
        Local NED position (m), velocity (m/s) and last acceleration (m/s^2).
    yaw_rad, yaw_rate_radps : float
        Heading (0 north, positive toward east) and its rate.
    on_ground : bool
        True while resting on the ground (z = 0).
    controller : object
        The velocity response's hidden state (None for the lag, at rest and on the ground).
    """

    position_ned_m: np.ndarray
    velocity_ned_mps: np.ndarray
    accel_ned_mps2: np.ndarray
    yaw_rad: float
    yaw_rate_radps: float
    on_ground: bool
    controller: Any = None

    @property
    def roll_pitch_rad(self) -> tuple[float, float]:
        """Roll and pitch (rad) that produce the horizontal acceleration at this yaw."""
        ax, ay = float(self.accel_ned_mps2[0]), float(self.accel_ned_mps2[1])
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        a_fwd, a_right = c * ax + s * ay, -s * ax + c * ay
        return math.atan2(a_right, GRAVITY_MPS2), -math.atan2(a_fwd, GRAVITY_MPS2)


@dataclass(frozen=True)
class VehicleCommand:
    """What the flight controller asks of the airframe for one step.

    Attributes
    ----------
    velocity_ned_mps : ndarray (3,)
        Velocity setpoint (NED, m/s).
    yaw_rad : float or None
        Heading setpoint; None keeps the heading (unless ``yaw_rate_radps`` is given).
    yaw_rate_radps : float or None
        Heading rate setpoint, used when ``yaw_rad`` is None.
    motors_on : bool
        False: no thrust (disarmed).
    """

    velocity_ned_mps: np.ndarray
    yaw_rad: float | None = None
    yaw_rate_radps: float | None = None
    motors_on: bool = True


def initial_state(position_ned_m: np.ndarray, yaw_rad: float = 0.0) -> VehicleState:
    """A vehicle at rest at ``position_ned_m`` (on the ground if z >= 0)."""
    p = np.array(position_ned_m, dtype=float)
    on_ground = bool(p[2] >= 0.0)
    if on_ground:
        p[2] = 0.0
    z3 = np.zeros(3)
    return VehicleState(p, z3.copy(), z3.copy(), float(yaw_rad), 0.0, on_ground)


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def step(state: VehicleState, command: VehicleCommand, dt: float, params: VehicleParams) -> VehicleState:
    """Advance the vehicle by ``dt`` seconds.

    Parameters
    ----------
    state : VehicleState
    command : VehicleCommand
    dt : float
        Step (s), > 0.
    params : VehicleParams

    Returns
    -------
    VehicleState
        The new state; ``state`` is not modified.
    """
    p, v = state.position_ned_m, state.velocity_ned_mps
    v_cmd = command.velocity_ned_mps
    if state.on_ground and (not command.motors_on or v_cmd[2] >= 0.0):
        # Resting on the ground: no sliding, no sinking.
        yaw = state.yaw_rad
        if command.motors_on:
            yaw, rate = _yaw_step(state.yaw_rad, command, dt)
        else:
            rate = 0.0
        z3 = np.zeros(3)
        return VehicleState(p, z3, z3, yaw, rate, True)
    controller = None
    if command.motors_on and params.response is not None:
        controller, v_new = params.response.step(state.controller, v, state.accel_ned_mps2, v_cmd, dt)
        dv = v_new - v
    elif command.motors_on:
        dv = (v_cmd - v) * (1.0 - math.exp(-dt / params.time_constant_s))  # first-order lag
        lim = params.accel_max_mps2 * dt
        n = math.sqrt(float(dv @ dv))
        if n > lim:
            dv = dv * (lim / n)  # |a| <= a_max
    else:
        dv = np.array([0.0, 0.0, GRAVITY_MPS2 * dt])  # free fall
    v_new = v + dv
    p_new = p + 0.5 * (v + v_new) * dt
    on_ground = False
    if p_new[2] >= 0.0:  # touch down
        p_new[2] = 0.0
        v_new = np.zeros(3)
        on_ground = True
    yaw, rate = _yaw_step(state.yaw_rad, command, dt) if command.motors_on else (state.yaw_rad, 0.0)
    if on_ground:
        controller = None
    return VehicleState(p_new, v_new, dv / dt, yaw, rate, on_ground, controller)


def _yaw_step(yaw: float, command: VehicleCommand, dt: float) -> tuple[float, float]:
    if command.yaw_rad is not None:
        err = _wrap(command.yaw_rad - yaw)
        rate = max(-YAW_RATE_MAX_RADPS, min(YAW_RATE_MAX_RADPS, err / dt))
    elif command.yaw_rate_radps is not None:
        rate = command.yaw_rate_radps
    else:
        return yaw, 0.0
    return _wrap(yaw + rate * dt), rate
