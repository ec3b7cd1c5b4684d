"""Decode inbound MAVLink messages into typed observations; encode outbound ones.

Pure: functions take pymavlink message objects (``pymavlink.dialects.v20.common``)
and numbers, and return dataclasses or message objects. Packing (sequence
numbers, source ids, signing) belongs to :mod:`companion.mavlink.link`.

(Over 400 lines: one job, the vehicle's own wire format in both directions: every kind
the autopilot sends, with its rejection reasons, and every kind the companion sends.
Traffic from other systems is decoded in :mod:`companion.mavlink.traffic`.)

Decoding never raises on bad traffic: a message that cannot be trusted comes back
as :class:`Rejected` and is logged. Encoding raises :class:`~companion.errors.InputError`
(a ``ValueError``) on non-finite input, because a wrong command must never be sent.

Frames and units: local NED (x north, y east, z down), metres, metres per second,
seconds; yaw in radians, 0 north, positive clockwise seen from above.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Union

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink import autopilots
from companion.mavlink.autopilots import Autopilot, ModeRole
from companion.errors import InputError

logger = logging.getLogger(__name__)

Key = tuple[int, int]

#: SET_POSITION_TARGET_LOCAL_NED type_mask bits (a set bit means "ignore").
TM_X, TM_Y, TM_Z = 1, 2, 4
TM_VX, TM_VY, TM_VZ = 8, 16, 32
TM_AX, TM_AY, TM_AZ = 64, 128, 256
TM_FORCE, TM_YAW, TM_YAW_RATE = 512, 1024, 2048
#: Velocity only, yaw and yaw rate ignored: 3527.
TYPE_MASK_VELOCITY = TM_X | TM_Y | TM_Z | TM_AX | TM_AY | TM_AZ | TM_YAW | TM_YAW_RATE
#: Velocity and yaw (yaw rate ignored), as MAVSDK's VelocityNed: 2503.
TYPE_MASK_VELOCITY_YAW = TYPE_MASK_VELOCITY & ~TM_YAW
#: Position with velocity feed-forward, yaw and yaw rate ignored: 3520.
TYPE_MASK_POSITION_VELOCITY = TM_AX | TM_AY | TM_AZ | TM_YAW | TM_YAW_RATE

MAV_FRAME_LOCAL_NED = mavlink2.MAV_FRAME_LOCAL_NED  # 1
MAV_FRAME_LOCAL_FRD = mavlink2.MAV_FRAME_LOCAL_FRD  # 20
MAV_FRAME_BODY_FRD = mavlink2.MAV_FRAME_BODY_FRD  # 12
#: ODOMETRY frame_id values taken as the shared local frame.
LOCAL_FRAMES = frozenset({MAV_FRAME_LOCAL_NED, MAV_FRAME_LOCAL_FRD})

#: Indices of the x/y/z block in a row-major upper triangle of a 6x6 matrix
#: (ODOMETRY pose_covariance and velocity_covariance): (0,0)=0 (0,1)=1 (0,2)=2
#: (1,1)=6 (1,2)=7 (2,2)=11.
_UT_INDEX = (0, 1, 2, 6, 7, 11)

STATUSTEXT_MAX_CHARS = 50
#: Largest variance a reported covariance may hold (m^2 or (m/s)^2): a standard deviation
#: of 100 m (or m/s), ten times the default sensing range, says nothing an avoidance
#: planner can use; a report claiming more (1e30 m^2 was seen in testing) is rejected, as
#: it would otherwise make every plan infeasible.
MAX_REPORTED_VARIANCE = 1e4
NAMED_VALUE_MAX_CHARS = 10
UINT32_WRAP = 1 << 32


# --------------------------------------------------------------------------- decoded types


@dataclass(frozen=True)
class VehicleHeartbeat:
    """A HEARTBEAT of any system, with its autopilot's mode and identity worked out.

    ``kind`` is the registered autopilot (:mod:`companion.mavlink.autopilots`) that the
    ``autopilot`` field announces, None for any other; ``mode`` is that autopilot's name
    of ``custom_mode`` (``''`` without one) and ``role`` what the mode means to the
    companion. ``is_autopilot``: a vehicle's autopilot of a registered kind
    (:func:`companion.mavlink.autopilots.of_heartbeat`).
    """

    sysid: int
    compid: int
    autopilot: int
    type: int
    base_mode: int
    custom_mode: int
    system_status: int
    armed: bool
    mode: str
    is_autopilot: bool
    role: ModeRole = ModeRole.OTHER
    kind: Autopilot | None = None

    @property
    def key(self) -> Key:
        return (self.sysid, self.compid)

    @property
    def offboard(self) -> bool:
        """In the autopilot's offboard role: the only evidence that the companion is in control."""
        return self.is_autopilot and self.role is ModeRole.OFFBOARD


