"""``[fleet]``: how a companion shares its vehicle with the other drones of a fleet and uses theirs.

    [fleet]
    coordination = "distributed"     # "decentralised" | "distributed" | "prioritised"
    intent_knot_spacing_s = 1.5      # s between the knots of an announced plan (fleet-wide)
    intent_growth_m2ps = 0.02        # m^2/s: a peer's variance about its announced plan grows so
    intent_stale_s = 1.0             # s: an intent older than this is not used (constant velocity instead)
    max_peers = 32
    state_rate_hz = 10.0             # Hz: this drone's ODOMETRY on the fleet link
    intent_resend_s = 0.5            # s: the intent in force is sent again this often (and at every new plan)
    keep_right = true                # the tie-break: a drone meeting a peer moves its target to the right
    deadlock_after_s = 6.0           # s without progress_m toward the goal, a peer near: a deadlock
    deadlock_progress_m = 0.5
    recovery_s = 4.0                 # s of a wider move to the right after a deadlock
    origin = [47.3977, 8.5456, 488.0]  # the fleet's shared frame (lat, lon deg, alt m AMSL); default: the vehicles' own
    peer_reports = "measurements"    # "measurements" | "estimate": what a peer's ODOMETRY is to the tracker

Coordination (docs/FLEET.md):

- ``decentralised``: peers are tracks like any other obstacle, predicted at constant
  velocity from their state announcements; intents are not used.
- ``distributed``: a peer with a fresh intent is predicted along it
  (:mod:`companion.core.intent`); without one, at constant velocity.
- ``prioritised``: the lower system id has the higher priority. A drone predicts the
  higher-priority peers along their fresh intents (as fixed) and leaves the lower-priority
  peers out of its plan while their intents are fresh and keep clear of its own plan (they
  give way); a lower-priority peer whose intent comes inside this drone's plan (it could not
  give way: boxed in, or met too fast for its acceleration) and a peer without a fresh intent
  are ordinary tracks, whatever their priority.

Right of way (:mod:`companion.loop.right_of_way`): with ``keep_right`` a drone that meets a
peer moves its target to the right of its way, so drones that meet pass left side to left
side; no progress toward the goal for ``deadlock_after_s`` with a peer near is a deadlock
(counted), followed by a wider move right for ``recovery_s``.

Frame (:mod:`companion.loop.fleet_frame`): announcements are in the fleet's NED frame about
``origin``, the same for the whole fleet; without it, in the vehicles' own local frame (one
simulator's world, or vehicles that share an origin).

Peers' states (``peer_reports``): a peer announces its companion's own estimate (mean and
covariance), already filtered. ``"measurements"`` (default) fuses the announcements like any
obstacle's reports in the tracker's constant-velocity filter; ``"estimate"`` takes each as
the peer's track state and only predicts between them. Fused, the tracks lag every
correction a peer's autopilot makes to its estimate: on PX4 SITL the tracks of three
swapping drones lay 0.33 m (median) and up to 2.2 m from the peers' own announcements, and
``"estimate"`` is what ``configs/swap_px4.toml`` flies (docs/FLEET.md, docs/notes/fleet.md).

``intent_knot_spacing_s`` must be the same for the whole fleet: the intent's message has no
per-point time (:mod:`companion.mavlink.fleet`).
"""

from __future__ import annotations

from dataclasses import dataclass

from companion import validation as check
from companion.errors import ConfigError

COORDINATION_MODES = ("decentralised", "distributed", "prioritised")
PEER_REPORTS = ("estimate", "measurements")


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
    keep_right: bool = True
    deadlock_after_s: float = 6.0
    deadlock_progress_m: float = 0.5
    recovery_s: float = 4.0
    origin: tuple | None = None
    peer_reports: str = "measurements"

    def __post_init__(self) -> None:
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        check.choice("coordination", self.coordination, COORDINATION_MODES)
        check.choice("peer_reports", self.peer_reports, PEER_REPORTS)
        set_("intent_knot_spacing_s", check.number("intent_knot_spacing_s", self.intent_knot_spacing_s,
                                                   lo=0.05, hi=10.0))
        set_("intent_growth_m2ps", check.number("intent_growth_m2ps", self.intent_growth_m2ps, lo=0.0, hi=100.0))
        set_("intent_stale_s", check.number("intent_stale_s", self.intent_stale_s, positive=True, hi=60.0))
        set_("max_peers", check.integer("max_peers", self.max_peers, lo=1, hi=255))
        set_("state_rate_hz", check.number("state_rate_hz", self.state_rate_hz, lo=0.5, hi=50.0))
        set_("intent_resend_s", check.number("intent_resend_s", self.intent_resend_s, lo=0.05, hi=10.0))
        check.boolean("keep_right", self.keep_right)
        set_("deadlock_after_s", check.number("deadlock_after_s", self.deadlock_after_s, positive=True, hi=600.0))
        set_("deadlock_progress_m", check.number("deadlock_progress_m", self.deadlock_progress_m, lo=0.0, hi=100.0))
        set_("recovery_s", check.number("recovery_s", self.recovery_s, lo=0.0, hi=600.0))
        if self.origin is not None:
            if not isinstance(self.origin, (list, tuple)) or len(self.origin) != 3:
                raise ConfigError(f"origin = {self.origin!r} must be [latitude deg, longitude deg, altitude m AMSL]")
            set_("origin", (check.number("origin latitude", self.origin[0], lo=-90.0, hi=90.0),
                            check.number("origin longitude", self.origin[1], lo=-180.0, hi=180.0),
                            check.number("origin altitude", self.origin[2], lo=-1000.0, hi=20000.0)))
        if self.intent_resend_s >= self.intent_stale_s:
            raise ConfigError(f"intent_resend_s = {self.intent_resend_s:g} must be < intent_stale_s = "
                              f"{self.intent_stale_s:g}: a peer would let the intent go stale between sendings")
