"""The goal approach of PX4 SITL flights, read from their tlogs (``tests.px4.flight`` work directories).

Usage::

    python -m tests.px4.approach /tmp/px4-flight/run0 [/tmp/px4-flight/run1 ...] [--scenario configs/antipodal_px4.toml] [--model]

Per flight, from PX4's ODOMETRY as the companion received it (its velocity rotated to NED
as the companion rotates it) and the companion's velocity setpoints, times in seconds
after PX4 reported OFFBOARD:

- where the estimate first crosses the plane through the goal across the approach (the
  mission's start-to-goal direction): when, how fast along the approach, and how far to
  the side; how far it then goes past the goal; when it first comes within the goal
  tolerance (the companion's goal test, to the 0.3 s of its replan requests);
- while it is more than the tolerance past the goal after that crossing: how long, the mean
  velocity error along the approach (setpoint less estimate) and the mean of PX4's own
  acceleration setpoint along it (POSITION_TARGET_LOCAL_NED ``afx``, ``afy``, ``afz``: the
  output of its velocity loop, so with a proportional gain of about 1.8 /s on that error,
  what is left is the loop's integral);
- with ``--model``, how well the scenario's identified response
  (``[planner.vehicle_response]``) predicts ``h`` seconds ahead, under the setpoints actually
  sent, PX4's velocity estimate, its position estimate, and the distance its velocity
  estimate integrates to ("flown": the position less PX4's drift), rms over the flight and
  over its last part. Each prediction starts, per axis, at the velocity estimate with the
  model's other states (the integral, the acceleration) either at their steady state (what
  the planner does), carried (the integral of setpoint less velocity estimate since
  OFFBOARD, and the acceleration lag run on it) or observed (the companion's
  :class:`~companion.core.planner.response_observer.ResponseObserver`, ``[companion]
  response_state = "observed"``, fed with the same reports and setpoints).

A reading tool for the notes; it asserts nothing.
"""

from __future__ import annotations

import argparse
import sys
import tomllib
from pathlib import Path

import numpy as np

from companion.core.planner.response_observer import ResponseObserver
from companion.core.planner.vehicle_model import AxisResponse, ResponseModel, discretise
from companion.mavlink.messages import decode_odometry
from companion.mavlink.tlog import read_tlog
from tests.px4.sitl import REPO

PX4_MAIN_MODE_OFFBOARD = 6
GRID_S = 0.05          # the setpoints' period (20 Hz) and the grid the model runs on
HORIZONS_S = (1.5, 3.0)
LATE_AFTER_S = 13.0    # "the last part": the approach to the goal (the encounter is over by then)