@dataclass(frozen=True, eq=False)
class PoseObservation:
    """Position (and maybe velocity) of one MAVLink system in the local NED frame.

    Attributes
    ----------
    key : (int, int)
        (system id, component id) of the sender.
    t_s : float
        Time of validity in seconds, from the message's own ``time_usec`` or
        ``time_boot_ms`` (time since the sender's boot; shared time base).
    position_ned : ndarray (3,)
        Metres, NED.
    velocity_ned : ndarray (3,) or None
        Metres per second, NED; None when the sender marks it unknown (NaN).
    position_cov, velocity_cov : ndarray (3, 3) or None
        Covariances in m^2 and (m/s)^2, symmetric positive definite; None when
        unknown (NaN in element 0, or a message without covariance).
    source : str
        ``'ODOMETRY'`` or ``'LOCAL_POSITION_NED'``.
    reset_counter : int or None
        ODOMETRY's ``reset_counter`` (the estimator's count of its resets, PX4's position
        reset counter); None for a message without one.
    """

    key: Key
    t_s: float
    position_ned: np.ndarray
    velocity_ned: np.ndarray | None
    position_cov: np.ndarray | None
    velocity_cov: np.ndarray | None
    source: str
    reset_counter: int | None = None

    @property
    def position_var(self) -> np.ndarray | None:
        """Diagonal of ``position_cov`` (m^2), or None."""
        return None if self.position_cov is None else np.diag(self.position_cov).copy()

    @property
    def velocity_var(self) -> np.ndarray | None:
        """Diagonal of ``velocity_cov`` ((m/s)^2), or None."""
        return None if self.velocity_cov is None else np.diag(self.velocity_cov).copy()


@dataclass(frozen=True)
class CommandAck:
    """COMMAND_ACK: ``result`` 0 accepted, 1 temporarily rejected, 2 denied, 3 unsupported, 4 failed, 5 in progress."""

    key: Key
    command: int
    result: int
    target_system: int
    target_component: int

    @property
    def accepted(self) -> bool:
        return self.result == mavlink2.MAV_RESULT_ACCEPTED

    @property
    def result_name(self) -> str:
        entry = mavlink2.enums["MAV_RESULT"].get(self.result)
        return entry.name if entry is not None else f"MAV_RESULT({self.result})"


@dataclass(frozen=True)
class StatusText:
    """STATUSTEXT: ``severity`` 0 emergency .. 7 debug (MAV_SEVERITY)."""

    key: Key
    severity: int
    text: str


@dataclass(frozen=True)
class HomePosition:
    """HOME_POSITION: the sender's home altitude, metres AMSL (the message's ``altitude`` is mm),
    its latitude and longitude (degrees) and its position in the local frame (NED, m)."""

    key: Key
    altitude_amsl_m: float
    #: home's down coordinate in the sender's local NED frame (m from its EKF origin)
    local_z_m: float = 0.0
    lat_deg: float = math.nan
    lon_deg: float = math.nan
    local_ned_m: tuple[float, float, float] = (math.nan, math.nan, math.nan)


