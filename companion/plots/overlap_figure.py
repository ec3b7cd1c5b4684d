"""The paper's figure: overlap of two Gaussians against their confidence contour of touch."""

from __future__ import annotations

import logging
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from companion.core.overlap import overlap_from_confidence  # noqa: E402

logger = logging.getLogger(__name__)


def plot_overlap_vs_contour(
    path: str | Path,
    dims: tuple[int, ...] = (2, 3),
    marks: tuple[tuple[int, float], ...] = (),
) -> Path:
    """Draw overlap ``Y`` against contour of touch ``c`` for each dimension and save a PNG.

    Parameters
    ----------
    path : str or Path
        Output file (PNG); parent folders are created.
    dims : tuple of int
        Dimensions to draw, one curve each.
    marks : tuple of (dim, c)
        Points to mark and label on the curves (e.g. the reference rows).

    Returns
    -------
    Path
        The file written.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    c = np.linspace(0.01, 0.995, 400)
    fig, ax = plt.subplots(figsize=(6.0, 4.0), dpi=120)
    try:
        for d in dims:
            ax.plot(100 * c, overlap_from_confidence(c, d), label=f"{d}-D")
        for d, cm in marks:
            y = float(overlap_from_confidence(cm, d))
            ax.plot(100 * cm, y, "o", color="k", ms=3)
            ax.annotate(f"{y:.4f}", (100 * cm, y), textcoords="offset points", xytext=(4, 4), fontsize=7)
        ax.set_xlabel("contour of touch c [%]")
        ax.set_ylabel("overlap Y = 2 (1 - Phi(r))")
        ax.set_title("Overlap of two Gaussians touching at contour c")
        ax.grid(True, alpha=0.3)
        ax.legend()
        fig.tight_layout()
        fig.savefig(path)
    finally:
        plt.close(fig)
    logger.info("wrote %s", path)
    return path
