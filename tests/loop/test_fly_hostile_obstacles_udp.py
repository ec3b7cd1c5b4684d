"""Hostile obstacle reports at ``companion fly``'s obstacle link over loopback UDP (issue 14).

mavsim serves ``short_hop`` in a thread; ``companion fly`` runs as its own process with an
obstacle link; a third socket sends that link well-formed but hostile ODOMETRY and
LOCAL_POSITION_NED the whole flight: covariances of 1e30 m^2, NaN and infinite fields,
100 systems on a 6 m ring round the route, and stamps of 0xFFFFFFFF. The companion must
not crash, must stream only finite setpoints at its rate, fly the mission without
collision and count the reports it refuses. 25-45 s of wall time: marked realtime
(``make realtime-test``).
"""

from __future__ import annotations

import json
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from tests.support.fly_udp import fly_beside_mavsim, streamed_setpoints
from tests.support.ports import free_udp_port

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "tests" / "data" / "short_hop.toml"
RING_IDS = range(150, 250)  # 100 systems
HUGE, NAN, INF = 1e30, float("nan"), float("inf")


def _cov(var: float) -> list[float]:
    cov = [0.0] * 21
    for i in (0, 6, 11):
        cov[i] = var
    return cov


#: Ring systems that send each round's report twice, 50 ms older first: at any speed of the machine
#: the older one waits in the stream's backlog when the newer arrives and is superseded (counted).
#: Without them, how many reports were superseded measured only how loaded the machine was: a
#: clean-clone CI run on a quiet machine counted 684 where the test asks for more than 1000.
TWICE_IDS = RING_IDS[:40]
TWICE_OLDER_S = 0.05


class HostileSender:
    """Sends one round of every hostile kind every 0.1 s (about 1440 reports per second)."""

    def __init__(self, port: int, seed: int = 3) -> None:
        self.port = port
        self.rng = np.random.default_rng(seed)
        self.sent = 0
        self.pairs_sent = 0  #: reports of TWICE_IDS followed at once by a newer one of theirs
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.mav = {sysid: mavlink2.MAVLink(None, sysid, 197) for sysid in (*RING_IDS, 140, 141, 142, 143)}

    def _round(self, t_s: float) -> list[bytes]:
        def pack(sysid: int, msg) -> bytes:
            mav = self.mav[sysid]
            packet = bytes(msg.pack(mav))
            mav.seq = (mav.seq + 1) % 256
            return packet

        t_us, t_ms = int(t_s * 1e6), int(t_s * 1e3)
        odometry = mavlink2.MAVLink_odometry_message
        out = [
            # a covariance of 1e30 m^2, everything else plausible, 2 m beside the route
            pack(140, odometry(t_us, 1, 1, 2.0, 2.0, -5.0, [1, 0, 0, 0], 0, 0, 0, 0, 0, 0, _cov(HUGE), _cov(HUGE), 0, 0, 100)),
            # NaN and infinite positions, velocities and covariances
            pack(141, odometry(t_us, 1, 1, NAN, INF, -5.0, [1, 0, 0, 0], INF, NAN, 0, 0, 0, 0, _cov(NAN), _cov(INF), 0, 0, 0)),
            pack(142, mavlink2.MAVLink_local_position_ned_message(t_ms, 2.0, -INF, NAN, NAN, 0.0, INF)),
            # the largest stamp there is (from well off the route: its track is real, and reset again and again)
            pack(143, mavlink2.MAVLink_local_position_ned_message(0xFFFFFFFF, 2.0, -40.0, -5.0, 0.0, 0.0, 0.0)),
        ]
        angles = np.linspace(0.0, 2 * np.pi, len(RING_IDS), endpoint=False)
        for sysid, a in zip(RING_IDS, angles):  # 100 ids on a 6 m ring round the route's middle, 0.2 m accurate
            x, y = 2.0 + 6.0 * np.cos(a), 6.0 * np.sin(a)
            stamps = (max(0, t_us - int(TWICE_OLDER_S * 1e6)), t_us) if sysid in TWICE_IDS else (t_us,)
            self.pairs_sent += len(stamps) - 1
            for stamp in stamps:  # back to back: the older one is still waiting when the newer one comes
                out.append(pack(sysid, odometry(stamp, 1, 1, x, y, -5.0, [1, 0, 0, 0], 0, 0, 0, 0, 0, 0,
                                                _cov(0.04), _cov(0.01), 0, 0, 100)))
        return out

    def _run(self) -> None:
        t0 = time.monotonic()
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            while not self.stop.is_set():
                for packet in self._round(time.monotonic() - t0):
                    s.sendto(packet, ("127.0.0.1", self.port))
                    self.sent += 1
                self.stop.wait(0.1)


@pytest.mark.realtime
def test_that_hostile_obstacle_reports_neither_crash_fly_nor_slow_its_stream(tmp_path):
    obstacle_port = free_udp_port()
    hostile = HostileSender(obstacle_port)

    def stop_hostile() -> None:
        hostile.stop.set()
        hostile.thread.join(timeout=5)

    run = fly_beside_mavsim(SCENARIO, tmp_path, autopilot_port=free_udp_port(), duration_s=30,
                            extra_obstacle_ports=(obstacle_port,), start_sender=hostile.thread.start,
                            stop_sender=stop_hostile)
    out, err, sim = run.out, run.err, run.sim
    assert "Traceback" not in err, err[-3000:]
    report = json.loads(out)
    assert hostile.sent > 5000
    assert any("ENGAGED" in text for _, text in report["events"]), report["events"]
    assert report["goal_reached_companion_t_s"] is not None, (report["events"], report)
    assert not sim.recorder.summary()["collided"]
    # the refused reports are counted, per source and reason
    rejected = report["obstacle_intake"]["rejected"]

    def refused(sysid: int, reason: str) -> int:
        return sum(n for k, n in rejected.items() if f" sys {sysid}: " in k and reason in k)

    # (the stream handles only the newest waiting report of a source: the rest are superseded, counted;
    # TWICE_IDS send 400 a second that a newer one of theirs follows at once: at least half of those)
    assert report["inbound_superseded"] > max(1000, hostile.pairs_sent // 2), (report["inbound_superseded"], hostile.pairs_sent)
    assert refused(140, "variances above") >= 5, rejected             # 1e30 m^2
    assert refused(141, "non-finite") >= 5 and refused(142, "non-finite") >= 5, rejected
    # a stamp stuck at 0xFFFFFFFF: its reports are duplicates or restart its clock (the track is reset), counted
    restarts = report["obstacle_intake"]["clock_restarts"]
    assert refused(143, "") + sum(n for k, n in restarts.items() if k.endswith(" sys 143")) >= 3, (rejected, restarts)
    assert report["tracks"] >= 100 and report["tracks_unconstrained_max"] > 0  # the ring: tracked, K constrained
    # every setpoint finite and bounded; the stream held its rate
    t, v = streamed_setpoints(run.tlog)
    assert len(t) > 100 and np.all(np.isfinite(v)) and np.abs(v).max() <= 2.0 + 1e-6
    rate = (len(t) - 1) / (t[-1] - t[0])
    assert rate >= 19.0, f"stream rate {rate:.2f} Hz"
    # (no gap near PX4's 1.3 s offboard loss; the 150 ms must-show is tests/loop/test_realtime_crowd.py)
    assert np.diff(t).max() < 0.5, f"largest setpoint gap {np.diff(t).max():.3f} s"
