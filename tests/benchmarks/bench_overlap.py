"""Batched ``minmax`` on 10,000 random 3-D pairs against a per-pair ``scipy.optimize.brentq`` loop.

Rows: the median wall time of one batched call (30 repeats, target <= 10 ms); the
brentq loop solving the same admissibility condition pair by pair, timed on a subset
and scaled to all pairs, and the speed-up; the largest relative admissibility
residual; the largest relative disagreement between the two ``eta``.
"""

from __future__ import annotations

import time

import numpy as np
from scipy import optimize

from companion.core.overlap import minmax

PAIRS = 10_000
REPEATS = 30
BRENTQ_SUBSET = 500


def random_pairs(n: int = PAIRS, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Seeded 3-D pairs: random rotations, eigenvalues log-uniform so condition numbers span 1 to ~1e4."""
    rng = np.random.default_rng(seed)

    def covs() -> np.ndarray:
        q = np.linalg.qr(rng.standard_normal((n, 3, 3)))[0]
        spread = rng.uniform(0.0, 4.0, (n, 1))  # decades between smallest and largest eigenvalue
        ev = 10.0 ** (rng.uniform(-2.0, 0.0, (n, 1)) + spread * rng.uniform(0.0, 1.0, (n, 3)))
        c = np.einsum("nij,nj,nkj->nik", q, ev, q)
        return 0.5 * (c + np.swapaxes(c, -1, -2))

    mu1 = rng.uniform(-10, 10, (n, 3))
    mu2 = mu1 + rng.standard_normal((n, 3)) * rng.uniform(0.1, 5.0, (n, 1))
    return mu1, covs(), mu2, covs()


def brentq_pair(mu1: np.ndarray, cov1: np.ndarray, mu2: np.ndarray, cov2: np.ndarray) -> tuple[float, float]:
    """Solve ``lam^2 a'S1a - (1-lam)^2 a'S2a = 0`` on (0, 1) with brentq; return (lam, eta)."""
    delta = mu2 - mu1

    def f(lam: float) -> float:
        a = np.linalg.solve(lam * cov1 + (1 - lam) * cov2, delta)
        return lam * np.sqrt(a @ cov1 @ a) - (1 - lam) * np.sqrt(a @ cov2 @ a)

    lam = optimize.brentq(f, 1e-12, 1 - 1e-12, xtol=1e-15, rtol=4 * np.finfo(float).eps)
    a = np.linalg.solve(lam * cov1 + (1 - lam) * cov2, delta)
    return lam, lam * float(np.sqrt(a @ cov1 @ a))


def run() -> list[dict]:
    mu1, cov1, mu2, cov2 = random_pairs()
    res = minmax(mu1, cov1, mu2, cov2)  # warm-up
    times = []
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        res = minmax(mu1, cov1, mu2, cov2)
        times.append(time.perf_counter() - t0)
    batched_ms = 1e3 * float(np.median(times))

    idx = np.arange(BRENTQ_SUBSET)
    t0 = time.perf_counter()
    ref = np.array([brentq_pair(mu1[i], cov1[i], mu2[i], cov2[i]) for i in idx])
    brentq_ms = 1e3 * (time.perf_counter() - t0) * PAIRS / BRENTQ_SUBSET
    eta_rel = float(np.max(np.abs(res.eta[idx] - ref[:, 1]) / ref[:, 1]))
    lam_abs = float(np.max(np.abs(res.lam[idx] - ref[:, 0])))
    residual = float(np.max(np.abs(res.residual) / res.eta))
    speedup = brentq_ms / batched_ms
    return [
        {
            "name": "minmax batched, 10k 3-D pairs",
            "value": batched_ms,
            "unit": "ms",
            "target": "<= 3",
            "note": f"median of {REPEATS} calls; condition numbers 1..1e4",
        },
        {
            "name": "minmax vs per-pair brentq",
            "value": speedup,
            "unit": "x",
            "target": ">= 100",
            "peer": f"{brentq_ms:.0f} ms",
            "ratio": speedup,
            "note": f"brentq timed on {BRENTQ_SUBSET} pairs, scaled x{PAIRS // BRENTQ_SUBSET}; same run",
        },
        {
            "name": "max relative admissibility residual",
            "value": residual,
            "unit": "",
            "target": "<= 1e-10",
            "note": "|eta1 - eta2| / eta over all 10k pairs",
        },
        {
            "name": "max relative eta difference vs brentq",
            "value": eta_rel,
            "unit": "",
            "target": "<= 1e-9",
            "note": f"on the {BRENTQ_SUBSET} brentq pairs; max |lam diff| {lam_abs:.1e}",
        },
    ]
