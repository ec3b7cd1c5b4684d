"""What this drone tells its fleet: its state, and its intent (the plan in force) while it flies one.

Each tick the announcer may add, to the fleet link's outbox (never the autopilot's: PX4
fuses any ODOMETRY it hears as its own vision, docs/OBSTACLES.md):

- ODOMETRY of the drone's estimate (position, velocity and their covariances, NED) at
  ``[fleet] state_rate_hz``, stamped with the estimate's vehicle time;
- TRAJECTORY_REPRESENTATION_WAYPOINTS of the plan in force as knots
  (:func:`companion.core.intent.intent_from_plan`) when a new plan comes into force and
  every ``intent_resend_s`` while it stays, stamped with the plan's start (vehicle time);
- the same message with no points (the intent withdrawn) as soon as no plan is flown
  (hovering, braking, handed back), and every ``intent_resend_s`` after, until one is again.

Stamps are the vehicle's time (the autopilot's boot clock, microseconds), on which the
estimate and the plans live; receivers map them as any source's clock. Pure: time comes
in as arguments.
"""

from __future__ import annotations

import math

import numpy as np

from companion.core.intent import intent_from_plan
from companion.core.planner import Plan
from companion.loop.fleet_config import FleetConfig
from companion.mavlink import fleet


_ZERO = np.zeros(3)
_ZERO.setflags(write=False)


def _usec(t_s: float) -> int:
    return max(0, int(round(t_s * 1e6)))


class FleetAnnouncer:
    """Builds the fleet link's messages (see the module docstring).

    Parameters
    ----------
    config : the ``[fleet]`` section.
    step_s : the planner's step (s): the plans' positions are ``step_s`` apart.
    """

    def __init__(self, config: FleetConfig, step_s: float) -> None:
        self.config = config
        self.step_s = float(step_s)
        self._state_period = 1.0 / config.state_rate_hz
        self._next_state_t = -math.inf
        self._last_state_stamp = -1
        self._sent_plan: Plan | None = None
        self._withdrawn = False
        self._last_intent_t = -math.inf
        #: messages built: ``states``, ``intents``, ``withdrawals``
        self.sent = {"states": 0, "intents": 0, "withdrawals": 0}

    def outbox(self, t_s: float, estimate, plan: Plan | None, plan_t0_v: float, plan_p0: np.ndarray,
               offset: np.ndarray | None = _ZERO) -> list:
        """The messages due at link time ``t_s``.

        ``estimate``: the drone filter's state (``t_s`` vehicle time, ``position``, ``velocity``,
        ``position_cov``, ``velocity_cov``) or None before the first; ``plan``: the plan in force
        (None: none flown), starting at vehicle time ``plan_t0_v`` from ``plan_p0`` (NED m).
        Positions go out in the fleet's frame: local plus ``offset`` (NED m,
        :class:`~companion.loop.fleet_frame.FleetFrame`; zero by default); None: the frame is not
        known yet and nothing is announced.
        """
        out: list = []
        if offset is None:
            return out
        offset = np.asarray(offset, dtype=float)
        if estimate is not None and t_s >= self._next_state_t - 1e-6 and _usec(estimate.t_s) != self._last_state_stamp:
            self._next_state_t = t_s + self._state_period
            self._last_state_stamp = _usec(estimate.t_s)
            out.append(fleet.encode_state(self._last_state_stamp, estimate.position + offset, estimate.velocity,
                                          estimate.position_cov, getattr(estimate, "velocity_cov", None)))
            self.sent["states"] += 1
        due = t_s - self._last_intent_t >= self.config.intent_resend_s - 1e-6
        if plan is None:
            if estimate is not None and (not self._withdrawn or due):   # nothing to withdraw before any state
                out.append(fleet.encode_intent(_usec(estimate.t_s), None, None))
                self._withdrawn, self._sent_plan, self._last_intent_t = True, None, t_s
                self.sent["withdrawals"] += 1
            return out
        if plan is not self._sent_plan or due:
            intent = intent_from_plan(plan_t0_v, self.step_s, plan_p0, plan.initial_velocity, plan.positions,
                                      plan.velocities, self.config.intent_knot_spacing_s)
            out.append(fleet.encode_intent(_usec(intent.t0_s), intent.positions + offset, intent.velocities))
            self._withdrawn, self._sent_plan, self._last_intent_t = False, plan, t_s
            self.sent["intents"] += 1
        return out
