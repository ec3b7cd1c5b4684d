"""mavsim's vehicle profiles against PX4 SITL's measured velocity step responses, side by side.

Usage::

    python -m tests.benchmarks.step_response [--vehicle px4|lag] [--json]

Flies the eight velocity steps of issue 13 (north 0 -> 1 -> 0 -> 3 -> 0, then up
0 -> 1 -> 0 -> 3 -> 0, each held :data:`HOLD_S`) against mavsim in lockstep, as a client
does over MAVLink: velocity-only SET_POSITION_TARGET_LOCAL_NED at 20 Hz in OFFBOARD, the
response read from LOCAL_POSITION_NED streamed at 100 Hz (sensor noise off, so the table
shows the profile's response). For each step it prints t63, t90, overshoot, peak
acceleration and the fraction of the step reached at 0.3 / 0.6 / 1 / 2 / 4 / 7.5 s
beside :data:`MEASURED_PX4_SITL` and the difference per fraction.

A step's fraction at ``t`` is ``(v(t) - v(0)) / (v_sp - v(0))``, ``v(0)`` the velocity
when the new setpoint is first sent (along the step's axis; up is positive). The peak
acceleration is the largest |dv/dt| over 0.05 s differences.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict, dataclass

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from mavsim.lockstep import LockstepSimulator

#: Fractions are read at these times after the step, seconds.
FRACTION_TIMES_S = (0.3, 0.6, 1.0, 2.0, 4.0, 7.5)
#: Each step is held this long, seconds (the table's last column is read at 7.5 s).
HOLD_S = 8.0
#: Setpoint rate, Hz, and the velocity-only type_mask (yaw and yaw rate ignored).
SETPOINT_RATE_HZ = 20.0
_VELOCITY_ONLY = 3527

#: Measured on PX4 SITL (PX4 main 02e73e3b6f of March 2026, SIH quadrotor, OFFBOARD velocity
#: setpoints, LOCAL_POSITION_NED at 100 Hz): issue 13's table. Per step (label, axis, from,
#: to in m/s, up positive): t63 s, t90 s, overshoot % (None: none), peak |accel| m/s^2,
#: fractions at FRACTION_TIMES_S. This is the reference data, not a result of this code.
MEASURED_PX4_SITL: tuple[tuple[str, str, float, float, float, float, float | None, float, tuple[float, ...]], ...] = (
    ("north 0 -> 1", "north", 0.0, 1.0, 1.17, 6.79, None, 1.6, (.12, .45, .62, .61, .77, .90)),
    ("north 1 -> 0", "north", 1.0, 0.0, 0.85, 4.98, 1.0, 1.7, (.18, .51, .68, .71, .80, .96)),
    ("north 0 -> 3", "north", 0.0, 3.0, 0.98, 6.07, None, 3.9, (.14, .44, .64, .75, .84, .89)),
    ("north 3 -> 0", "north", 3.0, 0.0, 0.75, 4.66, None, 4.2, (.23, .54, .73, .84, .89, .93)),
    ("up 0 -> 1", "up", 0.0, 1.0, 0.27, 0.51, 0.0, 3.9, (.67, .90, .85, .91, .96, .93)),
    ("up 1 -> 0", "up", 1.0, 0.0, 0.24, 0.54, 6.0, 3.1, (.71, .92, .95, .92, 1.02, 1.03)),
    ("up 0 -> 3", "up", 0.0, 3.0, 0.30, 1.73, None, 10.1, (.63, .82, .85, .90, .97, .95)),
    ("up 3 -> 0", "up", 3.0, 0.0, 0.28, 1.03, 1.0, 10.5, (.67, .86, .90, .95, .96, .98)),
)


@dataclass(frozen=True)
class StepResult:
    """One step's figures (seconds, %, m/s^2, fractions of the step)."""

    label: str
    t63_s: float
    t90_s: float
    overshoot_pct: float | None
    peak_accel_mps2: float
    fractions: tuple[float, ...]


def _scenario(vehicle: str) -> dict:
    zero = [[0.0] * 3 for _ in range(3)]
    return {
        "scenario": {"name": f"step_response_{vehicle}", "duration_s": 3600.0},
        "vehicle": {"start_ned_m": [0.0, 0.0, -10.0]},
        "sim": {"vehicle": vehicle, "position_noise_cov_m2": zero, "velocity_noise_cov_m2ps2": zero,
                "stream_rates_hz": {"LOCAL_POSITION_NED": 100.0}},
    }


def _setpoint(axis: str, value: float):
    vx, vz = (value, 0.0) if axis == "north" else (0.0, -value)
    return mavlink2.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, mavlink2.MAV_FRAME_LOCAL_NED, _VELOCITY_ONLY, 0, 0, 0, vx, 0.0, vz, 0, 0, 0, 0, 0)


