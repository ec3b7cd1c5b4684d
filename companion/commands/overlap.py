"""``companion overlap`` and ``companion overlap-table``: the overlap-of-Gaussians maps.

``overlap`` converts one contour of touch (or one overlap, ``--overlap``) to the touch
radius and overlap; ``overlap-table`` prints the paper's table for 2-D and 3-D, the
Bhattacharyya demonstration (two pairs with equal overlap, different distances) and,
with ``--plot``, the paper's figure.
"""

from __future__ import annotations

import argparse
import json
import logging

from companion.commands._argtypes import integer_at_least, open_unit_interval
from companion.errors import InputError

logger = logging.getLogger(__name__)

#: Contours of touch in the printed table; includes the reference rows of docs/METHOD.md section 1.6.
TABLE_CONFIDENCES = (0.05, 0.10, 0.20, 0.30, 0.40, 0.50, 0.60, 0.70, 0.80, 0.8051, 0.90, 0.95, 0.99)
#: (dim, c) reference rows of docs/METHOD.md section 1.6, marked on the figure.
REFERENCE_ROWS = ((2, 0.8051), (3, 0.60), (3, 0.30), (3, 0.90), (2, 0.90))
#: The paper's Bhattacharyya pairs: (label, cov1, cov2, separation axis); the covariances as
#: nested tuples (numpy is imported when the table is printed, not with the parser).
BHATTACHARYYA_PAIRS = (
    ("S1=diag(0.01,0.02) S2=diag(0.03,0.03), along x", ((0.01, 0.0), (0.0, 0.02)), ((0.03, 0.0), (0.0, 0.03)), 0),
    ("S1=[[0.04,0],[0,0.02]] S2=[[0.02,0.01],[0.01,0.02]], along y", ((0.04, 0.0), (0.0, 0.02)), ((0.02, 0.01), (0.01, 0.02)), 1),
)


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``overlap`` and ``overlap-table`` subcommands."""
    p = subparsers.add_parser("overlap", help="touch radius and overlap for a contour of touch (or the inverse)")
    p.add_argument("--dim", type=integer_at_least(1), default=3, help="dimension of the Gaussians (default 3)")
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--confidence", type=open_unit_interval, help="contour of touch c in (0, 1)")
    which.add_argument("--overlap", type=open_unit_interval, help="overlap Y in (0, 1); prints the contour of touch")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    p.set_defaults(func=run_overlap)

    t = subparsers.add_parser("overlap-table", help="overlap against contour of touch (2-D, 3-D) and the Bhattacharyya demo")
    t.add_argument("--plot", metavar="FILE.png", help="also draw the paper's figure to this PNG")
    t.set_defaults(func=run_table)


def run_overlap(args: argparse.Namespace) -> int:
    """Print touch radius, overlap and contour of touch for one ``--confidence`` or ``--overlap``."""
    from companion.core.overlap import confidence_from_overlap, overlap_from_confidence, touch_radius

    if args.confidence is not None:
        c = args.confidence
    else:
        c = float(confidence_from_overlap(args.overlap, args.dim))
        if not 0.0 < c < 1.0:
            raise InputError(f"overlap {args.overlap} has no contour of touch in (0, 1) in {args.dim}-D")
    r = float(touch_radius(c, args.dim))
    y = float(overlap_from_confidence(c, args.dim))
    if args.json:
        print(json.dumps({"dim": args.dim, "confidence": c, "touch_radius": r, "overlap": y}))
    else:
        print(f"dim {args.dim}  contour of touch c = {c:.6g}  touch radius r = {r:.4f}  overlap Y = {y:.4f}")
    return 0


def bhattacharyya_demo(confidence: float = 0.8051) -> list[dict[str, float | str]]:
    """The paper's two pairs placed to touch at ``confidence`` in 2-D: equal overlap, different distances.

    ``eta`` is linear in the mean separation, so the separation is the touch radius over
    ``eta`` at unit separation.
    """
    import numpy as np

    from companion.core.overlap import bhattacharyya, minmax, touch_radius

    r = float(touch_radius(confidence, 2))
    rows: list[dict[str, float | str]] = []
    for label, cov1, cov2, axis in BHATTACHARYYA_PAIRS:
        cov1, cov2 = np.array(cov1), np.array(cov2)
        unit = np.eye(2)[axis]
        separation = r / float(minmax(np.zeros(2), cov1, unit, cov2).eta)
        mu2 = unit * separation
        res = minmax(np.zeros(2), cov1, mu2, cov2)
        rows.append(
            {
                "pair": label,
                "separation_m": separation,
                "contour_of_touch": float(res.confidence),
                "overlap": float(res.overlap),
                "bhattacharyya": float(bhattacharyya(np.zeros(2), cov1, mu2, cov2)),
            }
        )
    return rows


def run_table(args: argparse.Namespace) -> int:
    """Print the overlap table for 2-D and 3-D and the Bhattacharyya demonstration; plot if asked."""
    from companion.core.overlap import overlap_from_confidence, touch_radius

    print("Overlap of two Gaussians touching at confidence contour c")
    print(f"{'c':>8}  {'r (2-D)':>8}  {'Y (2-D)':>8}  {'r (3-D)':>8}  {'Y (3-D)':>8}")
    for c in TABLE_CONFIDENCES:
        cells = [f"{float(touch_radius(c, d)):8.4f}  {float(overlap_from_confidence(c, d)):8.4f}" for d in (2, 3)]
        print(f"{c:8.4f}  " + "  ".join(cells))
    print()
    print("Bhattacharyya distance is not a function of the overlap (pairs touching at c = 0.8051, 2-D):")
    for row in bhattacharyya_demo():
        print(
            f"  {row['pair']}: separation {row['separation_m']:.4f} m, overlap {row['overlap']:.4f}, "
            f"Bhattacharyya {row['bhattacharyya']:.4f}"
        )
    if args.plot:
        from companion.plots.overlap_figure import plot_overlap_vs_contour

        path = plot_overlap_vs_contour(args.plot, marks=REFERENCE_ROWS)
        print(f"wrote {path}")
    return 0