def load(work: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """PX4's estimate (M, 7: link time s, position NED m, velocity NED m/s), the companion's
    setpoints (K, 4: link time s, velocity NED m/s), PX4's acceleration setpoints (J, 4: link
    time s, NED m/s^2; J may be 0) and the link time PX4 first reported OFFBOARD."""
    odometry, setpoints, targets, offboard = [], [], [], None
    for t, msg in read_tlog(work / "flight.tlog"):
        kind = msg.get_type()
        if kind == "ODOMETRY":
            obs = decode_odometry(msg)
            if getattr(obs, "velocity_ned", None) is not None:
                odometry.append((t, *obs.position_ned, *obs.velocity_ned))
        elif kind == "SET_POSITION_TARGET_LOCAL_NED":
            setpoints.append((t, msg.vx, msg.vy, msg.vz))
        elif kind == "POSITION_TARGET_LOCAL_NED" and msg.get_srcComponent() == 1:
            targets.append((t, msg.afx, msg.afy, msg.afz))
        elif kind == "HEARTBEAT" and offboard is None and msg.get_srcComponent() == 1 \
                and (msg.custom_mode >> 16) & 0xFF == PX4_MAIN_MODE_OFFBOARD:
            offboard = t
    if offboard is None or not odometry or not setpoints:
        raise ValueError(f"{work / 'flight.tlog'}: no OFFBOARD, ODOMETRY or setpoints in it")
    return np.array(odometry), np.array(setpoints), np.array(targets).reshape(-1, 4), offboard


def crossing(odometry: np.ndarray, setpoints: np.ndarray, targets: np.ndarray, offboard: float,
             start: np.ndarray, goal: np.ndarray, tolerance: float) -> dict:
    """The estimate's first pass of the goal and the time beyond it (see the module docstring)."""
    ahead = (goal - start) / np.linalg.norm(goal - start)
    offset = odometry[:, 1:4] - goal
    along = offset @ ahead
    passed = np.nonzero((along[:-1] < 0.0) & (along[1:] >= 0.0))[0]
    distance = np.linalg.norm(offset, axis=1)
    inside = np.nonzero(distance <= tolerance)[0]
    out = {"within_tolerance_s": None if not inside.size else float(odometry[inside[0], 0] - offboard)}
    if passed.size:
        k = passed[0] + 1
        out.update(
            crosses_s=float(odometry[k, 0] - offboard),
            speed_along_mps=float(odometry[k, 4:7] @ ahead),
            to_the_side_m=float(np.linalg.norm(offset[k] - along[k] * ahead)),
            beyond_m=float(along[k:].max()),
        )
        beyond = np.arange(odometry.shape[0]) >= k
        beyond &= along > tolerance
        if beyond.any():
            t = odometry[beyond, 0]
            held = np.searchsorted(setpoints[:, 0], t, side="right") - 1
            error = (setpoints[np.maximum(held, 0), 1:4] - odometry[beyond, 4:7]) @ ahead
            out.update(beyond_tolerance_s=float(t.size and t[-1] - t[0]), velocity_error_along_mps=float(error.mean()))
            if targets.shape[0]:
                acc = np.stack([np.interp(t, targets[:, 0], targets[:, 1 + j]) for j in range(3)], axis=1) @ ahead
                out["px4_acceleration_setpoint_along_mps2"] = float(acc.mean())
    return out


def _carried_states(axis: AxisResponse, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The PI state carried along the flight on the grid (M, 2): the integral of ``u - v``
    (m) and the acceleration lag driven by the PI law on the measured velocity (m/s^2)."""
    kp, ki, ta = axis.p_gain_per_s, axis.i_gain_per_s2, axis.accel_lag_s
    out = np.zeros((u.size, 2))
    for i in range(1, u.size):
        error = u[i - 1] - v[i - 1]
        xi, acc = out[i - 1]
        target = kp * error + ki * xi
        acc = target + (acc - target) * np.exp(-GRID_S / ta) if ta > 0.0 else target
        out[i] = xi + error * GRID_S, acc
    return out


def _observed_states(response: tuple[AxisResponse, AxisResponse], odometry: np.ndarray, setpoints: np.ndarray,
                     grid: np.ndarray) -> np.ndarray:
    """The companion's :class:`~companion.core.planner.response_observer.ResponseObserver` run over
    the flight (each setpoint at its link time, each velocity report at its own): its internal
    state (M, 3, 2), ``(xi, a)`` per NED axis, at each grid time (predicted from the last report)."""
    observer = ResponseObserver(ResponseModel(GRID_S, *response))
    out = np.zeros((grid.size, 3, 2))
    sent = reported = 0
    for i, t in enumerate(grid):
        while reported < odometry.shape[0] and odometry[reported, 0] <= t:
            t_report = odometry[reported, 0]
            while sent < setpoints.shape[0] and setpoints[sent, 0] <= t_report:
                observer.command(setpoints[sent, 0], setpoints[sent, 1:4])
                sent += 1
            observer.observe(t_report, odometry[reported, 4:7])
            reported += 1
        while sent < setpoints.shape[0] and setpoints[sent, 0] <= t:
            observer.command(setpoints[sent, 0], setpoints[sent, 1:4])
            sent += 1
        state = observer.internal(t)
        if state is not None:
            out[i] = state
    return out


def model_prediction(odometry: np.ndarray, setpoints: np.ndarray, offboard: float,
                     response: tuple[AxisResponse, AxisResponse]) -> list[dict]:
    """The identified response's prediction errors ``h`` ahead from each start (see the module docstring)."""
    end = min(odometry[-1, 0], setpoints[-1, 0]) - GRID_S
    grid = np.arange(offboard, end, GRID_S)
    position = np.stack([np.interp(grid, odometry[:, 0], odometry[:, 1 + k]) for k in range(3)], axis=1)
    velocity = np.stack([np.interp(grid, odometry[:, 0], odometry[:, 4 + k]) for k in range(3)], axis=1)
    held = np.searchsorted(setpoints[:, 0], grid, side="right") - 1     # the setpoint in force (zero-order hold)
    command = np.where(held[:, None] >= 0, setpoints[np.maximum(held, 0), 1:4], 0.0)
    late = grid - offboard > LATE_AFTER_S
    observed = _observed_states(response, odometry[odometry[:, 0] >= offboard], setpoints, grid)
    rows = []
    for k, name in enumerate("NED"):
        axis = response[0] if k < 2 else response[1]
        ad, bd = discretise(*axis.matrices(), GRID_S)
        carried = _carried_states(axis, command[:, k], velocity[:, k])
        for h in HORIZONS_S:
            n = int(round(h / GRID_S))
            starts = np.arange(0, grid.size - n, 2)
            for start_name in ("steady", "carried", "observed"):
                errors = np.empty((starts.size, 3))
                for row, i in enumerate(starts):
                    if start_name == "steady":
                        x = axis.steady_state(velocity[i, k])
                    elif start_name == "carried":
                        x = np.array([0.0, velocity[i, k], carried[i, 0]] + ([carried[i, 1]] if axis.accel_lag_s > 0 else []))
                    else:
                        x = np.array([0.0, velocity[i, k], *observed[i, k]])[:ad.shape[0]]
                    for j in range(n):
                        x = ad @ x + bd * command[i + j, k]
                    flown = np.trapezoid(velocity[i:i + n + 1, k], dx=GRID_S)   # the velocity estimate's integral
                    errors[row] = x[1] - velocity[i + n, k], x[0] - (position[i + n, k] - position[i, k]), x[0] - flown
                last = late[starts]
                rms = np.sqrt((errors**2).mean(axis=0))
                rms_late = np.sqrt((errors[last] ** 2).mean(axis=0)) if last.any() else np.full(3, np.nan)
                rows.append({"axis": name, "h_s": h, "start": start_name, "velocity_rms_mps": rms[0],
                             "position_rms_m": rms[1], "flown_rms_m": rms[2], "late_velocity_rms_mps": rms_late[0],
                             "late_position_rms_m": rms_late[1], "late_flown_rms_m": rms_late[2]})
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("works", nargs="+", type=Path, help="flight work directories (each with flight.tlog)")
    ap.add_argument("--scenario", type=Path, default=REPO / "configs" / "antipodal_px4.toml")
    ap.add_argument("--model", action="store_true", help="also the identified response's prediction errors")
    args = ap.parse_args(argv)
    try:
        with open(args.scenario, "rb") as f:
            scenario = tomllib.load(f)
    except (OSError, tomllib.TOMLDecodeError) as exc:
        print(f"approach: {args.scenario}: {exc}", file=sys.stderr)
        return 2
    goal = np.asarray(scenario["mission"]["goal_ned_m"], float)
    start = np.asarray(scenario["vehicle"]["start_ned_m"], float)
    tolerance = float(scenario["mission"]["goal_tolerance_m"])
    table = scenario["planner"].get("vehicle_response")
    for work in args.works:
        try:
            odometry, setpoints, targets, offboard = load(work)
        except (ValueError, OSError) as exc:   # TlogError is a ValueError: the message names the file
            print(f"approach: {exc}", file=sys.stderr)
            return 2
        passed = crossing(odometry, setpoints, targets, offboard, start, goal, tolerance)
        print(work, ", ".join(f"{k} {'-' if v is None else f'{v:.2f}'}" for k, v in passed.items()))
        if args.model and table:
            response = tuple(AxisResponse.from_mapping(table[k], f"vehicle_response.{k}") for k in ("horizontal", "vertical"))
            for r in model_prediction(odometry, setpoints, offboard, response):
                print(f"  {r['axis']} {r['h_s']:.1f} s ahead, {r['start']:8s}: velocity {r['velocity_rms_mps']:.3f} m/s, "
                      f"position {r['position_rms_m']:.3f} m, flown {r['flown_rms_m']:.3f} m; after {LATE_AFTER_S:g} s: "
                      f"{r['late_velocity_rms_mps']:.3f} m/s, {r['late_position_rms_m']:.3f} m, {r['late_flown_rms_m']:.3f} m")
    return 0


if __name__ == "__main__":
    sys.exit(main())
