"""Measured against modelled velocity of an identification (``companion identify --plot``)."""

from __future__ import annotations

import logging
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from companion.core.planner.vehicle_model import AxisResponse  # noqa: E402

logger = logging.getLogger(__name__)


def plot_identification(log, result, out_dir: str | Path, reference_lag_s: float = 0.3, dt: float = 0.05) -> Path:
    """Draw command, measured, modelled and reference-lag velocity per NED axis; return the PNG path.

    ``log`` has ``segments`` (t, command, velocity) on a ``dt`` grid and ``result`` the fitted
    ``horizontal`` and ``vertical`` :class:`AxisResponse` (``companion.offline.identify``).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    lag = AxisResponse(p_gain_per_s=1.0 / reference_lag_s)
    fig, axes = plt.subplots(3, 1, figsize=(11, 8), sharex=True)
    for k, (ax, name) in enumerate(zip(axes, ("north", "east", "down"))):
        model = result.horizontal if k < 2 else result.vertical
        for i, (t, cmd, vel) in enumerate(log.segments):
            first = i == 0
            ax.step(t, cmd[:, k], where="post", color="0.6", lw=1, label="command" if first else None)
            ax.plot(t, vel[:, k], color="k", lw=1.2, label="measured" if first else None)
            ax.plot(t, model.velocities(cmd[:, k], vel[0, k], dt), color="tab:blue", lw=1.2,
                    label="identified model" if first else None)
            ax.plot(t, lag.velocities(cmd[:, k], vel[0, k], dt), color="tab:red", lw=1, ls="--",
                    label=f"lag {reference_lag_s:g} s" if first else None)
        ax.set_ylabel(f"v {name} [m/s]")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time in OFFBOARD [s]")
    fig.suptitle("velocity response: measured vs modelled (open loop from the logged commands)")
    fig.tight_layout()
    path = out / "identify_velocity.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    logger.info("wrote %s", path)
    return path