@dataclass(frozen=True)
class EstimatorStatus:
    """EKF_STATUS_REPORT: the sender's estimator ``flags`` (EKF_STATUS_FLAGS), which say whether it can fly."""

    key: Key
    flags: int


@dataclass(frozen=True)
class LandedState:
    """EXTENDED_SYS_STATE: the sender's ``landed_state`` (MAV_LANDED_STATE: 0 unknown, 1 on the
    ground, 2 in the air, 3 taking off, 4 landing)."""

    key: Key
    landed_state: int

    @property
    def on_ground(self) -> bool:
        return self.landed_state == mavlink2.MAV_LANDED_STATE_ON_GROUND


@dataclass(frozen=True)
class MissionCurrent:
    """MISSION_CURRENT: the sender's current mission item ``seq``, the mission's ``total`` items
    (MAVLink 2 extension: 65535 when unknown) and ``mission_state`` (MISSION_STATE: 0 unknown,
    1 no mission, 2 not started, 3 active, 4 paused, 5 complete)."""

    key: Key
    seq: int
    total: int = 65535
    mission_state: int = 0


@dataclass(frozen=True)
class MissionItemReached:
    """MISSION_ITEM_REACHED: the sender reached mission item ``seq`` (PX4 repeats it with the next
    MISSION_CURRENT messages: count distinct items, not messages)."""

    key: Key
    seq: int


@dataclass(frozen=True)
class TimeSync:
    """TIMESYNC: a request when ``tc1_ns`` is 0 (``ts1_ns`` the sender's clock), else an answer
    (``tc1_ns`` the answerer's clock on receipt, ``ts1_ns`` the request's echoed). Nanoseconds."""

    key: Key
    tc1_ns: int
    ts1_ns: int

    @property
    def is_request(self) -> bool:
        return self.tc1_ns == 0


@dataclass(frozen=True)
class Rejected:
    """An inbound message that was not trusted; ``reason`` says why."""

    key: Key
    msg_type: str
    reason: str


Decoded = Union[VehicleHeartbeat, PoseObservation, CommandAck, StatusText, HomePosition, EstimatorStatus, LandedState,
                MissionCurrent, MissionItemReached, TimeSync, Rejected]


# --------------------------------------------------------------------------- decoding


def source_key(msg: mavlink2.MAVLink_message) -> Key:
    """(system id, component id) of the sender of a parsed message."""
    return (int(msg.get_srcSystem()), int(msg.get_srcComponent()))


def decode(msg: mavlink2.MAVLink_message) -> Decoded | None:
    """Decode one parsed message; None for message types the companion ignores.

    Never raises on message content: untrusted content gives :class:`Rejected`
    (logged at WARNING).
    """
    handler = _DECODERS.get(msg.get_type())
    if handler is None:
        return None
    try:
        return handler(msg)
    except Exception as exc:  # a malformed message must never stop the control loop
        return _reject(msg, f"malformed: {type(exc).__name__}: {exc}")


def decode_heartbeat(msg: mavlink2.MAVLink_heartbeat_message) -> VehicleHeartbeat:
    """HEARTBEAT to :class:`VehicleHeartbeat`."""
    sysid, compid = source_key(msg)
    kind = autopilots.by_mav_autopilot(msg.autopilot)
    is_ap = autopilots.of_heartbeat(sysid, compid, msg.autopilot, msg.type) is not None
    return VehicleHeartbeat(
        sysid=sysid,
        compid=compid,
        autopilot=int(msg.autopilot),
        type=int(msg.type),
        base_mode=int(msg.base_mode),
        custom_mode=int(msg.custom_mode),
        system_status=int(msg.system_status),
        armed=autopilots.is_armed(msg.base_mode),
        mode=kind.mode_name(msg.custom_mode) if kind is not None else "",
        is_autopilot=is_ap,
        role=kind.mode_role(msg.custom_mode) if kind is not None else ModeRole.OTHER,
        kind=kind,
    )


