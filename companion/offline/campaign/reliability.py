"""Promise against truth: a reliability diagram of the collision probability the contours promise.

For every (step, obstacle) pair in sensing range, the realised contour of touch ``c``
between the drone's and the obstacle's current estimates promises a collision
probability of at most ``p = Phi(-r(c))``, ``r(c) = sqrt(chi2_3.ppf(c))`` (1/2 when the
inflated ellipsoids already overlap, 0 for ``c = 1``). The truth says whether the
bodies overlapped at that instant. Pairs are binned by ``p`` (decades); per bin the
observed frequency gets a 95 % Clopper-Pearson interval. A bin *exceeds its promise*
when the interval's lower end lies above the bin's mean promise; ``observed / promised``
(hits over the sum of ``p``) says how conservative the promise is (1: exact, < 1:
conservative).

The promise is evaluated on the estimates each replan started from (the state the
previous plan was to keep outside ``c_min``), not on the plan's own predicted contours,
which the replan records do not keep.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
import numpy as np

from companion.offline.campaign.jsonable import to_jsonable

logger = logging.getLogger(__name__)

#: Bin edges of the promised probability: decades from 1e-6, the last bin up to 1/2 (overlap).
PROMISE_EDGES = (0.0, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 0.5)


def promise_bin(p: float) -> int:
    """Index of the bin of promised probability ``p`` in [0, 1/2]."""
    return int(min(max(np.searchsorted(PROMISE_EDGES, p, side="right") - 1, 0), len(PROMISE_EDGES) - 2))


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
