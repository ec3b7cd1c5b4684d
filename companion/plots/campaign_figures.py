"""Figures of a safety campaign: collision rate by method, smallest contour of touch per episode,
and the reliability diagrams (promised collision probability against the frequency observed in truth)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Mapping

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

logger = logging.getLogger(__name__)


def plot_campaign(summary: Mapping[str, Any], directory: str | Path, *, c_min: float, title: str = "campaign") -> list[Path]:
    """Draw ``collision_rate.png``, ``min_contour_ecdf.png``, ``reliability.png`` (the plan's
    promise) and ``reliability_estimates.png`` (the estimates' promise) into ``directory``.

    Parameters
    ----------
    summary : mapping of method name to summary
        Per-method summaries (``MethodSummary`` of :mod:`companion.offline.campaign.stats`,
        read by attribute): ``collision_rate``, ``collision_ci95``, ``collisions``,
        ``episodes``, ``min_realised_contour`` (one value per episode, ``None`` when no
        obstacle came within sensing range), ``plan_reliability`` and ``reliability`` (bins
        with ``pairs``, ``hits``, ``promised_mean``, ``observed``, ``observed_ci95``), their
        ``plan_observed_over_promised`` and ``observed_over_promised``, ``drone_nees_mean``
        and ``relative_nees_mean`` (drawn beside the diagram).
    directory : output folder (created).
    c_min : the contour of touch the constraint protects (drawn as a line).
    title : figure title prefix.

    Returns
    -------
    list of Path
        The files written.
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    methods = list(summary)
    written = []

    fig, ax = plt.subplots(figsize=(6.0, 3.6))
    rates = np.array([summary[m].collision_rate or 0.0 for m in methods])
    ci = np.array([summary[m].collision_ci95 for m in methods]).reshape(-1, 2)
    x = np.arange(len(methods))
    ax.bar(x, rates, color="tab:blue", alpha=0.7)
    ax.errorbar(x, rates, yerr=[rates - ci[:, 0], ci[:, 1] - rates], fmt="none", ecolor="k", capsize=5,
                label="95 % Clopper-Pearson")
    for xi, m in zip(x, methods):
        s = summary[m]
        ax.annotate(f"{s.collisions}/{s.episodes}", (xi, ci[xi, 1]), textcoords="offset points", xytext=(0, 4),
                    ha="center", fontsize=8)
    ax.set_xticks(x, methods)
    ax.set_ylabel("episodes with a collision")
    ax.set_ylim(0.0, max(0.05, float(ci[:, 1].max()) * 1.2))
    ax.set_title(f"{title}\ncollision rate by method", fontsize=9)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    path = directory / "collision_rate.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    written.append(path)

    fig, ax = plt.subplots(figsize=(6.0, 3.6))
    styles = ("-", "--", "-.", ":")
    for i, m in enumerate(methods):
        values = np.sort([v for v in summary[m].min_realised_contour if v is not None])
        if values.size:
            # ECDF, closed on the right at c = 1 (most episodes never come near: c = 1.0)
            x = np.concatenate([[0.0], values, [1.0]])
            y = np.concatenate([[0.0], np.arange(1, values.size + 1) / values.size, [1.0]])
            below = int(np.sum(values < c_min))
            ax.step(x, y, where="post", linestyle=styles[i % len(styles)], linewidth=1.5,
                    label=f"{m}: {below}/{values.size} below c_min")
    ax.axvline(c_min, color="k", linestyle="--", linewidth=0.8, label=f"c_min = {c_min:.2f}")
    ax.set_xlim(0.0, 1.02)
    ax.set_xlabel("smallest realised contour of touch in the episode")
    ax.set_ylabel("share of episodes (ECDF)")
    ax.set_title(f"{title}\nsmallest contour of touch", fontsize=9)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    path = directory / "min_contour_ecdf.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    written.append(path)
    written.append(_reliability(summary, directory / "reliability.png", f"{title}\nthe plan's promise (first step) against truth",
                                "plan_reliability", "plan_observed_over_promised"))
    written.append(_reliability(summary, directory / "reliability_estimates.png",
                                f"{title}\nthe estimates' promise against truth", "reliability", "observed_over_promised"))
    logger.info("wrote %s", ", ".join(str(p) for p in written))
    return written


def _reliability(summary: Mapping[Any, Any], path: Path, title: str, bins_attr: str, ratio_attr: str,
                 label: Any = lambda key, s: str(key)) -> Path:
    """Promised collision probability per (step, obstacle) pair against the observed frequency.

    Log-log; per bin of promised probability, the observed frequency with its 95 %
    Clopper-Pearson interval; a bin with no hit is drawn at its upper limit (a downward
    triangle): the truth allows at most that. Points under the diagonal keep the promise.
    Beside the axes, per curve: pairs, hits, observed/promised and the mean NEES of the
    drone's and the relative estimates (3 for consistent filters). ``summary`` maps a curve's
    key (a method, or a ``c_min``) to its summary; ``label(key, summary)`` names the curve.
    """
    fig, (ax, side) = plt.subplots(1, 2, figsize=(8.6, 4.8), gridspec_kw={"width_ratios": [1.0, 0.55]})
    floor, top = 1e-7, 1.0
    markers = ("o", "s", "D", "^")
    n_methods = max(len(summary), 1)
    notes = []
    for i, (key, s) in enumerate(summary.items()):
        m = label(key, s)
        bins = [b for b in getattr(s, bins_attr) if b.pairs > 0]
        color = f"C{i}"
        ratio = getattr(s, ratio_attr)
        over = sum(b.exceeds_promise for b in bins)
        notes.append((color, f"{m}\n  pairs {sum(b.pairs for b in bins)}, hits {sum(b.hits for b in bins)}\n"
                             f"  observed/promised {'-' if ratio is None else format(ratio, '.2g')}\n"
                             f"  bins above promise: {over}\n"
                             f"  NEES drone {_num(s.drone_nees_mean)}, relative {_num(s.relative_nees_mean)}"))
        if not bins:
            continue
        shift = 10 ** (0.06 * (i - (n_methods - 1) / 2))  # side by side within a bin
        x = np.array([max(b.promised_mean, floor) for b in bins]) * shift
        lo = np.array([b.observed_ci95[0] for b in bins])
        hi = np.array([b.observed_ci95[1] for b in bins])
        obs = np.array([b.observed for b in bins])
        hit = obs > 0
        if hit.any():
            ax.errorbar(x[hit], obs[hit], yerr=[obs[hit] - np.maximum(lo[hit], floor), hi[hit] - obs[hit]],
                        fmt=markers[i % len(markers)], color=color, capsize=3, label=f"{m}")
        if (~hit).any():
            ax.plot(x[~hit], hi[~hit], "v", color=color, alpha=0.7,
                    label=f"{m}: no hit (95 % upper limit)")
    ax.plot([floor, 0.5], [floor, 0.5], "k--", linewidth=0.8, label="promise kept exactly")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlim(floor, top)
    ax.set_ylim(floor, top)
    ax.set_xlabel("promised collision probability Phi(-r(c)) per (step, obstacle)")
    ax.set_ylabel("observed collision frequency (95 % Clopper-Pearson)")
    ax.set_title(title, fontsize=8)
    ax.legend(loc="lower right", fontsize=7)
    side.axis("off")
    for i, (color, text) in enumerate(notes):
        side.text(0.0, 1.0 - 0.25 * i, text, transform=side.transAxes, fontsize=7.5, va="top", color=color,
                  family="monospace")
    side.text(0.0, 0.0, "NEES: mean over replans;\n3 if the filters are consistent", transform=side.transAxes,
              fontsize=7, va="bottom", color="0.3")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _num(x: float | None) -> str:
    return "-" if x is None else f"{x:.2f}"


def plot_reliability_by_c_min(campaigns: Mapping[float, Mapping[str, Any]], directory: str | Path, *,
                              title: str) -> list[Path]:
    """One reliability diagram per method, one curve per ``c_min``: ``reliability_METHOD.png``.

    Parameters
    ----------
    campaigns : ``{c_min: {method: summary}}`` (``MethodSummary``: ``plan_reliability``,
        ``plan_observed_over_promised``, ``drone_nees_mean``, ``relative_nees_mean``,
        ``episodes``); a method may be missing at some ``c_min``.
    directory : output folder (created).
    title : figure title prefix (family, seed, noise model).
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    methods = list(dict.fromkeys(m for per in campaigns.values() for m in per))
    written = []
    for method in methods:
        per_c = {c: per[method] for c, per in sorted(campaigns.items()) if method in per}
        path = directory / f"reliability_{method}.png"
        _reliability(per_c, path, f"{title}\n{method}: the plan's promise (first step) against truth",
                     "plan_reliability", "plan_observed_over_promised",
                     label=lambda c, s: f"c_min {c:.2f} ({s.episodes} ep.)")
        written.append(path)
    return written