def decode_command_ack(msg: mavlink2.MAVLink_command_ack_message) -> CommandAck:
    """COMMAND_ACK to :class:`CommandAck` (MAVLink 1 packets carry no target: 0, 0)."""
    return CommandAck(
        key=source_key(msg),
        command=int(msg.command),
        result=int(msg.result),
        target_system=int(getattr(msg, "target_system", 0) or 0),
        target_component=int(getattr(msg, "target_component", 0) or 0),
    )


def decode_statustext(msg: mavlink2.MAVLink_statustext_message) -> StatusText:
    """STATUSTEXT to :class:`StatusText` (one chunk; text stripped of NULs)."""
    text = msg.text if isinstance(msg.text, str) else bytes(msg.text).decode("ascii", "replace")
    return StatusText(key=source_key(msg), severity=int(msg.severity), text=text.rstrip("\x00"))


def decode_timesync(msg: mavlink2.MAVLink_timesync_message) -> TimeSync | Rejected:
    tc1, ts1 = int(msg.tc1), int(msg.ts1)
    if tc1 < 0 or ts1 < 0:
        return _reject(msg, f"TIMESYNC with tc1 {tc1} and ts1 {ts1}: clocks are non-negative nanoseconds")
    return TimeSync(source_key(msg), tc1, ts1)


def decode_home_position(msg: mavlink2.MAVLink_home_position_message) -> HomePosition:
    """HOME_POSITION to :class:`HomePosition` (altitude mm AMSL to metres)."""
    z = float(msg.z)
    return HomePosition(key=source_key(msg), altitude_amsl_m=msg.altitude / 1000.0, local_z_m=z if math.isfinite(z) else 0.0,
                        lat_deg=msg.latitude * 1e-7, lon_deg=msg.longitude * 1e-7,
                        local_ned_m=(float(msg.x), float(msg.y), float(msg.z)))


def decode_ekf_status_report(msg) -> EstimatorStatus:
    """EKF_STATUS_REPORT (193, ArduPilot's dialect) to :class:`EstimatorStatus`."""
    return EstimatorStatus(key=source_key(msg), flags=int(msg.flags))


def decode_extended_sys_state(msg) -> LandedState:
    """EXTENDED_SYS_STATE (245) to :class:`LandedState`."""
    return LandedState(key=source_key(msg), landed_state=int(msg.landed_state))


def decode_mission_current(msg) -> MissionCurrent:
    """MISSION_CURRENT (42) to :class:`MissionCurrent` (a MAVLink 1 packet has no ``total`` nor state)."""
    return MissionCurrent(key=source_key(msg), seq=int(msg.seq), total=int(getattr(msg, "total", 65535) or 65535),
                          mission_state=int(getattr(msg, "mission_state", 0) or 0))


def decode_mission_item_reached(msg) -> MissionItemReached:
    """MISSION_ITEM_REACHED (46) to :class:`MissionItemReached`."""
    return MissionItemReached(key=source_key(msg), seq=int(msg.seq))


