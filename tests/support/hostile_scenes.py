"""The antipodal scenario with hostile obstacle traffic added, for lockstep runs (issue 14).

- ``crowd200``: 200 stationary systems reporting ODOMETRY at 1 Hz from 4-9 m beside the
  route (:func:`companion.offline.crowd.positions_off_route`, the real-time crowd's places
  and accuracy);
- ``ring20``: 20 stationary systems on a 6 m ring round the route's midpoint, reporting at
  10 Hz (the route crosses the ring: the planner must find a gap or brake);
- ``cov1e30``: one more obstacle whose reports claim (and are drawn from) a covariance of
  1e30 m^2.

mavsim numbers the obstacles from system id 2 here, so 203 fit below 256.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from companion.offline.crowd import POSITION_VAR_M2, positions_off_route

ANTIPODAL = Path(__file__).resolve().parents[2] / "configs" / "antipodal.toml"
SCENES = ("crowd200", "ring20", "cov1e30")


def _static(name: str, p: np.ndarray, var: float, rate_hz: float) -> str:
    cov = f"[[{var!r}, 0.0, 0.0], [0.0, {var!r}, 0.0], [0.0, 0.0, {var!r}]]"
    return (f'\n[[world.obstacles]]\nname = "{name}"\nradius_m = 0.5\n'
            f"start_ned_m = [{p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}]\nvelocity_ned_mps = [0.0, 0.0, 0.0]\n"
            f"measurement_cov_m2 = {cov}\nreport_rate_hz = {rate_hz}\n")


def hostile_positions(scene: str) -> tuple[np.ndarray, float, float]:
    """(positions NED m, reported variance m^2, report rate Hz) of the systems ``scene`` adds."""
    start, goal = np.array([0.0, 0.0, -5.0]), np.array([24.0, 0.0, -5.0])
    if scene == "crowd200":
        return positions_off_route(start, goal, 200, seed=0), POSITION_VAR_M2, 1.0
    if scene == "ring20":
        a = np.linspace(0.0, 2.0 * np.pi, 20, endpoint=False) + np.pi / 20  # no system exactly on the route
        centre = (start + goal) / 2.0
        return centre + 6.0 * np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1), POSITION_VAR_M2, 10.0
    if scene == "cov1e30":
        return np.array([[12.0, 3.0, -5.0]]), 1e30, 10.0
    raise ValueError(f"unknown hostile scene {scene!r}: expected one of {', '.join(SCENES)}")


def hostile_antipodal(scene: str, directory: Path) -> Path:
    """Write the antipodal scenario with ``scene``'s systems added (see the module docstring); its path."""
    text = ANTIPODAL.read_text()
    positions, var, rate = hostile_positions(scene)
    head, sep, rest = text.partition("[[world.obstacles]]")
    head = head.rstrip() + "\n\n[world]\nobstacle_sysid_base = 2\n\n" if "[world]\n" not in head else head
    out = head + sep + rest + "".join(_static(f"{scene}_{i}", p, var, rate) for i, p in enumerate(positions))
    path = Path(directory) / f"antipodal_{scene}.toml"
    path.write_text(out)
    return path
