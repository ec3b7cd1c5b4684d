"""Figures of one flight from the companion's replan records (demo and replay).

:func:`write_flight_figures` draws four PNGs from ``companion.records``
(:class:`companion.loop.app.ReplanRecord`) and the companion's configuration:

- ``topview.png``: paths of the drone and of every tracked obstacle seen from above,
  with confidence ellipses at a few instants, walls and static obstacles;
- ``contour.png``: contour of touch with each obstacle over time, with ``c_min`` and
  ``c_max``;
- ``speed_accel.png``: commanded velocity per axis and its norm, and the acceleration
  between successive replans, against the planner's bounds;
- ``solve_time.png``: planner solve time per replan, marked by plan status.

Everything is in the local NED frame (x north, y east, z down; metres, seconds). Only
this package imports matplotlib (Agg backend, no display).
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Circle  # noqa: E402

from companion.plots.ellipses import top_view_patch  # noqa: E402

logger = logging.getLogger(__name__)

_DPI = 110
_STATUS_STYLE = {"optimal": ("tab:green", "o"), "slack": ("tab:orange", "s"), "failed": ("tab:red", "x")}


def _track_label(key) -> str:
    """A track's name for a legend: ``ICAO 4CA2B1``, ``system 101 on obstacles1``, ``Remote ID ... on obstacles1``."""
    if isinstance(key, tuple) and key:
        if key[0] == "icao" and len(key) == 2:
            return f"ICAO {int(key[1]):06X}"
        if key[0] == "uas":
            uid = bytes(key[1]).rstrip(b"\x00").hex().upper() if isinstance(key[1], (bytes, bytearray, tuple, list)) else key[1]
            return f"Remote ID {uid}" + (f" on {key[2]}" if len(key) > 2 else "")
        if all(isinstance(k, int) for k in key[:2]):
            return f"system {key[0]}" + (f" on {key[2]}" if len(key) > 2 else "")
    return str(key)


def _start_s(companion, records) -> float:
    """Link time of the run's start (its first event or replan), s: the figures' time zero."""
    times = [t for t, _ in getattr(getattr(companion, "state", None), "events", [])[:1]]
    times += [records[0].t_link_s] if records else []
    return min(times) if times else 0.0


