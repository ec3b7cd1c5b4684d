"""GUIDED velocity steps flown against ArduCopter (SITL, or mavsim's ``ardupilot`` personality), measured.

Usage::

    python -m tests.benchmarks.ardupilot_steps fly --connect udpin:127.0.0.1:14546 --out sitl.json
    mavsim --autopilot ardupilot --scenario STEPS.toml --on-ground --forever --api-port 14547 --api-local-port 14587 --no-gcs &
    python -m tests.benchmarks.ardupilot_steps fly --connect udpin:127.0.0.1:14547 --out mavsim.json
    python -m tests.benchmarks.ardupilot_steps table sitl.json mavsim.json

(STEPS.toml: any scenario with ``[sim] vehicle = "ardupilot"`` and the sensor noise off.)

``fly`` does what a companion does on ArduCopter's companion link (pymavlink, sysid 245/191):
asks for LOCAL_POSITION_NED and POSITION_TARGET_LOCAL_NED at 50 Hz and EKF_STATUS_REPORT at 2 Hz
(MAV_CMD_SET_MESSAGE_INTERVAL), waits until the EKF has an absolute horizontal position, sets
GUIDED, arms (retrying), takes off to 10 m above home, then flies the velocity steps of
:data:`STEPS` with velocity-only SET_POSITION_TARGET_LOCAL_NED (type_mask 3527) at 20 Hz, and
last a 2 m/s north leg after which the stream stops (the GUID_TIMEOUT hold). It ends in LOITER.
Every LOCAL_POSITION_NED and POSITION_TARGET_LOCAL_NED is recorded with the vehicle's
``time_boot_ms``.

``table`` prints, per step, t63 / t90 / overshoot and the fraction of the step reached at
0.3 / 0.6 / 1 / 2 / 4 s, t = 0 being the vehicle's echo of the new target (as in the SITL
README's FACTS table), and for the stream stop: when the target was zeroed, when the vehicle
started slowing and when it was below 0.1 m/s, after the last setpoint.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

#: (label, axis "north"/"up", to m/s, hold s). Each step starts from the previous one's value.
STEPS: tuple[tuple[str, str, float, float], ...] = (
    ("north 0 -> 1", "north", 1.0, 6.0),
    ("north 1 -> 0", "north", 0.0, 6.0),
    ("north 0 -> 3", "north", 3.0, 6.0),
    ("north 3 -> 0", "north", 0.0, 6.0),
    ("up 0 -> 1", "up", 1.0, 5.0),
    ("up 1 -> 0", "up", 0.0, 5.0),
    ("up 0 -> 3", "up", 3.0, 4.5),
    ("up 3 -> 0", "up", 0.0, 6.0),
)
FRACTION_TIMES_S = (0.3, 0.6, 1.0, 2.0, 4.0)
SETPOINT_RATE_HZ = 20.0
VELOCITY_ONLY = 3527
TAKEOFF_M = 10.0
#: The stream-stop leg: north at this speed for this long, then nothing for STOP_WATCH_S.
STOP_SPEED_MPS, STOP_LEG_S, STOP_WATCH_S = 2.0, 4.0, 8.0

#: Measured on ArduCopter SITL 4.7.0-dev (shared/ardupilot-sitl/README.md, FACTS section 3):
#: label -> (t63, t90, fractions at FRACTION_TIMES_S). The reference the personality was fitted to.
MEASURED_SITL_README: dict[str, tuple[float, float, tuple[float, ...]]] = {
    "north 0 -> 1": (0.71, 1.19, (.10, .51, .84, .97, 1.02)),
    "north 1 -> 0": (0.71, 1.19, (.10, .50, .84, .98, 1.01)),
    "north 0 -> 3": (1.06, 1.61, (.03, .22, .58, .95, 1.01)),
    "north 3 -> 0": (1.07, 1.64, (.03, .21, .57, .95, 1.02)),
    "up 0 -> 1": (0.78, 1.03, (.13, .43, .88, 1.04, .99)),
    "up 1 -> 0": (0.78, 1.03, (.13, .43, .87, 1.03, .98)),
    "up 0 -> 3": (1.96, 2.75, (.05, .15, .30, .64, 1.00)),
    "up 3 -> 0": (1.58, 2.42, (.10, .27, .43, .77, .98)),
}


def _velocity_setpoint(mav, sysid: int, time_boot_ms: int, v_ned) -> None:
    mav.set_position_target_local_ned_send(time_boot_ms, sysid, 1, 1, VELOCITY_ONLY, 0.0, 0.0, 0.0,
                                           float(v_ned[0]), float(v_ned[1]), float(v_ned[2]), 0.0, 0.0, 0.0, 0.0, 0.0)


class _Recorder:
    """Collects LOCAL_POSITION_NED / POSITION_TARGET_LOCAL_NED samples and other news."""

    def __init__(self) -> None:
        self.lpn: list[tuple[float, float, float, float]] = []
        self.target: list[tuple[float, float, float, float]] = []
        self.marks: list[tuple[str, float, float]] = []    # (what, vehicle s, wall s)
        self.ekf_flags = 0
        self.acks: list[tuple[int, int]] = []
        self.mode = None
        self.armed = False
        self.texts: list[str] = []
        self.last_boot_s = 0.0

    def take(self, msg) -> None:
        t = msg.get_type()
        if t == "LOCAL_POSITION_NED":
            self.last_boot_s = msg.time_boot_ms / 1e3
            self.lpn.append((msg.time_boot_ms / 1e3, msg.vx, msg.vy, msg.vz, msg.x))
        elif t == "POSITION_TARGET_LOCAL_NED":
            self.target.append((msg.time_boot_ms / 1e3, msg.vx, msg.vy, msg.vz))
        elif t == "EKF_STATUS_REPORT":
            self.ekf_flags = msg.flags
        elif t == "COMMAND_ACK":
            self.acks.append((msg.command, msg.result))
        elif t == "HEARTBEAT" and msg.get_srcComponent() == 1:
            self.mode, self.armed = msg.custom_mode, bool(msg.base_mode & 128)
        elif t == "STATUSTEXT":
            self.texts.append(msg.text)


def fly(connect: str, out: str) -> dict:
    """Fly :data:`STEPS` on ``connect`` (pymavlink connection string); write and return the record."""
    from pymavlink import mavutil
    m = mavutil.mavlink_connection(connect, source_system=245, source_component=191, dialect="ardupilotmega")
    rec = _Recorder()
    sysid = 1
    wall0 = time.monotonic()

    def pump(seconds: float) -> None:
        end = time.monotonic() + seconds
        while True:
            left = end - time.monotonic()
            if left <= 0:
                return
            msg = m.recv_match(blocking=True, timeout=min(left, 0.02))
            while msg is not None:
                rec.take(msg)
                msg = m.recv_match(blocking=False)

    def command(cmd: int, *params: float) -> int | None:
        p = list(params) + [0.0] * (7 - len(params))
        n = len(rec.acks)
        m.mav.command_long_send(sysid, 1, cmd, 0, *p)
        for _ in range(100):
            pump(0.02)
            for c, r in rec.acks[n:]:
                if c == cmd:
                    return r
        return None

    hb = m.wait_heartbeat(timeout=60)
    if hb is None:
        raise SystemExit("no HEARTBEAT")
    sysid = hb.get_srcSystem()
    rec.marks.append(("first heartbeat", 0.0, time.monotonic() - wall0))
    for msg_id, hz in ((32, 50.0), (85, 50.0), (193, 2.0)):
        print(f"interval {msg_id}: ack {command(511, msg_id, 1e6 / hz)}", file=sys.stderr)
    while not (rec.ekf_flags & 16 and not rec.ekf_flags & 128):
        pump(0.5)
    rec.marks.append(("ekf ready", rec.last_boot_s, time.monotonic() - wall0))
    print(f"EKF ready (flags {rec.ekf_flags}) after {time.monotonic() - wall0:.1f} s", file=sys.stderr)
    print(f"GUIDED: ack {command(176, 1, 4)}", file=sys.stderr)
    for attempt in range(20):
        r = command(400, 1)
        print(f"arm: ack {r}", file=sys.stderr)
        if r == 0:
            break
        pump(1.0)
    print(f"takeoff: ack {command(22, 0, 0, 0, 0, 0, 0, TAKEOFF_M)}", file=sys.stderr)
    pump(11.0)
    period = 1.0 / SETPOINT_RATE_HZ
    v = np.zeros(3)
    for label, axis, to, hold in STEPS:
        v = np.zeros(3)
        if axis == "north":
            v[0] = to
        else:
            v[2] = -to
        rec.marks.append((label, rec.last_boot_s, time.monotonic() - wall0))
        end = time.monotonic() + hold
        while time.monotonic() < end:
            _velocity_setpoint(m.mav, sysid, int(rec.last_boot_s * 1e3), v)
            pump(period)
    # the stream stop
    leg = np.array([STOP_SPEED_MPS, 0.0, 0.0])
    end = time.monotonic() + STOP_LEG_S
    while time.monotonic() < end:
        _velocity_setpoint(m.mav, sysid, int(rec.last_boot_s * 1e3), leg)
        last = rec.last_boot_s
        pump(period)
    rec.marks.append(("stream stopped", last, time.monotonic() - wall0))
    pump(STOP_WATCH_S)
    rec.marks.append(("mode after stop", float(rec.mode or -1), 0.0))
    m.mav.set_mode_send(sysid, 1, 5)   # LOITER
    pump(1.0)
    record = {"connect": connect, "lpn": rec.lpn, "target": rec.target, "marks": rec.marks,
              "texts": rec.texts, "acks": rec.acks}
    with open(out, "w") as f:
        json.dump(record, f)
    return record


def _interp_v(lpn: np.ndarray, axis: str, t: np.ndarray) -> np.ndarray:
    col = lpn[:, 1] if axis == "north" else -lpn[:, 3]
    return np.interp(t, lpn[:, 0], col)


def analyse(record: dict) -> dict:
    """Per-step figures and stream-stop figures of one record."""
    lpn = np.array(record["lpn"])
    tgt = np.array(record["target"]) if record["target"] else np.zeros((0, 4))
    marks = {name: t for name, t, _ in record["marks"]}
    out: dict = {"steps": {}}
    prev = 0.0
    for label, axis, to, hold in STEPS:
        t_send = marks[label]
        col = 1 if axis == "north" else 3
        want = to if axis == "north" else -to
        t0 = t_send
        if len(tgt):
            hit = np.nonzero((tgt[:, 0] >= t_send - 0.05) & (np.abs(tgt[:, col] - want) < 1e-3))[0]
            if len(hit):
                t0 = float(tgt[hit[0], 0])
        v0 = prev
        step = to - v0
        ts = t0 + np.arange(0.0, hold - 0.3, 0.005)
        frac = (_interp_v(lpn, axis, ts) - v0) / step
        def cross(level: float) -> float | None:
            i = np.nonzero(frac >= level)[0]
            return round(float(ts[i[0]] - t0), 3) if len(i) else None
        out["steps"][label] = {
            "t63": cross(0.63), "t90": cross(0.9), "overshoot_pct": round(float(max(0.0, frac.max() - 1.0) * 100), 1),
            "fractions": [round(float((_interp_v(lpn, axis, np.array([t0 + tf]))[0] - v0) / step), 3)
                          for tf in FRACTION_TIMES_S],
            "echo_delay_s": round(t0 - t_send, 3)}
        prev = to
    t_stop = marks.get("stream stopped")
    if t_stop is not None:
        after = lpn[lpn[:, 0] > t_stop]
        zero = tgt[(tgt[:, 0] > t_stop) & (np.abs(tgt[:, 1]) < 1e-3)] if len(tgt) else []
        slowing = after[after[:, 1] < STOP_SPEED_MPS - 0.05]
        still = after[np.hypot(after[:, 1], after[:, 2]) < 0.1]
        out["stop"] = {
            "target_zeroed_s": round(float(zero[0, 0] - t_stop), 2) if len(zero) else None,
            "slowing_s": round(float(slowing[0, 0] - t_stop), 2) if len(slowing) else None,
            "below_0.1_s": round(float(still[0, 0] - t_stop), 2) if len(still) else None,
            "mode_after": marks.get("mode after stop"),
        }
        if len(after) and len(after[0]) > 4:
            out["stop"]["distance_m"] = round(float(after[-1, 4] - after[0, 4]), 2)
    return out


def table(paths: list[str]) -> str:
    results = [(p, analyse(json.load(open(p)))) for p in paths]
    lines = ["| step | source | t63 s | t90 s | overshoot % | fraction at " + " / ".join(f"{t:g}" for t in FRACTION_TIMES_S) + " s |",
             "|---|---|---|---|---|---|"]
    for label, *_ in STEPS:
        t63, t90, fr = MEASURED_SITL_README[label]
        lines.append(f"| {label} | SITL README | {t63:.2f} | {t90:.2f} | | " + " / ".join(f"{x:.2f}" for x in fr) + " |")
        for p, r in results:
            s = r["steps"][label]
            fmt = lambda x: "-" if x is None else f"{x:.2f}"
            lines.append(f"| | {p} | {fmt(s['t63'])} | {fmt(s['t90'])} | {s['overshoot_pct']:.1f} | "
                         + " / ".join(f"{x:.2f}" for x in s["fractions"]) + " |")
    for p, r in results:
        if "stop" in r:
            lines.append(f"\nstream stop, {p}: {r['stop']}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tests.benchmarks.ardupilot_steps", description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    f = sub.add_parser("fly")
    f.add_argument("--connect", required=True)
    f.add_argument("--out", required=True)
    t = sub.add_parser("table")
    t.add_argument("paths", nargs="+")
    a = ap.parse_args(argv)
    if a.cmd == "fly":
        fly(a.connect, a.out)
    else:
        print(table(a.paths))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
