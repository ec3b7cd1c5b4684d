"""Confidence ellipses of 3-D Gaussians in the top view (east right, north up): one helper for every figure."""

from __future__ import annotations

import logging
import math

import numpy as np
from matplotlib.patches import Ellipse

from companion.core.overlap import touch_radius

logger = logging.getLogger(__name__)

VIEWS = ("slice", "shadow")


def top_view_ellipse(cov: np.ndarray, confidence: float, *, view: str = "slice") -> tuple[float, float, float]:
    """The ``confidence`` ellipsoid of a 3-D Gaussian seen from above, as an ellipse.

    The ellipsoid is ``d' S^-1 d <= r^2`` with ``r = touch_radius(confidence, 3)`` (the
    contour the planner keeps apart). ``view="slice"``: its cut by the horizontal plane
    through its centre, ``[dx dy] A [dx dy]' <= r^2`` with ``A`` the north-east block of
    ``S^-1``. ``view="shadow"``: its projection onto the horizontal plane, which uses the
    inverse of the north-east block of ``S`` itself and is larger when north/east
    correlate with down.

    Parameters
    ----------
    cov : (3, 3) position covariance, NED, m^2.
    confidence : the contour, e.g. ``c_min``.
    view : ``"slice"`` or ``"shadow"``.

    Returns
    -------
    width_east, height_north, angle_deg : full axis lengths (m) along east and north
        before rotation, and the rotation (degrees counter-clockwise from east) for a
        plot with east on the horizontal axis and north on the vertical.
    """
    if view not in VIEWS:
        raise ValueError(f"view must be one of {VIEWS}, got {view!r}")
    r = float(touch_radius(confidence, 3))
    cov = np.asarray(cov, dtype=float)
    a_ne = np.linalg.inv(cov)[:2, :2] if view == "slice" else np.linalg.inv(cov[:2, :2])
    # Plot coordinates (east, north) = (y, x): swap the NED block.
    a_plot = a_ne[::-1, ::-1]
    evals, evecs = np.linalg.eigh(a_plot)
    semi = r / np.sqrt(np.maximum(evals, 1e-300))
    angle = math.degrees(math.atan2(evecs[1, 0], evecs[0, 0]))
    return 2.0 * semi[0], 2.0 * semi[1], angle


def top_view_patch(center_ned: np.ndarray, cov: np.ndarray, confidence: float, *, view: str = "slice",
                   **style) -> Ellipse:
    """A matplotlib patch of :func:`top_view_ellipse` centred on ``center_ned`` (metres, NED)."""
    w, h, angle = top_view_ellipse(cov, confidence, view=view)
    return Ellipse((center_ned[1], center_ned[0]), w, h, angle=angle, **style)


def slice_ellipse(cov: np.ndarray, confidence: float) -> tuple[float, float, float]:
    """:func:`top_view_ellipse` with ``view="slice"`` (the flight figures' ellipses)."""
    return top_view_ellipse(cov, confidence, view="slice")