def write_flight_figures(companion, out_dir: str | Path, truth: dict | None = None, *, prefix: str = "",
                         path=None) -> list[Path]:
    """Draw the flight figures of a companion run (demo, replay) as PNGs in ``out_dir``.

    Parameters
    ----------
    companion : :class:`companion.loop.app.Companion`
        After the run: ``records`` (one per replan), ``cfg`` (planner config: ``c_min``,
        ``c_max``, ``velocity_max``, ``accel_max``) and ``scenario`` (walls, static
        obstacles, goal). A run with no replans or no obstacles gives figures that say so.
    out_dir : str or Path
        Folder (created if missing).
    truth : dict, optional
        The simulator's summary (``mavsim`` truth); its smallest true distances and
        collision flag go into the top view's title.
    prefix : str
        Prepended to each file name (``antipodal_`` gives ``antipodal_topview.png``).
    path : sequence of (3,) NED positions, optional
        The drone's estimate over the whole flight (replans are recorded only while the companion
        flies: a mission the autopilot flies itself is drawn from this), with the takeovers of a
        guarding companion marked on it.

    Returns
    -------
    list of Path
        ``topview``, ``contour``, ``speed_accel`` and ``solve_time`` PNGs, in that order.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    records = list(getattr(companion, "records", []) or [])
    drawers = (("topview", _topview), ("contour", _contour), ("speed_accel", _speed_accel), ("solve_time", _solve_time))
    paths = []
    for name, draw in drawers:
        file = out / f"{prefix}{name}.png"
        fig = _topview(companion, records, truth, path) if draw is _topview else draw(companion, records, truth)
        try:
            fig.savefig(file, dpi=_DPI)
        finally:
            plt.close(fig)
        paths.append(file)
    logger.info("wrote %d flight figures to %s", len(paths), out)
    return paths


def _no_data(ax, text: str) -> None:
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, color="0.4")


def _tracks(records) -> list:
    keys: list = []
    for r in records:
        for k in r.obstacle_positions:
            if k not in keys:
                keys.append(k)
    return keys


def _instants(records, n: int = 4) -> list[int]:
    """A few replans to draw ellipses at: evenly spaced, plus the closest approach."""
    if not records:
        return []
    idx = set(np.linspace(0, len(records) - 1, min(n, len(records))).round().astype(int).tolist())
    contours = [min(r.realised_contour.values()) if r.realised_contour else math.inf for r in records]
    if any(math.isfinite(c) for c in contours):
        idx.add(int(np.argmin(contours)))
    return sorted(idx)


def _topview(companion, records, truth, path=None):
    cfg = companion.planner_config
    scenario = companion.scenario
    fig, ax = plt.subplots(figsize=(7.0, 6.4))
    ax.set_xlabel("east y [m]")
    ax.set_ylabel("north x [m]")
    ax.set_aspect("equal", adjustable="box")
    ax.grid(True, alpha=0.3)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    pts = []
    watched = getattr(companion, "watch", None) is not None
    if path is not None and len(path):
        flown = np.asarray(path, dtype=float).reshape(-1, 3)
        pts.append(flown)
        ax.plot(flown[:, 1], flown[:, 0], "-", color="0.55", lw=1.0,
                label="flown by the autopilot (estimate)" if watched else "flown (estimate)")
    if records:
        p = np.array([r.drone_position for r in records])
        pts.append(p)
        if watched:   # replans only while taken over: each takeover its own stretch
            breaks = np.flatnonzero(np.diff([r.t_link_s for r in records]) > 1.5 * cfg.replan_period_s + 0.5) + 1
            for k, part in enumerate(np.split(p, breaks)):
                ax.plot(part[:, 1], part[:, 0], "-", color="k", lw=2.2, label=None if k else "taken over (replans)")
        else:
            ax.plot(p[:, 1], p[:, 0], "-", color="k", lw=1.8, label="drone (estimate)")
        ax.plot(p[0, 1], p[0, 0], "o", color="k", ms=5)
    for i, key in enumerate(_tracks(records)):
        q = np.array([r.obstacle_positions[key] for r in records if key in r.obstacle_positions])
        pts.append(q)
        c = colors[(i + 1) % len(colors)]
        ax.plot(q[:, 1], q[:, 0], "-", color=c, lw=1.3, label=_track_label(key))
        ax.plot(q[0, 1], q[0, 0], "o", color=c, ms=4)
    waypoints = [np.asarray(w.position, dtype=float) for w in getattr(companion.goal, "waypoints", [])]
    if len(waypoints) > 1:   # a mission: its legs from the first waypoint on, numbered
        wp = np.array(waypoints)
        pts.append(wp)
        ax.plot(wp[:, 1], wp[:, 0], "--", color="0.45", lw=1.0, label="mission legs")
        for k, w in enumerate(wp, start=1):
            ax.annotate(str(k), (w[1], w[0]), xytext=(3, -9), textcoords="offset points", fontsize=7, color="0.3")
    if companion.goal.goal is not None:
        goal = np.asarray(waypoints[-1] if waypoints else companion.goal.goal, dtype=float)
        pts.append(goal[None, :])
        ax.plot(goal[1], goal[0], "*", color="gold", mec="k", ms=14, label="goal")
    pts.extend(_fence(ax, getattr(getattr(companion, "fence", None), "fence", None)))
    for s in getattr(scenario, "static_obstacles", ()):
        c = np.asarray(s.center, dtype=float)
        pts.append(c[None, :])
        ax.add_patch(Circle((c[1], c[0]), s.radius, color="0.4", alpha=0.5))
        ax.add_patch(top_view_patch(c, s.covariance, cfg.c_min, fill=False, ec="0.2", lw=0.8, ls="--"))
    r_drone = float(getattr(cfg, "drone_radius_m", 0.0))
    radius_of = getattr(getattr(companion, "builder", None), "obstacle_radius", lambda key: 0.0)
    t0 = _start_s(companion, records)
    for j in _instants(records):
        rec = records[j]
        for k, (pos, cov, radius, c) in enumerate(
            [(rec.drone_position, rec.drone_cov, r_drone, "k")]
            + [(rec.obstacle_positions[key], rec.obstacle_covs[key], radius_of(key), colors[(i + 1) % len(colors)])
               for i, key in enumerate(_tracks(records)) if key in rec.obstacle_positions]
        ):
            ax.add_patch(top_view_patch(pos, cov, cfg.c_min, fill=True, fc=c, alpha=0.25, ec=c, lw=0.8))
            ax.add_patch(Circle((pos[1], pos[0]), radius, fill=False, ec=c, lw=0.6, ls=":"))
        pos = rec.drone_position
        ax.annotate(f"t={rec.t_link_s - t0:.1f}s", (pos[1], pos[0]), xytext=(4, 4), textcoords="offset points", fontsize=7)
    allp = np.vstack(pts) if pts else np.zeros((1, 3))
    lo, hi = allp[:, :2].min(axis=0) - 2.0, allp[:, :2].max(axis=0) + 2.0
    _walls(ax, scenario, lo, hi)
    ax.set_xlim(lo[1], hi[1])
    ax.set_ylim(lo[0], hi[0])
    title = f"top view (north up, east right); ellipses: c_min = {cfg.c_min:g} slice, dotted: body radii"
    if truth:
        dist = truth.get("min_distance_m") or {}
        extra = []
        if dist:
            extra.append(f"smallest true distance {min(dist.values()):.2f} m")
        if "collided" in truth:
            extra.append("COLLISION" if truth.get("collided") else "no collision")
        if extra:
            title += "\n" + ", ".join(extra)
    if not records and (path is None or not len(path)):
        _no_data(ax, "no replans recorded")
    ax.set_title(title, fontsize=9)
    ax.legend(loc="best", fontsize=7)
    fig.tight_layout()
    return fig


def _fence(ax, fence) -> list:
    """The geofence's zones from above: inclusion outlines (green), exclusion zones filled (red); their points."""
    if fence is None:
        return []
    from matplotlib.patches import Polygon

    pts = []
    for k, z in enumerate(fence.polygons):
        v = z.vertices
        pts.append(np.column_stack([v, np.zeros(len(v))]))
        label = None if k else "geofence (inclusion green, exclusion red)"
        if z.inclusion:
            ax.add_patch(Polygon(v[:, ::-1], closed=True, fill=False, ec="forestgreen", lw=1.6, label=label))
        else:
            ax.add_patch(Polygon(v[:, ::-1], closed=True, fc="firebrick", alpha=0.35, ec="firebrick", lw=1.2, label=label))
    for c in fence.circles:
        pts.append(np.array([[c.center[0] - c.radius_m, c.center[1] - c.radius_m, 0.0],
                             [c.center[0] + c.radius_m, c.center[1] + c.radius_m, 0.0]]))
        ax.add_patch(Circle((c.center[1], c.center[0]), c.radius_m, fill=not c.inclusion,
                            fc="firebrick", alpha=0.35 if not c.inclusion else 1.0,
                            ec="forestgreen" if c.inclusion else "firebrick", lw=1.4))
    return pts


