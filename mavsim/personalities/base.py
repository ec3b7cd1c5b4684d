"""What the simulator needs of an autopilot: the :class:`Personality` and :class:`Commander` protocols.

mavsim's core (the MAVLink face :mod:`mavsim.autopilot`, the telemetry of
:mod:`mavsim.telemetry`, the simulator :mod:`mavsim.core`, the scenario reader and the
traffic player) is the same for every autopilot it imitates. What differs lives in one
personality module per autopilot, registered in :mod:`mavsim.personalities`:

- its HEARTBEAT identity (MAV_TYPE, MAV_AUTOPILOT), and how it packs its flight mode into
  ``base_mode`` / ``custom_mode`` and its state into ``system_status`` (the commander's);
- its flight-mode names (``[sim] start_mode``) and the start mode by default;
- its commander (:class:`Commander`): mode requests, arming, takeoff, setpoint acceptance,
  offboard-loss behaviour and the velocity command it flies each physics step;
- its parameter table, the telemetry streams it sends by default and their rates (what
  SET_MESSAGE_INTERVAL with 0 restores), its AUTOPILOT_VERSION;
- the vehicle responses it brings (``[sim] vehicle`` profiles beside the generic ``"lag"``);
- how a real autopilot of its kind shows in a HEARTBEAT (mode name, engaged), for the
  traffic player.

Words: *offboard* is the mode in which the client's setpoints fly the vehicle, whatever the
autopilot calls it; *engaged* is armed in that mode. Units: SI, local NED (m, m/s, rad),
simulated time ``now_s`` in seconds since boot.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from mavsim.params import ParamStore, ParamTable
from mavsim.vehicle import VehicleCommand, VehicleState, VelocityResponse

__all__ = ["Personality", "Commander", "OffboardSetpoint",
           "SEV_CRITICAL", "SEV_WARNING", "SEV_NOTICE", "SEV_INFO"]

#: MAV_SEVERITY of the STATUSTEXTs the simulator sends.
SEV_CRITICAL, SEV_WARNING, SEV_NOTICE, SEV_INFO = 2, 4, 5, 6


@dataclass(frozen=True)
class OffboardSetpoint:
    """An accepted offboard setpoint in LOCAL_NED; NaN marks an ignored field.

    position_ned_m (m), velocity_ned_mps (m/s), accel_ned_mps2 (m/s^2): ndarray (3,);
    yaw_rad, yaw_rate_radps: float (NaN if ignored).
    """

    position_ned_m: np.ndarray
    velocity_ned_mps: np.ndarray
    accel_ned_mps2: np.ndarray
    yaw_rad: float
    yaw_rate_radps: float


class Commander(Protocol):
    """One vehicle's mode, arming and failsafe logic; pure and clock-free.

    Requests return a MAV_RESULT. STATUSTEXTs for the ground station are queued in
    :attr:`texts` as (MAV_SEVERITY, text) for the simulator to send.
    """

    #: Armed now.
    armed: bool
    #: The current flight mode's name (one of the personality's :attr:`Personality.mode_names`).
    mode: str
    #: Queued (severity, text) STATUSTEXTs; the simulator sends and clears them.
    texts: list[tuple[int, str]]
    #: (simulated time s, mode name) of every mode change, the start mode at 0.
    mode_changes: list[tuple[float, str]]
    #: Message ids to send once, unrequested, on every link (e.g. the origin when it is set);
    #: the simulator sends and clears them.
    announce: list[int]

    @property
    def base_mode(self) -> int:
        """HEARTBEAT ``base_mode`` now."""

    @property
    def custom_mode(self) -> int:
        """HEARTBEAT ``custom_mode`` now."""

    @property
    def system_status(self) -> int:
        """HEARTBEAT ``system_status`` (MAV_STATE) now."""

    @property
    def engaged(self) -> bool:
        """Armed in the offboard mode (a client's setpoints fly the vehicle)."""

    def landed_state(self, vehicle: VehicleState) -> int:
        """EXTENDED_SYS_STATE ``landed_state`` (MAV_LANDED_STATE) for the true ``vehicle``."""

    def sends(self, msg_id: int) -> bool:
        """Whether the stream of message ``msg_id`` has something to send now (e.g. no local
        position before the estimator has one); a due stream that has not is skipped."""

    def message(self, msg_id: int, now_us: int, vehicle: VehicleState, est_pos: np.ndarray, est_vel: np.ndarray):
        """The message ``msg_id`` if this autopilot builds it itself (its own dialect, its
        targets); None: the generic one of :mod:`mavsim.telemetry`."""

    def request_mode(self, custom_mode: int, custom_sub_mode: int, now_s: float, vehicle: VehicleState) -> int:
        """MAV_CMD_DO_SET_MODE with these param2 and param3 (custom mode and sub mode)."""

    def request_set_mode(self, custom_mode: int, now_s: float, vehicle: VehicleState) -> int:
        """SET_MODE with this ``custom_mode`` (answered as DO_SET_MODE)."""

    def request_land(self, now_s: float, vehicle: VehicleState) -> int:
        """MAV_CMD_NAV_LAND: land here."""

    def request_return(self, now_s: float, vehicle: VehicleState) -> int:
        """MAV_CMD_NAV_RETURN_TO_LAUNCH."""

    def request_hold(self, now_s: float, vehicle: VehicleState) -> int:
        """MAV_CMD_NAV_LOITER_UNLIM: hold position."""

    def request_takeoff(self, rel_alt_m: float, now_s: float, vehicle: VehicleState) -> int:
        """MAV_CMD_NAV_TAKEOFF to ``rel_alt_m`` above home (m; NaN: the autopilot's default)."""

    def request_arm(self, arm: bool, force: bool, now_s: float, vehicle: VehicleState) -> int:
        """MAV_CMD_COMPONENT_ARM_DISARM (``force``: param2 21196)."""

    def request_mission_start(self, first: float, now_s: float, vehicle: VehicleState) -> int:
        """MAV_CMD_MISSION_START (param1 the first item; NaN or 0: the stored current one)."""

    def load_mission(self, items: list, current: int) -> None:
        """The stored mission (:class:`mavsim.missions.MissionItem` list, local NED) and
        its current item, after an upload completed or a clear."""

    def set_mission_current(self, seq: int) -> None:
        """MISSION_SET_CURRENT: the mission goes on from item ``seq`` (at once, if flying)."""

    def load_fence(self, items: list) -> None:
        """The stored fence items (:class:`mavsim.missions.MissionItem` list, local NED), after an
        upload completed or a clear."""

    def accept_setpoint(self, sp: OffboardSetpoint, now_s: float) -> None:
        """A validated offboard setpoint arrived (proof of life; flown in the offboard mode)."""

    def position_aiding(self, unaided_s: float | None, now_s: float, vehicle: VehicleState) -> None:
        """The estimator has dead-reckoned (no GPS) for ``unaided_s`` seconds, None when aided;
        told before each :meth:`update` while the scenario has GPS outages. An autopilot that
        stops trusting a dead-reckoned position fails safe here."""

    def update(self, now_s: float, dt: float, vehicle: VehicleState) -> VehicleCommand:
        """Failsafe and auto-disarm checks, then the velocity command for the next ``dt`` seconds."""


class Personality(Protocol):
    """One autopilot as mavsim imitates it (see the module docstring)."""

    #: Registry name (``[sim]``-style lower case), e.g. for ``mavsim --autopilot``.
    name: str
    #: HEARTBEAT ``type`` (MAV_TYPE) and ``autopilot`` (MAV_AUTOPILOT) it announces.
    mav_type: int
    mav_autopilot: int
    #: AUTOPILOT_VERSION ``flight_sw_version``, ``vendor_id`` and ``product_id``.
    flight_sw_version: int
    vendor_id: int
    product_id: int
    #: Mode names ``[sim] start_mode`` accepts.
    mode_names: tuple[str, ...]
    #: Its parameters (PARAM_* and ``[sim] params``).
    params: ParamTable
    #: Stream name (a key of :data:`mavsim.telemetry.STREAM_IDS`) -> default rate (Hz, 0 off).
    stream_rates_hz: dict[str, float]
    #: ``[sim] vehicle`` profile name -> the velocity response it flies (besides ``"lag"``).
    response_models: dict[str, VelocityResponse]
    #: Integer parameters travel with their int32 bits in PARAM_VALUE's float (True), or as the
    #: float of their value (False).
    param_ints_bytewise: bool
    #: MAV_CMD_NAV_TAKEOFF's param7 is an altitude AMSL (True) or metres above home (False).
    takeoff_alt_amsl: bool
    #: Longest GPS outage whose end it models (s; None: any); longer ones are refused, for an
    #: autopilot whose failsafe on a lost position is not modelled.
    gps_outage_max_s: float | None

    def default_arming_delay_s(self, airborne: bool) -> float:
        """Arming is refused this long after boot when ``[sim] arming_delay_s`` is unset (s)."""

    def default_start_mode(self, airborne: bool) -> str:
        """The start mode when the scenario names none (airborne or on the ground)."""

    def commander(self, params: ParamStore, start_mode: str, armed: bool, vehicle: VehicleState,
                  arming_delay_s: float, offboard_reject_ack: int) -> Commander:
        """A commander starting in ``start_mode`` with the parameter store ``params``."""

    def heartbeat_mode_name(self, custom_mode: int) -> str:
        """A HEARTBEAT's mode as this autopilot names it (never raises)."""

    def engaged(self, base_mode: int, custom_mode: int) -> bool:
        """A HEARTBEAT of this autopilot shows it armed in its offboard mode."""