def covariance_from_upper_triangle(values, *, what: str) -> np.ndarray | None | str:
    """x/y/z 3x3 block of a 21-element row-major upper triangle of a 6x6 matrix.

    Returns the symmetric (3, 3) matrix, None when element 0 is NaN (unknown, as
    MAVLink defines it), or a string giving the reason it cannot be trusted
    (wrong length, non-finite entry, negative variance, a variance above
    :data:`MAX_REPORTED_VARIANCE`, not positive definite).

    Written on Python floats (six numbers), not small numpy arrays: every ODOMETRY a
    companion hears goes through it, and the array version cost about 60 us a call.
    """
    try:
        n = len(values)
    except TypeError:
        n = np.asarray(values).size
    if n != 21:
        return f"{what} has {n} elements, expected 21"
    block = [float(values[i]) for i in _UT_INDEX]
    if math.isnan(block[0]):
        return None
    if not all(math.isfinite(x) for x in block):
        return f"{what} has non-finite entries in the x/y/z block: {block}"
    xx, xy, xz, yy, yz, zz = block
    diag = [xx, yy, zz]
    if min(diag) < 0.0:
        return f"{what} has negative variances {diag}"
    if max(diag) > MAX_REPORTED_VARIANCE:
        return f"{what} has variances above {MAX_REPORTED_VARIANCE:g}: {diag}"
    cov = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
    # Sylvester's criterion in closed form, as the planner checks its covariances (0.3 us;
    # numpy's Cholesky took 9 to 10 us, and can disagree only within rounding of singular)
    det = xx * (yy * zz - yz * yz) + xy * (xz * yz - xy * zz) + xz * (xy * yz - xz * yy)
    if not (xx > 0.0 and xx * yy - xy * xy > 0.0 and det > 0.0):
        return f"{what} x/y/z block is not positive definite: {cov.tolist()}"
    return cov


def _finite3(v: np.ndarray) -> bool:
    """All three entries finite (on Python floats: a few times cheaper than ``np.all(np.isfinite(v))``)."""
    x, y, z = v.tolist()
    return math.isfinite(x) and math.isfinite(y) and math.isfinite(z)


def _quat_to_rot(q) -> np.ndarray | None:
    """Rotation matrix body -> local of a MAVLink quaternion (w, x, y, z); None if unusable."""
    w, x, y, z = (float(v) for v in q)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if not math.isfinite(n) or n < 1e-6:
        return None
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def decode_odometry(msg: mavlink2.MAVLink_odometry_message) -> PoseObservation | Rejected:
    """ODOMETRY to :class:`PoseObservation`, or :class:`Rejected`.

    Accepted: ``frame_id`` LOCAL_NED (1) or LOCAL_FRD (20); finite position.
    Velocity is taken in the local frame when ``child_frame_id`` is 1, 20 or 0,
    rotated by the attitude quaternion when it is BODY_FRD (12), and dropped
    (None) for other child frames or when it is NaN. A covariance whose element
    0 is NaN is unknown (None); one with other non-finite entries, negative
    variances or not positive definite rejects the whole message.
    """
    key = source_key(msg)
    if int(msg.frame_id) not in LOCAL_FRAMES:
        return _reject(msg, f"frame_id {msg.frame_id} is not LOCAL_NED (1) or LOCAL_FRD (20)")
    position = np.array([msg.x, msg.y, msg.z], dtype=float)
    if not _finite3(position):
        return _reject(msg, f"non-finite position {position.tolist()}")
    t_s = int(msg.time_usec) * 1e-6

    pos_cov = covariance_from_upper_triangle(msg.pose_covariance, what="pose_covariance")
    if isinstance(pos_cov, str):
        return _reject(msg, pos_cov)
    vel_cov = covariance_from_upper_triangle(msg.velocity_covariance, what="velocity_covariance")
    if isinstance(vel_cov, str):
        return _reject(msg, vel_cov)

    velocity: np.ndarray | None = np.array([msg.vx, msg.vy, msg.vz], dtype=float)
    if not _finite3(velocity):
        velocity, vel_cov = None, None
    else:
        child = int(msg.child_frame_id)
        if child in LOCAL_FRAMES or child == 0:
            pass
        elif child == MAV_FRAME_BODY_FRD:
            rot = _quat_to_rot(msg.q)
            if rot is None:
                logger.debug("ODOMETRY from %s: body velocity without usable attitude; velocity dropped", key)
                velocity, vel_cov = None, None
            else:
                velocity = rot @ velocity
                vel_cov = None if vel_cov is None else rot @ vel_cov @ rot.T
        else:
            logger.debug("ODOMETRY from %s: child_frame_id %s not understood; velocity dropped", key, child)
            velocity, vel_cov = None, None

    return PoseObservation(
        key=key,
        t_s=t_s,
        position_ned=position,
        velocity_ned=velocity,
        position_cov=pos_cov,
        velocity_cov=vel_cov,
        source="ODOMETRY",
        reset_counter=int(msg.reset_counter),
    )