def _walls(ax, scenario, lo: np.ndarray, hi: np.ndarray) -> None:
    """Each wall ``n . p <= b`` as its boundary line in the horizontal plane, the blocked side hatched."""
    for wall in getattr(scenario, "walls", ()):
        n = np.asarray(wall.normal, dtype=float)
        nx, ny, b = n[0], n[1], float(wall.offset)
        if math.hypot(nx, ny) < 1e-9:
            continue  # floor or ceiling: not visible from above
        if abs(ny) >= abs(nx):
            xs = np.array([lo[0], hi[0]])
            ys = (b - nx * xs) / ny
        else:
            ys = np.array([lo[1], hi[1]])
            xs = (b - ny * ys) / nx
        ax.plot(ys, xs, "-", color="saddlebrown", lw=2.0)
        # blocked side: shift the line along +normal
        d = 0.6 / math.hypot(nx, ny)
        ax.fill([ys[0], ys[1], ys[1] + ny * d, ys[0] + ny * d], [xs[0], xs[1], xs[1] + nx * d, xs[0] + nx * d],
                color="saddlebrown", alpha=0.25, hatch="//", lw=0)


def _contour(companion, records, truth):
    """Above: each track's estimated clearance (m, centre distance less both radii) at each replan.
    Below: the contour of touch, the smallest over the tracks now (line) and over the planned horizon (dots)."""
    cfg = companion.planner_config
    radius = getattr(getattr(companion, "builder", None), "obstacle_radius", lambda key: 0.0)
    t0 = _start_s(companion, records)
    fig, (ax_d, ax) = plt.subplots(2, 1, figsize=(7.0, 6.4), sharex=True)
    keys = _tracks(records)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, key in enumerate(keys):
        pts = [(r.t_link_s - t0, float(np.linalg.norm(r.obstacle_positions[key] - r.drone_position))
                - cfg.drone_radius_m - radius(key)) for r in records if key in r.obstacle_positions]
        if pts:
            t, d = np.array(pts).T
            ax_d.plot(t, d, "-", color=colors[(i + 1) % len(colors)], lw=1.4, label=_track_label(key))
    ax_d.axhline(0.0, color="k", lw=0.8)
    ax_d.set_ylabel("estimated clearance [m]")
    ax_d.set_title("each track: distance between the estimates less both body radii", fontsize=9)
    ax_d.grid(True, alpha=0.3)
    if keys:
        ax_d.legend(loc="upper right", fontsize=7)
    else:
        _no_data(ax_d, "no obstacles tracked" if records else "no replans recorded")
    now = np.array([(r.t_link_s - t0, min(r.realised_contour.values())) for r in records if r.realised_contour])
    if now.size:
        ax.plot(now[:, 0], now[:, 1], "-", color="tab:blue", lw=1.4, label="now: smallest over the tracks (estimates)")
    planned = np.array([(r.t_link_s - t0, r.planned_min_contour) for r in records if math.isfinite(r.planned_min_contour)])
    if planned.size:
        ax.plot(planned[:, 0], planned[:, 1], ".", color="k", ms=3, label="planned: smallest over the horizon (in range)")
    ax.axhline(cfg.c_min, color="tab:red", ls="--", lw=1.2, label=f"c_min = {cfg.c_min:g}")
    if cfg.c_max is not None:
        ax.axhline(cfg.c_max, color="tab:purple", ls="--", lw=1.2, label=f"c_max = {cfg.c_max:g}")
    values = [cfg.c_min] + ([cfg.c_max] if cfg.c_max is not None else [])
    values += now[:, 1].tolist() if now.size else []
    values += planned[:, 1].tolist() if planned.size else []
    ax.set_ylim(max(0.0, min(values) - 0.05), 1.005)  # zoom on the range that matters
    ax.set_xlabel("time since the run's start [s]")
    ax.set_ylabel("contour of touch (confidence)")
    ax.set_title("contour of touch: the confidence at which the drone's and a track's ellipsoids touch\n"
                 "(the plans promise at least c_min)", fontsize=9)
    ax.grid(True, alpha=0.3)
    if not now.size and not planned.size:
        _no_data(ax, "no obstacles tracked" if records else "no replans recorded")
    else:
        ax.legend(loc="lower right", fontsize=7)
    fig.tight_layout()
    return fig


