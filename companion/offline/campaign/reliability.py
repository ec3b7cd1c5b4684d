"""Promise against truth: a reliability diagram of the collision probability the contours promise.

A contour of touch ``c`` between the drone's and an obstacle's Gaussians promises a
collision probability of at most ``p = Phi(-r(c))``, ``r(c) = sqrt(chi2_3.ppf(c))`` (1/2
when the inflated ellipsoids already overlap, 0 for ``c = 1``). Two promises are scored
against the simulator's truth, per (replan step, obstacle) pair:

*the plan's* (the reliability diagram): the contour the plan kept at its first step
    between the planned drone position and the obstacle's prediction, for every track the
    plan constrained within sensing range; the truth one step later (``step_s``, the
    next replan) says whether the bodies overlapped. This is the chance constraint's own
    promise, with everything that can break it: filter consistency, the obstacle's
    prediction, the vehicle's tracking of the plan.
*the estimates'*: the realised contour between the current estimates at the replan, the
    truth at that instant (filter consistency alone).

Pairs are binned by ``p`` (decades); per bin the observed frequency gets a 95 %
Clopper-Pearson interval. A bin *exceeds its promise* when the interval's lower end lies
above the bin's mean promise; ``observed / promised`` (hits over the sum of ``p``) says
how conservative the promise is (1: exact, < 1: conservative).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
import numpy as np
from scipy import special

from companion.offline.campaign.jsonable import to_jsonable

logger = logging.getLogger(__name__)

#: Bin edges of the promised probability: decades from 1e-6, the last bin up to 1/2 (overlap).
PROMISE_EDGES = (0.0, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 0.5)


def promise_bin(p: float) -> int:
    """Index of the bin of promised probability ``p`` in [0, 1/2]."""
    return int(min(max(np.searchsorted(PROMISE_EDGES, p, side="right") - 1, 0), len(PROMISE_EDGES) - 2))


def promised_probability(contour: float) -> float:
    """``Phi(-r(c))``, ``r(c) = sqrt(chi2_3.ppf(c))``: 1/2 for ``c = 0`` (overlap), 0 for ``c = 1``.

    Written with the special functions scipy.stats evaluates for these two (``chi2_3.ppf(c)
    = 2 gammaincinv(3/2, c)``, ``Phi = ndtr``): the same numbers without the distribution
    objects' argument handling, which cost about 0.1 ms a call (tests/offline/test_campaign.py
    checks them against scipy.stats).
    """
    c = min(max(float(contour), 0.0), 1.0)
    if c >= 1.0:
        return 0.0
    return float(special.ndtr(-math.sqrt(2.0 * special.gammaincinv(1.5, c))))


class PromiseTally:
    """Per-bin counts of one episode's promises: pairs, true overlaps and the sum of promised ``p``."""

    def __init__(self) -> None:
        n = len(PROMISE_EDGES) - 1
        self.pairs, self.hits, self.sums = [0] * n, [0] * n, [0.0] * n

    def add(self, p: float, hit: bool) -> None:
        """One (step, obstacle) pair promised ``p``; ``hit``: the bodies truly overlapped."""
        b = promise_bin(p)
        self.pairs[b] += 1
        self.hits[b] += int(hit)
        self.sums[b] += p


@dataclass(frozen=True)
class ReliabilityBin:
    """One bin of the reliability diagram (probabilities per (step, obstacle) pair)."""

    lo: float
    hi: float
    pairs: int
    hits: int
    promised_mean: float | None  #: mean promised p over the bin's pairs
    observed: float | None       #: hits / pairs
    observed_ci95: tuple[float, float]
    exceeds_promise: bool        #: the interval's lower end lies above promised_mean

    def to_json(self) -> dict:
        return to_jsonable(self)


def observed_over_promised(hits: int, promised_sum: float) -> float | None:
    """Hits over the expected hits the promises allow (``None`` when nothing was promised)."""
    return hits / promised_sum if promised_sum > 0 and math.isfinite(promised_sum) else None