def decode_local_position_ned(msg: mavlink2.MAVLink_local_position_ned_message) -> PoseObservation | Rejected:
    """LOCAL_POSITION_NED to :class:`PoseObservation` (no covariance), or :class:`Rejected`."""
    position = np.array([msg.x, msg.y, msg.z], dtype=float)
    if not _finite3(position):
        return _reject(msg, f"non-finite position {position.tolist()}")
    velocity: np.ndarray | None = np.array([msg.vx, msg.vy, msg.vz], dtype=float)
    if not _finite3(velocity):
        velocity = None
    return PoseObservation(
        key=source_key(msg),
        t_s=int(msg.time_boot_ms) * 1e-3,
        position_ned=position,
        velocity_ned=velocity,
        position_cov=None,
        velocity_cov=None,
        source="LOCAL_POSITION_NED",
    )


def _reject(msg: mavlink2.MAVLink_message, reason: str) -> Rejected:
    key = source_key(msg)
    logger.warning("rejected %s from system %d component %d: %s", msg.get_type(), key[0], key[1], reason)
    return Rejected(key=key, msg_type=msg.get_type(), reason=reason)


_DECODERS = {
    "HEARTBEAT": decode_heartbeat,
    "ODOMETRY": decode_odometry,
    "LOCAL_POSITION_NED": decode_local_position_ned,
    "COMMAND_ACK": decode_command_ack,
    "STATUSTEXT": decode_statustext,
    "HOME_POSITION": decode_home_position,
    "EKF_STATUS_REPORT": decode_ekf_status_report,
    "EXTENDED_SYS_STATE": decode_extended_sys_state,
    "MISSION_CURRENT": decode_mission_current,
    "MISSION_ITEM_REACHED": decode_mission_item_reached,
    "TIMESYNC": decode_timesync,
}


# --------------------------------------------------------------------------- encoding


def _boot_ms(t_boot_ms: int) -> int:
    value = int(t_boot_ms)
    if value != t_boot_ms or value < 0:
        raise InputError(f"time_boot_ms must be a non-negative integer, got {t_boot_ms!r}")
    return value % UINT32_WRAP


def velocity_setpoint(
    t_boot_ms: int,
    v_ned,
    yaw: float | None = None,
    *,
    target_system: int = 1,
    target_component: int = 1,
) -> mavlink2.MAVLink_set_position_target_local_ned_message:
    """SET_POSITION_TARGET_LOCAL_NED commanding a velocity in MAV_FRAME_LOCAL_NED.

    Parameters
    ----------
    t_boot_ms : int
        Companion time since boot, milliseconds (wrapped to uint32).
    v_ned : array_like (3,)
        Velocity setpoint, m/s, NED (climb is negative vz).
    yaw : float, optional
        Yaw to hold, radians (0 north). None leaves yaw to the vehicle
        (type_mask 3527); a value uses type_mask 2503.

    Raises
    ------
    InputError
        If ``v_ned`` is not three finite numbers or ``yaw`` is not finite.
    """
    v = np.asarray(v_ned, dtype=float)
    if v.shape != (3,) or not _finite3(v):
        raise InputError(f"velocity setpoint must be 3 finite m/s values (NED), got {v_ned!r}")
    if yaw is not None and not math.isfinite(float(yaw)):
        raise InputError(f"yaw setpoint must be finite radians, got {yaw!r}")
    mask = TYPE_MASK_VELOCITY if yaw is None else TYPE_MASK_VELOCITY_YAW
    return mavlink2.MAVLink_set_position_target_local_ned_message(
        _boot_ms(t_boot_ms),
        int(target_system),
        int(target_component),
        MAV_FRAME_LOCAL_NED,
        mask,
        0.0, 0.0, 0.0,
        float(v[0]), float(v[1]), float(v[2]),
        0.0, 0.0, 0.0,
        0.0 if yaw is None else float(yaw),
        0.0,
    )


