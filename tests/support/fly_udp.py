"""``companion fly`` as a process against mavsim in a thread over loopback UDP, with a sender beside it.

Shared by the real-time tests that attack ``fly`` while it flies (garbage on the autopilot
port, hostile obstacle reports on an obstacle link): the ports, the two programs, the
start order (the companion's sockets bound before mavsim sends), bounded waits and the
teardown, and the setpoints the companion streamed, read back from its tlog.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from companion.mavlink.tlog import read_tlog
from mavsim.core import Simulator
from mavsim.scenario import load_scenario
from mavsim.udp import LinkAddress, UdpServer
from tests.support.ports import free_udp_port

FLY_TIMEOUT_S = 120.0


@dataclass
class FlyRun:
    """What one flight left: mavsim's simulator (its truth), fly's stdout, stderr and exit code, and its tlog."""

    sim: Simulator
    out: str
    err: str
    tlog: Path
    returncode: int


def fly_beside_mavsim(scenario: Path, tmp_path: Path, *, autopilot_port: int, duration_s: float,
                      extra_obstacle_ports: Sequence[int] = (), start_sender: Callable[[], None] = lambda: None,
                      stop_sender: Callable[[], None] = lambda: None,
                      during: Callable[[subprocess.Popen, Simulator], None] | None = None,
                      new_session: bool = False, fly_port: int | None = None,
                      env: dict[str, str] | None = None,
                      launcher: Sequence[str] = ("-m", "companion.cli")) -> FlyRun:
    """Fly ``scenario`` with mavsim on ``autopilot_port`` while a sender runs; every wait bounded.

    mavsim's obstacles go to an obstacle link of their own; ``extra_obstacle_ports`` are
    further obstacle links of ``fly`` (for a sender). ``start_sender`` runs once fly's
    sockets are bound, ``stop_sender`` when fly has ended (it must join its thread).
    ``during(fly, sim)`` runs after ``start_sender``, before waiting for fly to end (to signal
    fly, or act on the simulated vehicle as a pilot would);
    ``new_session`` puts fly in a process group of its own (its planning process with it).
    ``fly_port``: the port fly listens on when it is not ``autopilot_port`` (a proxy between them).
    ``env``: variables added to fly's environment (systemd's ``NOTIFY_SOCKET``, say).
    ``launcher``: Python's arguments before ``fly`` (a wrapper module instead of ``companion.cli``).
    """
    sim_obstacle_port = free_udp_port()
    sim = Simulator(load_scenario(scenario), seed=0)
    server = UdpServer(sim, [LinkAddress("api", 0, autopilot_port), LinkAddress("obstacles", 0, sim_obstacle_port)],
                       speed=1.0)
    serve = threading.Thread(target=server.run, args=(60.0,), daemon=True)
    tlog = tmp_path / "fly.tlog"
    obstacles = [arg for p in (sim_obstacle_port, *extra_obstacle_ports) for arg in ("--obstacles", f"udpin:127.0.0.1:{p}")]
    fly = subprocess.Popen(
        [sys.executable, *launcher, "fly", "--connect", f"udpin:127.0.0.1:{fly_port or autopilot_port}",
         "--scenario", str(scenario), *obstacles,
         "--duration", str(duration_s), "--exit-after-goal", "1.0", "--tlog", str(tlog), "--json"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=new_session,
        env=None if env is None else {**os.environ, **env})
    time.sleep(0.5)  # the companion's sockets are bound before mavsim sends
    serve.start()
    start_sender()
    try:
        if during is not None:
            during(fly, sim)
        out, err = fly.communicate(timeout=FLY_TIMEOUT_S)
    finally:
        stop_sender()
        if fly.poll() is None:
            fly.kill()
            fly.communicate()
        server.stop()
        serve.join(timeout=5)
        server.close()
    return FlyRun(sim, out, err, tlog, fly.returncode)


def streamed_setpoints(tlog: Path) -> tuple[np.ndarray, np.ndarray]:
    """Send times (s) and velocities (N, 3) of the setpoints the companion (component 191) logged."""
    setpoints = [(t, m) for t, m in read_tlog(tlog)
                 if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED" and m.get_srcComponent() == 191]
    return np.array([t for t, _ in setpoints]), np.array([[m.vx, m.vy, m.vz] for _, m in setpoints]).reshape(-1, 3)
