"""What the control loop needs of an offboard sequence (the protocol the sequencer is injected by).

:class:`companion.mavlink.offboard.OffboardSequencer` is the real one (PX4's arm, take-off and
OFFBOARD handshake); ``companion replay`` passes a stand-in that counts as engaged from the
first autopilot HEARTBEAT (:class:`companion.offline.replay.AssumeEngaged`).
"""

from __future__ import annotations

from typing import Protocol

from companion.mavlink.messages import CommandAck, Key, VehicleHeartbeat
from companion.mavlink.autopilots import Autopilot
from companion.mavlink.offboard import Action, OffboardConfig, Phase, SequencerState


class OffboardSequence(Protocol):
    """The engagement state machine the loop feeds and asks whether to stream and command."""

    @property
    def target(self) -> Key | None:
        """(system, component) of the autopilot followed, once heard."""

    @property
    def phase(self) -> Phase:
        """Current phase."""

    @property
    def state(self) -> SequencerState:
        """Snapshot: whether to stream setpoints and whether the companion is in control."""

    def on_heartbeat(self, t_s: float, hb: VehicleHeartbeat) -> None:
        """Every decoded HEARTBEAT (link time ``t_s``, s)."""

    def on_ack(self, t_s: float, ack: CommandAck) -> None:
        """The autopilot's COMMAND_ACKs."""

    def on_statustext(self, t_s: float, text: str) -> None:
        """The autopilot's STATUSTEXTs."""

    @property
    def kind(self) -> Autopilot | None:
        """The followed autopilot's kind, once heard."""

    @property
    def config(self) -> OffboardConfig:
        """The engagement settings."""

    def on_home_altitude(self, alt_amsl_m: float) -> None:
        """The autopilot's home altitude, metres AMSL (HOME_POSITION)."""

    def on_home_local_z(self, local_z_m: float) -> None:
        """Home's down coordinate in the autopilot's local frame, m (HOME_POSITION ``z``)."""

    def on_estimator_status(self, t_s: float, flags: int) -> None:
        """The autopilot's estimator status (EKF_STATUS_REPORT flags): whether it can fly."""

    def on_vehicle_position(self, t_s: float, z_ned_m: float, vz_ned_mps: float | None) -> None:
        """The autopilot's own down position (m) and velocity (m/s) estimate."""

    def on_goal_reached(self, t_s: float) -> None:
        """The companion reached its goal at link time ``t_s`` (the sequencer may hand back to Hold)."""

    def on_at_goal(self, t_s: float, settled: bool) -> None:
        """Whether the vehicle is settled at its goal at link time ``t_s`` (after it was reached)."""

    def hand_back(self, t_s: float, reason: str) -> bool:
        """Ask for Hold at link time ``t_s``, streaming until the vehicle shows it; whether it started
        (False when nothing of ours was streaming)."""

    def step(self, t_s: float) -> list[Action]:
        """Advance to link time ``t_s``; the commands to send and the events to report."""