def position_velocity_setpoint(
    t_boot_ms: int,
    p_ned,
    v_ned,
    *,
    target_system: int = 1,
    target_component: int = 1,
) -> mavlink2.MAVLink_set_position_target_local_ned_message:
    """SET_POSITION_TARGET_LOCAL_NED with a position and its velocity feed-forward (type_mask 3520).

    PX4's position loop tracks ``p_ned`` (metres, NED) and adds ``v_ned`` (m/s, NED) to its
    velocity setpoint, as MAVSDK's ``PositionNedYaw`` + ``VelocityNedYaw`` offboard users do.

    Raises
    ------
    InputError
        If either vector is not three finite numbers.
    """
    p, v = np.asarray(p_ned, dtype=float), np.asarray(v_ned, dtype=float)
    if p.shape != (3,) or v.shape != (3,) or not (np.all(np.isfinite(p)) and np.all(np.isfinite(v))):
        raise InputError(f"position + velocity setpoint must be 3 finite metres and 3 finite m/s (NED), "
                         f"got {p_ned!r}, {v_ned!r}")
    return mavlink2.MAVLink_set_position_target_local_ned_message(
        _boot_ms(t_boot_ms), int(target_system), int(target_component), MAV_FRAME_LOCAL_NED,
        TYPE_MASK_POSITION_VELOCITY, float(p[0]), float(p[1]), float(p[2]), float(v[0]), float(v[1]), float(v[2]),
        0.0, 0.0, 0.0, 0.0, 0.0,
    )


def companion_heartbeat(system_status: int = mavlink2.MAV_STATE_ACTIVE) -> mavlink2.MAVLink_heartbeat_message:
    """HEARTBEAT of the companion: type ONBOARD_CONTROLLER (18), autopilot INVALID (8)."""
    return mavlink2.MAVLink_heartbeat_message(
        mavlink2.MAV_TYPE_ONBOARD_CONTROLLER,
        mavlink2.MAV_AUTOPILOT_INVALID,
        0,
        0,
        int(system_status),
        3,
    )


def statustext(severity: int, text: str) -> mavlink2.MAVLink_statustext_message:
    """STATUSTEXT; ``text`` is made ASCII and truncated to 50 characters.

    ``severity`` is MAV_SEVERITY: 0 emergency, 2 critical, 4 warning, 6 info.
    """
    severity = int(severity)
    if not 0 <= severity <= 7:
        raise InputError(f"STATUSTEXT severity must be 0..7 (MAV_SEVERITY), got {severity}")
    raw = str(text).encode("ascii", "replace")[:STATUSTEXT_MAX_CHARS]
    if len(str(text)) > STATUSTEXT_MAX_CHARS:
        logger.debug("STATUSTEXT truncated to %d characters: %r", STATUSTEXT_MAX_CHARS, text)
    return mavlink2.MAVLink_statustext_message(severity, raw, 0, 0)


def timesync(tc1_ns: int, ts1_ns: int) -> mavlink2.MAVLink_timesync_message:
    """TIMESYNC: a request (``tc1_ns`` 0, ``ts1_ns`` our clock) or an answer (``tc1_ns`` our clock on
    receipt, ``ts1_ns`` the request's, echoed). Nanoseconds, int64."""
    return mavlink2.MAVLink_timesync_message(int(tc1_ns), int(ts1_ns))


def named_value_float(t_boot_ms: int, name: str, value: float) -> mavlink2.MAVLink_named_value_float_message:
    """NAMED_VALUE_FLOAT (e.g. ``'ct_min'``, the current minimum contour of touch).

    Raises
    ------
    InputError
        If ``name`` is empty, longer than 10 characters or not ASCII (silent
        truncation could make two names collide).
    """
    try:
        raw = str(name).encode("ascii")
    except UnicodeEncodeError:
        raise InputError(f"NAMED_VALUE_FLOAT name must be ASCII, got {name!r}") from None
    if not 0 < len(raw) <= NAMED_VALUE_MAX_CHARS:
        raise InputError(f"NAMED_VALUE_FLOAT name must be 1..10 characters, got {name!r}")
    return mavlink2.MAVLink_named_value_float_message(_boot_ms(t_boot_ms), raw, float(value))


