"""The fleet's intents: which peers a plan predicts along their announced plans, and which it leaves out.

A peer is a track like any other (its state announcements, ODOMETRY, feed the obstacle
tracker under its key ``(system id, component id, link)``). Its intents
(:class:`~companion.core.intent.Intent`, stamps already on the vehicle's time base) are
kept here under the same key. When the request builder has predicted its tracks at
constant velocity, :meth:`PeerIntents.predict` replaces a peer's row by its intent if the
coordination mode uses it and the intent is fresh; :meth:`PeerIntents.gives_way` says which
peers a prioritised drone leaves to give way (``[fleet]``, :mod:`companion.loop.fleet_config`),
as long as their announced plans keep clear of its own (:meth:`PeerIntents.along`: the request
builder checks).

Bounded: at most ``max_peers`` intents are kept (a new peer beyond them replaces the one
heard from longest ago, counted). Pure: times are the caller's (vehicle time, s).
"""

from __future__ import annotations

import logging
from collections import Counter
from typing import Hashable

import numpy as np

from companion.core.intent import Intent, intent_covariances, intent_means
from companion.loop.fleet_config import FleetConfig

logger = logging.getLogger(__name__)


def system_of(key: Hashable) -> int | None:
    """The MAVLink system id of a track key ``(system, component, link)``; None for other keys (ADS-B...)."""
    if isinstance(key, tuple) and key and isinstance(key[0], int) and not isinstance(key[0], bool):
        return key[0]
    return None


class PeerIntents:
    """The latest intent of each peer, by track key.

    Parameters
    ----------
    config : the ``[fleet]`` section.
    own_system : this drone's MAVLink system id (its priority in ``prioritised``); None until the
        vehicle is known (then no peer outranks it and none gives way).
    """

    def __init__(self, config: FleetConfig, own_system: int | None) -> None:
        self.config = config
        self.own_system = None if own_system is None else int(own_system)
        self._intents: dict[Hashable, Intent] = {}
        self._peers: set[Hashable] = set()   # keys that ever announced an intent (bounded as the intents)
        #: what happened to intents: ``received``, ``withdrawn``, ``evicted``, ``own`` (an intent under
        #: this drone's own system id, never used), ``used`` and ``stale`` (per track and replan),
        #: ``not_giving_way`` (per replan: a lower-priority peer whose plan came too close to this
        #: drone's, so planned around)
        self.counts: Counter = Counter()

    def __len__(self) -> int:
        return len(self._intents)

    def update(self, key: Hashable, intent: Intent | None) -> None:
        """Keep ``intent`` as ``key``'s latest (an older one than kept is ignored); None withdraws it."""
        if system_of(key) == self.own_system:
            self.counts["own"] += 1
            return
        if key not in self._peers and len(self._peers) < 4 * self.config.max_peers:
            self._peers.add(key)
        if intent is None:
            if self._intents.pop(key, None) is not None:
                self.counts["withdrawn"] += 1
            return
        held = self._intents.get(key)
        if held is not None and intent.t0_s < held.t0_s:
            self.counts["out_of_order"] += 1
            return
        if held is None and len(self._intents) >= self.config.max_peers:
            oldest = min(self._intents, key=lambda k: self._intents[k].t0_s)
            del self._intents[oldest]
            self.counts["evicted"] += 1
            logger.warning("fleet: more than %d peers announce intents; %s's is forgotten", self.config.max_peers, oldest)
        self._intents[key] = intent
        self.counts["received"] += 1

    def forget(self, key: Hashable) -> None:
        """Drop ``key``'s intent (its track was dropped): it is no longer a peer."""
        self._intents.pop(key, None)
        self._peers.discard(key)

    def is_peer(self, key: Hashable) -> bool:
        """Whether ``key`` has announced an intent (even one withdrawn since): a drone of the fleet,
        which keeps the fleet's rules of the road (:mod:`companion.loop.right_of_way`)."""
        return key in self._peers

    def keys(self) -> list:
        return list(self._intents)

    def fresh(self, key: Hashable, t_v: float) -> Intent | None:
        """``key``'s intent if it was made at most ``intent_stale_s`` before ``t_v``, else None."""
        intent = self._intents.get(key)
        if intent is None or t_v - intent.t0_s > self.config.intent_stale_s:
            return None
        return intent

    def _outranks_me(self, key: Hashable) -> bool:
        system = system_of(key)
        return system is not None and self.own_system is not None and system < self.own_system

    def gives_way(self, key: Hashable, t_v: float) -> bool:
        """Whether the plan leaves ``key`` out: ``prioritised``, a peer of lower priority (higher
        system id) with a fresh intent, which gives way to this drone."""
        if self.config.coordination != "prioritised" or self.own_system is None or self._outranks_me(key):
            return False
        return system_of(key) is not None and self.fresh(key, t_v) is not None

    def predict(self, key: Hashable, times_s: np.ndarray, position_cov_now: np.ndarray,
                t_v: float) -> tuple[np.ndarray, np.ndarray] | None:
        """Means (N, 3) NED m and covariances (N, 3, 3) m^2 of ``key`` at ``times_s`` along its intent,
        or None when the mode does not use it or it is not fresh (the caller keeps constant velocity).

        The covariance is the track's at ``t_v`` (``position_cov_now``, m^2) plus
        ``intent_growth_m2ps`` for every second since the intent was made.
        """
        mode = self.config.coordination
        if mode == "decentralised" or key not in self._intents:
            return None
        if mode == "prioritised" and not self._outranks_me(key):
            return None
        intent = self.fresh(key, t_v)
        if intent is None:
            self.counts["stale"] += 1
            return None
        self.counts["used"] += 1
        return self.along(key, times_s, position_cov_now, t_v)

    def along(self, key: Hashable, times_s: np.ndarray, position_cov_now: np.ndarray,
              t_v: float) -> tuple[np.ndarray, np.ndarray] | None:
        """``key``'s fresh intent at ``times_s`` as :meth:`predict` gives it, whatever the mode and
        priority (means (N, 3) NED m, covariances (N, 3, 3) m^2), or None without a fresh one."""
        intent = self.fresh(key, t_v)
        if intent is None:
            return None
        means = intent_means(intent, times_s)
        covs = intent_covariances(position_cov_now, intent.t0_s, times_s, self.config.intent_growth_m2ps)
        return means, covs

    def summary(self) -> dict:
        """Counts for the run report, and the peers held."""
        return {"peers_with_intent": len(self._intents), **{f"intents_{k}": v for k, v in sorted(self.counts.items())}}
