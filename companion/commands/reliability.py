"""``companion reliability``: the plan's promise against truth across campaigns of several ``c_min``.

Reads campaign results files (``companion campaign --results``; one campaign per file,
typically one per ``c_min``), prints per method and ``c_min``: episodes, scored (step,
obstacle) pairs, true overlaps, the overlaps the plans promised at most (the sum of their
``Phi(-r)``), observed over promised for the plan's promise and the
estimates' promise, the bins whose 95 % Clopper-Pearson interval lies above their promise,
and the mean NEES of the drone's and the relative estimates with its 95 % interval
(episodes as independent clusters: a consistent filter's interval holds 3); ``--plot DIR`` draws one
reliability diagram per method with one curve per ``c_min`` (``reliability_METHOD.png``).
Runs nothing: the figures come from the files alone.
"""

from __future__ import annotations

import argparse
import logging

from companion.errors import ConfigError

logger = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``reliability`` subcommand."""
    p = subparsers.add_parser("reliability", help="reliability diagrams across campaigns (one per c_min) from their results files",
                              description=__doc__.split("\n\n")[1])
    p.add_argument("results", nargs="+", metavar="RESULTS.jsonl", help="campaign results files (one campaign each)")
    p.add_argument("--plot", metavar="DIR", help="draw reliability_METHOD.png into DIR")
    p.set_defaults(func=run)


def _fmt(x: float | None, spec: str) -> str:
    return "-" if x is None else format(x, spec)


def _nees(mean: float | None, ci: tuple[float, float] | None) -> str:
    """``2.91 [2.79, 3.04]``: the pooled mean NEES and its 95 % interval (episodes as clusters)."""
    if mean is None:
        return "-"
    return f"{mean:.2f}" if ci is None else f"{mean:.2f} [{ci[0]:.2f}, {ci[1]:.2f}]"


def run(args: argparse.Namespace) -> int:
    """Summarise every file, print the table, draw the figures if asked."""
    from companion.offline.campaign import METHODS, summarise
    from companion.offline.campaign.store import read_results_file

    campaigns: dict[float, dict] = {}
    described: set[tuple] = set()
    for path in args.results:
        header, rows, _ = read_results_file(path)
        c_min = float(header["c_min"])
        if c_min in campaigns:
            raise ConfigError(f"{path}: a second campaign with c_min = {c_min:g}")
        described.add((header.get("family"), header.get("seed"), header.get("noise_correlation_s", 0.0)))
        methods = [m for m in METHODS if any(r.method == m for r in rows)]
        campaigns[c_min] = summarise(rows, methods, c_min)
    print(f"{'method':<14}{'c_min':>6}{'eps':>5}{'pairs':>8}{'hits':>6}{'promised':>10}{'plan obs/prom':>15}{'est obs/prom':>14}"
          f"{'NEES drone [95 %]':>26}{'NEES rel [95 %]':>24}  bins above their promise (plan)")
    for method in METHODS:
        for c_min, per in sorted(campaigns.items()):
            s = per.get(method)
            if s is None:
                continue
            used = [b for b in s.plan_reliability if b.pairs]
            over = [f"[{b.lo:.0e}, {b.hi:.0e}): {b.hits}/{b.pairs}, 95 % [{b.observed_ci95[0]:.1e}, {b.observed_ci95[1]:.1e}] "
                    f"against {b.promised_mean:.1e}" for b in used if b.exceeds_promise]
            promised = sum(b.promised_mean * b.pairs for b in used)  # expected overlaps if every promise were exact
            print(f"{method:<14}{c_min:>6.2f}{s.episodes:>5}{sum(b.pairs for b in used):>8}{sum(b.hits for b in used):>6}{promised:>10.3g}"
                  f"{_fmt(s.plan_observed_over_promised, '15.3g')}{_fmt(s.observed_over_promised, '14.3g')}"
                  f"{_nees(s.drone_nees_mean, s.drone_nees_ci95):>26}{_nees(s.relative_nees_mean, s.relative_nees_ci95):>24}"
                  f"  {'; '.join(over) or 'none'}")
    if args.plot:
        from companion.plots.campaign_figures import plot_reliability_by_c_min

        title = "; ".join(f"{f} campaign, seed {s}, " + (f"noise correlation {t:g} s" if t else "white noise")
                          for f, s, t in sorted(described, key=str))
        for path in plot_reliability_by_c_min(campaigns, args.plot, title=title):
            print(f"wrote {path}")
    return 0