def command_long(
    command: int,
    params=(),
    *,
    target_system: int = 1,
    target_component: int = 1,
    confirmation: int = 0,
) -> mavlink2.MAVLink_command_long_message:
    """COMMAND_LONG with up to seven parameters (missing ones are 0).

    ``confirmation`` counts retransmissions (0 first, then 1, 2, ...).
    """
    values = [float(p) for p in params]
    if len(values) > 7:
        raise InputError(f"COMMAND_LONG takes at most 7 params, got {len(values)}")
    values += [0.0] * (7 - len(values))
    return mavlink2.MAVLink_command_long_message(
        int(target_system), int(target_component), int(command), int(confirmation) & 0xFF, *values
    )


def request_message_command(message_id: int, **target) -> mavlink2.MAVLink_command_long_message:
    """MAV_CMD_REQUEST_MESSAGE (512): param1 = the id of the message wanted (e.g. HOME_POSITION 242)."""
    return command_long(mavlink2.MAV_CMD_REQUEST_MESSAGE, (float(int(message_id)),), **target)


def set_message_interval_command(message_id: int, rate_hz: float, **target) -> mavlink2.MAVLink_command_long_message:
    """MAV_CMD_SET_MESSAGE_INTERVAL (511): param1 = message id, param2 = interval in microseconds."""
    return command_long(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL,
                        (float(int(message_id)), float(round(1e6 / float(rate_hz)))), **target)


def set_mode_command(autopilot: Autopilot, role: ModeRole, armed: bool, **target) -> mavlink2.MAVLink_command_long_message:
    """MAV_CMD_DO_SET_MODE (176) asking ``autopilot`` for the mode of ``role`` (offboard, hold, position).

    The parameters are the autopilot's (:meth:`~companion.mavlink.autopilots.base.Autopilot.set_mode_params`);
    ``armed`` says whether the vehicle is armed (some autopilots read param1's armed bit).
    """
    return command_long(mavlink2.MAV_CMD_DO_SET_MODE,
                        autopilot.set_mode_params(autopilot.custom_mode_of(role), armed), **target)


def arm_command(arm: bool, **target) -> mavlink2.MAVLink_command_long_message:
    """MAV_CMD_COMPONENT_ARM_DISARM (400): param1 = 1 arm, 0 disarm."""
    return command_long(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, (1.0 if arm else 0.0,), **target)


def mission_start_command(**target) -> mavlink2.MAVLink_command_long_message:
    """MAV_CMD_MISSION_START (300): param1 0 and param2 0, the stored mission from its current item
    to its end (PX4 switches to AUTO.MISSION; the vehicle must be armed)."""
    return command_long(mavlink2.MAV_CMD_MISSION_START, (0.0, 0.0), **target)


def takeoff_command(altitude_amsl_m: float = math.nan, **target) -> mavlink2.MAVLink_command_long_message:
    """MAV_CMD_NAV_TAKEOFF (22); param7 = altitude AMSL in metres, NaN for PX4's MIS_TAKEOFF_ALT.

    param4 (yaw) is NaN: keep the current heading. param5/6 (lat/lon) NaN: here.
    """
    alt = float(altitude_amsl_m)
    if math.isinf(alt):
        raise InputError(f"takeoff altitude must be finite metres AMSL or NaN, got {altitude_amsl_m!r}")
    return command_long(
        mavlink2.MAV_CMD_NAV_TAKEOFF, (0.0, 0.0, 0.0, math.nan, math.nan, math.nan, alt), **target
    )
