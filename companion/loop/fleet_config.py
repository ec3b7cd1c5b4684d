"""``[fleet]``: how a companion shares its vehicle with the other drones of a fleet and uses theirs.

    [fleet]
    coordination = "distributed"     # "decentralised" | "distributed" | "prioritised"
    intent_knot_spacing_s = 1.5      # s between the knots of an announced plan (fleet-wide)
    intent_growth_m2ps = 0.02        # m^2/s: a peer's variance about its announced plan grows so
    intent_stale_s = 1.0             # s: an intent older than this is not used (constant velocity instead)
    max_peers = 32
    state_rate_hz = 10.0             # Hz: this drone's ODOMETRY on the fleet link
    intent_resend_s = 0.5            # s: the intent in force is sent again this often (and at every new plan)

Coordination (docs/FLEET.md):

- ``decentralised``: peers are tracks like any other obstacle, predicted at constant
  velocity from their state announcements; intents are not used.
- ``distributed``: a peer with a fresh intent is predicted along it
  (:mod:`companion.core.intent`); without one, at constant velocity.
- ``prioritised``: the lower system id has the higher priority. A drone predicts the
  higher-priority peers along their fresh intents (as fixed) and leaves the lower-priority
  peers out of its plan while their intents are fresh (they give way); a peer without a fresh
  intent is an ordinary track, whatever its priority.

``intent_knot_spacing_s`` must be the same for the whole fleet: the intent's message has no
per-point time (:mod:`companion.mavlink.fleet`).
"""

from __future__ import annotations

from dataclasses import dataclass

from companion import validation as check
from companion.errors import ConfigError

COORDINATION_MODES = ("decentralised", "distributed", "prioritised")


@dataclass(frozen=True)
class FleetConfig:
    """The ``[fleet]`` section (see the module docstring). Units: s, m^2/s."""

    coordination: str = "distributed"
    intent_knot_spacing_s: float = 1.5
    intent_growth_m2ps: float = 0.02
    intent_stale_s: float = 1.0
    max_peers: int = 32
    state_rate_hz: float = 10.0
    intent_resend_s: float = 0.5

    def __post_init__(self) -> None:
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        check.choice("coordination", self.coordination, COORDINATION_MODES)
        set_("intent_knot_spacing_s", check.number("intent_knot_spacing_s", self.intent_knot_spacing_s,
                                                   lo=0.05, hi=10.0))
        set_("intent_growth_m2ps", check.number("intent_growth_m2ps", self.intent_growth_m2ps, lo=0.0, hi=100.0))
        set_("intent_stale_s", check.number("intent_stale_s", self.intent_stale_s, positive=True, hi=60.0))
        set_("max_peers", check.integer("max_peers", self.max_peers, lo=1, hi=255))
        set_("state_rate_hz", check.number("state_rate_hz", self.state_rate_hz, lo=0.5, hi=50.0))
        set_("intent_resend_s", check.number("intent_resend_s", self.intent_resend_s, lo=0.05, hi=10.0))
        if self.intent_resend_s >= self.intent_stale_s:
            raise ConfigError(f"intent_resend_s = {self.intent_resend_s:g} must be < intent_stale_s = "
                              f"{self.intent_stale_s:g}: a peer would let the intent go stale between sendings")