def _speed_accel(companion, records, truth):
    cfg = companion.planner_config
    vmax = np.asarray(cfg.velocity_max, dtype=float)
    amax = np.asarray(cfg.accel_max, dtype=float)
    fig, (ax_v, ax_a) = plt.subplots(2, 1, figsize=(7.0, 6.0), sharex=True)
    axis_colors = ("tab:blue", "tab:orange", "tab:green")
    names = ("north", "east", "down")
    if records:
        t = np.array([r.t_link_s for r in records]) - _start_s(companion, records)
        v = np.array([r.command for r in records])
        for k in range(3):
            ax_v.step(t, v[:, k], where="post", color=axis_colors[k], lw=1.2, label=f"v {names[k]}")
            ax_v.axhline(vmax[k], color=axis_colors[k], ls=":", lw=0.8)
            ax_v.axhline(-vmax[k], color=axis_colors[k], ls=":", lw=0.8)
        ax_v.step(t, np.linalg.norm(v, axis=1), where="post", color="k", lw=1.4, label="|v|")
        if t.size >= 2:
            dt = np.diff(t)
            a = np.diff(v, axis=0) / dt[:, None]
            for k in range(3):
                ax_a.plot(t[1:], a[:, k], ".-", color=axis_colors[k], ms=3, lw=0.8, label=f"a {names[k]}")
                ax_a.axhline(amax[k], color=axis_colors[k], ls="--", lw=0.8)
                ax_a.axhline(-amax[k], color=axis_colors[k], ls="--", lw=0.8)
        else:
            _no_data(ax_a, "fewer than two replans")
    else:
        _no_data(ax_v, "no replans recorded")
        _no_data(ax_a, "no replans recorded")
    ax_v.set_ylabel("commanded velocity [m/s]")
    ax_v.set_title("first planned velocity per replan; dotted: velocity bounds per axis", fontsize=9)
    ax_a.set_ylabel("acceleration [m/s²]")
    ax_a.set_xlabel("time since the run's start [s]")
    ax_a.set_title("finite difference between replans; dashed: acceleration bounds per axis", fontsize=9)
    for ax in (ax_v, ax_a):
        ax.grid(True, alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="upper right", fontsize=7, ncol=4)
    fig.tight_layout()
    return fig


def _solve_time(companion, records, truth):
    cfg = companion.planner_config
    fig, ax = plt.subplots(figsize=(7.0, 3.8))
    if records:
        t = np.array([r.t_link_s for r in records]) - _start_s(companion, records)
        ms = np.array([r.solve_time_s for r in records]) * 1e3
        ax.plot(t, ms, "-", color="0.6", lw=0.8)
        for status, (color, marker) in _STATUS_STYLE.items():
            sel = np.array([r.status == status for r in records])
            if sel.any():
                ax.plot(t[sel], ms[sel], marker, color=color, ms=4, ls="none", label=f"{status} ({int(sel.sum())})")
        ax.axhline(cfg.replan_period_s * 1e3, color="tab:red", ls="--", lw=1.0, label=f"replan period {cfg.replan_period_s * 1e3:.0f} ms")
        ax.set_ylim(0.0, max(float(ms.max()), cfg.replan_period_s * 1e3) * 1.1)
        ax.legend(loc="upper right", fontsize=7)
    else:
        _no_data(ax, "no replans recorded")
    ax.set_xlabel("time since the run's start [s]")
    ax.set_ylabel("solve time [ms]")
    ax.set_title("planner solve time per replan (wall clock of the run that planned)", fontsize=9)
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    return fig
