"""How old the autopilot's newest pose looks through :class:`VehicleClock`, tick by tick, from a tlog.

    python -m tests.support.clock_age flight.tlog [more.tlog ...]

Feeds the autopilot's ODOMETRY arrivals (component 1 of the vehicle) and the companion's
TIMESYNC requests and their answers (component 191) to a fresh
:class:`companion.loop.vehicle_clock.VehicleClock`, in the tlog's order and at its receive
stamps, and every 50 ms of link time compares the newest pose's age as the clock maps it
(``vehicle_time(t) - stamp``, what the loop holds against ``estimate_timeout_s``) with the
link time since it arrived. Over loopback the two differ by the latency, about a millisecond;
more is the mapping's lag. Prints, per log, the autopilot clock's rate against link time
(the slope of its pose stamps) and the excess's median, 99th percentile and largest (ms).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from pymavlink import mavutil

from companion.loop.vehicle_clock import VehicleClock

COMPANION_COMPONENT = 191
AUTOPILOT_COMPONENT = 1
TICK_S = 0.05


def events(path: str) -> list[tuple[float, str, object]]:
    """(receive stamp s, kind, value): ``pose`` (stamp s), ``request`` (ts1 ns), ``answer`` ((tc1, ts1) ns)."""
    log = mavutil.mavlink_connection(path)
    out: list[tuple[float, str, object]] = []
    while (msg := log.recv_match(type=["ODOMETRY", "TIMESYNC"], blocking=False)) is not None:
        t, comp = msg._timestamp, msg.get_srcComponent()
        if msg.get_type() == "ODOMETRY" and comp == AUTOPILOT_COMPONENT:
            out.append((t, "pose", msg.time_usec * 1e-6))
        elif msg.get_type() == "TIMESYNC" and comp == COMPANION_COMPONENT and msg.tc1 == 0:
            out.append((t, "request", msg.ts1))
        elif msg.get_type() == "TIMESYNC" and comp == AUTOPILOT_COMPONENT and msg.tc1 != 0:
            out.append((t, "answer", (msg.tc1, msg.ts1)))
    return out


def age_excess_ms(evs: list[tuple[float, str, object]], clock: VehicleClock) -> np.ndarray:
    """Mapped age less the link time since arrival (ms), every :data:`TICK_S` from 2 s after the first event."""
    excess, newest, i = [], None, 0
    for t in np.arange(evs[0][0] + 2.0, evs[-1][0], TICK_S):
        while i < len(evs) and evs[i][0] <= t:
            t_rx, kind, value = evs[i]
            if kind == "pose":
                clock.observe_pose(t_rx, value)
                newest = (t_rx, value)
            elif kind == "request":
                clock._pending.append(value)   # the request as the companion sent it
            else:
                clock.answer(t_rx, *value)
            i += 1
        if newest is not None:
            excess.append((clock.vehicle_time(t) - newest[1]) - (t - newest[0]))
    return 1e3 * np.array(excess)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tlogs", nargs="+")
    args = parser.parse_args(argv)
    for path in args.tlogs:
        evs = events(path)
        poses = np.array([(t, v) for t, kind, v in evs if kind == "pose"])
        if len(poses) < 2:
            print(f"clock_age: {path}: fewer than two ODOMETRY from the autopilot", file=sys.stderr)
            return 2
        rate = np.polyfit(poses[:, 0] - poses[0, 0], poses[:, 1] - poses[0, 1], 1)[0]
        e = age_excess_ms(evs, VehicleClock())
        print(f"{path}: clock rate {rate:.4f}; age excess median {np.median(e):.1f} ms, "
              f"p99 {np.percentile(e, 99):.1f} ms, max {e.max():.1f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