def fly_steps(vehicle: str = "px4") -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Fly the eight steps; per step ``(t s since the step, velocity along its axis m/s (up +), setpoint)``."""
    sim = LockstepSimulator(_scenario(vehicle))
    enc = mavlink2.MAVLink(None, srcSystem=245, srcComponent=190)
    dec = mavlink2.MAVLink(None)
    dec.robust_parsing = True
    samples: list[tuple[float, float, float]] = []   # (t, vn, up)

    def send(msg) -> None:
        sim.write(msg.pack(enc))
        enc.seq = (enc.seq + 1) % 256

    def run(seconds: float, axis: str, value: float) -> None:
        n = int(round(seconds * SETPOINT_RATE_HZ))
        for _ in range(n):
            send(_setpoint(axis, value))
            for t, data in sim.advance(1.0 / SETPOINT_RATE_HZ):
                for m in dec.parse_buffer(data) or []:
                    if m.get_type() == "LOCAL_POSITION_NED":
                        samples.append((t, m.vx, -m.vz))

    run(1.0, "north", 0.0)
    send(mavlink2.MAVLink_command_long_message(1, 1, mavlink2.MAV_CMD_DO_SET_MODE, 0, 29, 6, 0, 0, 0, 0, 0))
    run(2.0, "north", 0.0)
    if sim.truth.mode != "OFFBOARD":
        raise RuntimeError(f"mavsim did not enter OFFBOARD (mode {sim.truth.mode})")
    starts = []
    for _, axis, _, to, *_ in MEASURED_PX4_SITL:
        starts.append(sim.time_s)
        run(HOLD_S, axis, to)
    data = np.array(samples)
    out = []
    for start, (_, axis, _, to, *_) in zip(starts, MEASURED_PX4_SITL):
        sel = (data[:, 0] >= start - 1e-9) & (data[:, 0] < start + HOLD_S - 1e-9)
        col = 1 if axis == "north" else 2
        out.append((data[sel, 0] - start, data[sel, col], to))
    return out


def step_figures(label: str, t: np.ndarray, v: np.ndarray, target: float) -> StepResult:
    """t63, t90, overshoot, peak acceleration and fractions of one step's response."""
    v0 = float(v[0])
    frac = (v - v0) / (target - v0)

    def first(level: float) -> float:
        hit = np.flatnonzero(frac >= level)
        return float(t[hit[0]]) if hit.size else float("nan")

    lag = max(1, int(round(0.05 / float(np.median(np.diff(t))))))
    accel = np.abs(v[lag:] - v[:-lag]) / (t[lag:] - t[:-lag])
    over = float(frac.max() - 1.0)
    fractions = tuple(float(np.interp(x, t, frac)) for x in FRACTION_TIMES_S)
    return StepResult(label, first(0.63), first(0.9), round(100 * over, 1) if over > 0.005 else None,
                      float(accel.max()), fractions)


def step_table(vehicle: str = "px4") -> list[StepResult]:
    """The figures of the eight steps flown against mavsim's ``vehicle`` profile."""
    return [step_figures(ref[0], t, v, to) for ref, (t, v, to) in zip(MEASURED_PX4_SITL, fly_steps(vehicle))]


def fraction_differences(results: list[StepResult]) -> np.ndarray:
    """(8, 6) mavsim's fractions minus the measured ones."""
    return np.array([r.fractions for r in results]) - np.array([ref[8] for ref in MEASURED_PX4_SITL])


def format_table(results: list[StepResult], vehicle: str) -> str:
    """The side-by-side table (markdown)."""
    fr = lambda xs: " / ".join(f"{x:.2f}" for x in xs[:5])  # noqa: E731
    ov = lambda x: "none" if x is None else f"{x:.0f} %"  # noqa: E731
    lines = [
        "| step | source | t63 s | t90 s | overshoot | peak accel m/s^2 | fraction at 0.3 / 0.6 / 1 / 2 / 4 s | after 7.5 s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    diffs = fraction_differences(results)
    for r, ref, d in zip(results, MEASURED_PX4_SITL, diffs):
        lines.append(f"| {r.label} | PX4 SITL (measured) | {ref[4]:.2f} | {ref[5]:.2f} | {ov(ref[6])} | {ref[7]:.1f} | "
                     f"{fr(ref[8])} | {ref[8][5]:.2f} |")
        lines.append(f"| | mavsim `{vehicle}` | {r.t63_s:.2f} | {r.t90_s:.2f} | {ov(r.overshoot_pct)} | "
                     f"{r.peak_accel_mps2:.1f} | {fr(r.fractions)} | {r.fractions[5]:.2f} |")
        lines.append(f"| | difference | | | | | {' / '.join(f'{x:+.2f}' for x in d[:5])} | {d[5]:+.2f} |")
    within = int((np.abs(diffs) <= 0.05 + 1e-9).sum())
    lines.append("")
    lines.append(f"fractions within 0.05 of PX4 SITL: {within} of {diffs.size}; largest difference "
                 f"{np.abs(diffs).max():.2f}; rms {np.sqrt(np.mean(diffs ** 2)):.3f}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicle", default="px4", choices=("px4", "lag"))
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    results = step_table(args.vehicle)
    if args.json:
        print(json.dumps({"vehicle": args.vehicle, "steps": [asdict(r) for r in results],
                          "fraction_differences": fraction_differences(results).round(3).tolist()}, indent=2))
    else:
        print(format_table(results, args.vehicle))
    return 0


if __name__ == "__main__":
    sys.exit(main())
