"""The paper's trajectory-optimisation figure for one plan (matplotlib, Agg backend).

(a) top view (north up, east right) of the drone and obstacle mean paths with their
``c_min`` confidence ellipses (the shadow of the 3-D ellipsoid of radius ``r_min``, i.e.
the ellipse of the 2x2 north-east block) and the body radii; (b) contour of touch over
time per obstacle with the ``c_min``/``c_max`` lines; (c) Mahalanobis distance from the
drone to the goal over time.
"""

from __future__ import annotations

import logging
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Circle  # noqa: E402

from companion.core.planner import Plan, PlannerConfig, PlanRequest  # noqa: E402
from companion.plots.ellipses import top_view_patch  # noqa: E402

logger = logging.getLogger(__name__)


def plot_plan(path: str | Path, request: PlanRequest, plan: Plan, config: PlannerConfig, title: str = "") -> Path:
    """Draw the three panels for ``plan`` and save a PNG.

    Parameters
    ----------
    path : str or Path
        Output file; parent folders are created.
    request, plan, config
        The problem, its solution and the planner configuration.
    title : str
        Figure title.

    Returns
    -------
    Path
        The file written.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    n = request.horizon_steps
    t = config.step_s * np.arange(1, n + 1)
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.8))
    ax = axes[0]
    drone = np.vstack([request.position, plan.positions])
    ax.plot(drone[:, 1], drone[:, 0], "o-", color="tab:blue", ms=3, label="drone")
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"][1:]
    for i in range(n):
        ax.add_patch(top_view_patch(plan.positions[i], request.drone_covs[i], config.c_min, view="shadow",
                                    fc="tab:blue", alpha=0.15))
    ax.add_patch(Circle((plan.positions[-1, 1], plan.positions[-1, 0]), config.drone_radius_m, fill=False, color="tab:blue"))
    for j in range(request.num_obstacles):
        c = colors[j % len(colors)]
        m = request.obstacle_means[j]
        ax.plot(m[:, 1], m[:, 0], "s--", color=c, ms=3, label=f"obstacle {j + 1}")
        for i in range(n):
            ax.add_patch(top_view_patch(m[i], request.obstacle_covs[j, i], config.c_min, view="shadow", fc=c, alpha=0.12))
        k = int(np.argmin(plan.contour_of_touch[j]))
        ax.add_patch(Circle((m[k, 1], m[k, 0]), request.obstacle_radii[j], fill=False, color=c))
        ax.add_patch(Circle((plan.positions[k, 1], plan.positions[k, 0]), config.drone_radius_m, fill=False,
                            color="tab:blue", ls=":"))
    for a, b in zip(request.walls_normal, request.walls_offset):
        # a.p = b in the north-east plane: points b a + s (a rotated)
        d = np.array([-a[1], a[0]])
        s = np.linspace(-30, 30, 2)
        ax.plot(b * a[1] + s * d[1], b * a[0] + s * d[0], "k-", lw=2)
    ax.plot(request.target[1], request.target[0], "k*", ms=12, label="goal")
    ax.set_xlabel("east y [m]")
    ax.set_ylabel("north x [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title(f"(a) paths, {config.c_min:.0%} ellipses at every step")
    ax.legend(fontsize=8)
    ax = axes[1]
    for j in range(request.num_obstacles):
        ax.plot(t, plan.contour_of_touch[j], "o-", ms=3, color=colors[j % len(colors)], label=f"obstacle {j + 1}")
    ax.axhline(config.c_min, color="r", ls="--", label=f"c_min {config.c_min:.0%}")
    if config.c_max is not None:
        ax.axhline(config.c_max, color="g", ls="--", label=f"c_max {config.c_max:.0%}")
    ax.set_ylim(0.0, 1.02)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("contour of touch c")
    ax.set_title("(b) contour of touch (exact, with radii)")
    ax.legend(fontsize=8)
    ax = axes[2]
    diff = plan.positions - request.target
    maha = np.sqrt(np.einsum("nk,nkl,nl->n", diff, np.linalg.inv(request.drone_covs), diff))
    ax.plot(t, maha, "o-", ms=3)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("Mahalanobis distance to goal")
    ax.set_title("(c) distance to goal")
    fig.suptitle(f"{title}: {plan.status}, {plan.iterations} SCP iterations, {plan.solve_time_s * 1e3:.1f} ms")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    logger.info("wrote %s", path)
    return path
