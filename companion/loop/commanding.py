"""This tick's command and setpoint: hover before control, brake on a stale estimate or without a
valid plan, else fly the plan in force; then the setpoint in the autopilot's frame.

:class:`Commanding` is the loop's last stage. It asks the :class:`~companion.loop.plan_cycle.PlanCycle`
for the replan due, the :class:`~companion.loop.executor.Executor` for the command of the plan in
force, keeps the loop's mode (:class:`~companion.loop.records.LoopMode`) and says its changes
through the :class:`~companion.loop.supervisor.Supervisor`. Pure: link time (s) comes in as an
argument, vehicle time (s) from :class:`~companion.loop.perception.Perception`.
"""

from __future__ import annotations

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.loop.config import LoopConfig
from companion.loop.executor import Executor, Follow
from companion.loop.goal import GoalSource
from companion.loop.perception import Perception
from companion.loop.plan_cycle import PlanCycle
from companion.loop.position_quality import PositionQuality
from companion.loop.records import CompanionState, LoopMode
from companion.loop.supervisor import SEV_NOTICE, SEV_WARNING, Supervisor
from companion.mavlink import messages

Outbox = list[mavlink2.MAVLink_message]


class Commanding:
    """The command of each tick and its setpoint (see the module docstring)."""

    def __init__(self, settings: LoopConfig, *, perception: Perception, executor: Executor, cycle: PlanCycle,
                 supervisor: Supervisor, goal: GoalSource, state: CompanionState) -> None:
        self.settings, self.perception, self.executor, self.cycle = settings, perception, executor, cycle
        self.supervisor, self.goal, self.state = supervisor, goal, state
        self._plan_too_old = False  # braking for an old plan was announced
        self._braking_since: float | None = None  # link time the current braking (stale estimate, no plan) began
        self._reset_epoch = 0  # the perception's estimator reset epoch last acted on
        self.position_quality = PositionQuality(settings.position_sd_warn_m)
        #: not engaged, stream the vehicle's own estimated velocity rather than a hover (a guarding
        #: companion: should OFFBOARD be entered before a plan, the vehicle goes on, braking from there)
        self.mirror = False

    def released(self, t_s: float) -> Outbox:
        """Not streaming (nothing of ours in force): hold the executor, restart the response
        observer, take back what the planner finished without applying it."""
        if self.state.mode not in (LoopMode.WAITING, LoopMode.IDLE):
            self.state.mode = LoopMode.IDLE
        self._reset_epoch = self.perception.reset_epoch  # no plan of ours in force to drop
        self.executor.hold()
        self.perception.released()
        return self.cycle.collect(t_s, apply=False)

    def command(self, t_s: float, engaged: bool) -> tuple[np.ndarray, Outbox]:
        """The velocity command (NED m/s, the plans' frame) while streaming, and what it says."""
        if not engaged:
            self._reset_epoch = self.perception.reset_epoch  # hovering: no plan in force to drop
            self.state.mode = LoopMode.PRESTREAM
            est = self.perception.drone.state
            if self.mirror and est is not None:
                command = self.executor.mirror(est.velocity)
            else:
                command = self.executor.hold()  # hover while the autopilot is asked to switch
            return command, self.cycle.collect(t_s, apply=False)
        return self._engaged(t_s)

    def setpoint(self, t_s: float, engaged: bool, command: np.ndarray,
                 autopilot: tuple[int, int] | None) -> mavlink2.MAVLink_message:
        """This tick's setpoint in the autopilot's frame (the plans' velocity less the drift;
        not while the estimate is stale: a drift measured before the silence is no reason to
        command a velocity while braking blind), told to the response observer."""
        target = dict(zip(("target_system", "target_component"), autopilot or (1, 1)))
        reference = None
        if engaged and self.settings.setpoint_kind == "position_velocity" and self.state.mode is LoopMode.TRACKING:
            t_v = self.perception.vehicle_time(t_s)
            reference = self.executor.reference(t_v) if t_v is not None else None
        if engaged and self.state.mode is not LoopMode.STALE:
            command = self.perception.autopilot_command(command)
            if reference is not None:
                reference = (reference[0], self.perception.autopilot_command(reference[1]))
        self.perception.setpoint_sent(t_s, engaged, command)
        t_boot_ms = int(round(t_s * 1000.0))
        if reference is not None:
            return messages.position_velocity_setpoint(t_boot_ms, *reference, **target)
        return messages.velocity_setpoint(t_boot_ms, command, **target)

    def _engaged(self, t_s: float) -> tuple[np.ndarray, Outbox]:
        """The command while engaged: brake on a stale estimate or without a valid plan, else fly the plan."""
        said: Outbox = self._after_reset(t_s) + self._position_quality(t_s)
        t_v = self.perception.vehicle_time(t_s)
        est = self.perception.drone.state
        if t_v is None or est is None or t_v - est.t_s > self.settings.estimate_timeout_s:
            if self.state.mode is not LoopMode.STALE:
                self.state.stale_events += 1
                said.append(self.supervisor.say(t_s, SEV_WARNING, "companion: estimate stale, braking"))
            self.state.mode = LoopMode.STALE
            self.executor.drop()
            said.extend(self.cycle.collect(t_s, apply=False))
            return self.executor.brake(), said
        if self.state.mode is LoopMode.STALE:
            said.append(self.supervisor.say(t_s, SEV_NOTICE, "companion: estimate back, resuming"))
        self.goal.start(est.position)
        said.extend(self.cycle.step(t_s, t_v))
        command, why = self.executor.follow(t_s, t_v)
        if why is Follow.PLAN:
            if self.state.mode is LoopMode.BRAKING:
                said.append(self.supervisor.say(t_s, SEV_NOTICE, "companion: valid plan again, resuming"))
            self.state.mode = LoopMode.TRACKING
            self._plan_too_old = False
            return command, said
        if why is Follow.TOO_OLD and not self._plan_too_old:
            self._plan_too_old = True
            self.state.old_plan_events += 1
            said.append(self.supervisor.say(t_s, SEV_WARNING,
                                            f"companion: plan older than {self.executor.max_plan_age_s:g} s, braking"))
        self.state.mode = LoopMode.BRAKING
        return command, said

    def _after_reset(self, t_s: float) -> Outbox:
        """The autopilot's estimator reset since the last tick: the plan in force (built from a
        position of the old frame) is dropped, so the stream brakes, and the next replan, from
        the new estimate, is asked at once; plans built before it are discarded on arrival
        (:class:`~companion.loop.plan_cycle.PlanCycle`)."""
        epoch = self.perception.reset_epoch
        if epoch == self._reset_epoch:
            return []
        self._reset_epoch = epoch
        self.state.estimator_resets += 1
        self.executor.drop()
        self.cycle.replan_now()
        jump = float(np.linalg.norm(self.perception.resets[-1][1]))
        return [self.supervisor.say(t_s, SEV_WARNING, f"companion: estimator reset ({jump:.1f} m), replanning")]

    def _position_quality(self, t_s: float) -> Outbox:
        """Say when the autopilot's reported position becomes uncertain, and when it is certain
        again (:mod:`companion.loop.position_quality`); the planner's margins follow the
        reported covariance by themselves (``drone_covariance = "reported"``)."""
        quality = self.position_quality
        text = quality.update(self.perception.reported_cov)
        self.state.position_uncertain_events = quality.events
        self.state.reported_position_sd_max_m = quality.largest_sd_m
        if text is None:
            return []
        return [self.supervisor.say(t_s, SEV_WARNING if quality.uncertain else SEV_NOTICE, text)]

    def braked_to_a_stop(self, t_s: float, engaged: bool, command: np.ndarray, limit_s: float | None) -> str | None:
        """Why to hand the vehicle back now, or None: the companion has braked (stale estimate, no
        valid plan) for ``limit_s`` (s; None: never) and the braking command is zero. An autopilot
        that keeps its offboard mode whatever the stream does (ArduCopter) must not be left hovering
        on a companion that cannot fly it."""
        if not engaged or self.state.mode not in (LoopMode.STALE, LoopMode.BRAKING):
            self._braking_since = None
            return None
        if self._braking_since is None:
            self._braking_since = t_s
        if limit_s is None or t_s - self._braking_since < limit_s - 1e-9 or np.any(np.asarray(command) != 0.0):
            return None
        why = "estimate stale" if self.state.mode is LoopMode.STALE else "no valid plan"
        return f"{why}, braked to a stop"


def brake_hand_back_s(sequencer) -> float | None:
    """How long braking lasts before the hand-back (s): ``[offboard] brake_hand_back_s``, else the
    autopilot's own default (None: never, as for an autopilot that leaves its offboard mode itself)."""
    limit = getattr(getattr(sequencer, "config", None), "brake_hand_back_s", None)
    if limit is None:
        kind = getattr(sequencer, "kind", None)
        limit = None if kind is None else kind.brake_hand_back_s
    return limit
