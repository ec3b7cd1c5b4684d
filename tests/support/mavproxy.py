"""MAVProxy (the PyPI package) as the router between an autopilot and ``companion fly``, for tests.

A companion computer often reaches its autopilot through a router: MAVProxy or
mavlink-router owns the serial port and hands the stream to the companion, the ground
station and a logger over UDP. :class:`MavProxy` starts ``mavproxy.py`` with the autopilot
as its master (``udpin``: it answers whoever sends) and the companion as an output
(``udpout``), headless and without its modules (no parameter or mission download of its
own, no stream-rate requests), and ends it. Every wait is bounded.

Where it comes from: ``$MAVPROXY`` (the path of ``mavproxy.py``), else ``mavproxy.py`` on the
PATH, else ``out/mavproxy-venv/bin/mavproxy.py`` (made by ``make mavproxy-test``: MAVProxy
without its GUI's dependencies, which a router does not use).
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

from tests.support.ports import wait_for_udp_listener

ROOT = Path(__file__).resolve().parents[2]
VENV_MAVPROXY = ROOT / "out" / "mavproxy-venv" / "bin" / "mavproxy.py"
START_S = 20.0


def find_mavproxy() -> str | None:
    """The ``mavproxy.py`` to run, or None when there is none (see the module docstring)."""
    given = os.environ.get("MAVPROXY")
    if given:
        return given
    return shutil.which("mavproxy.py") or (str(VENV_MAVPROXY) if VENV_MAVPROXY.exists() else None)


class MavProxy:
    """``mavproxy.py --master=udpin:127.0.0.1:MASTER --out=udpout:127.0.0.1:OUT``, headless, as a process.

    Parameters
    ----------
    executable : ``mavproxy.py``'s path.
    master_port : where the autopilot sends (MAVProxy binds it).
    out_port : where the companion listens (``fly --connect udpin:127.0.0.1:OUT``).
    workdir : MAVProxy's state directory and its output file (``mavproxy.log``).
    """

    def __init__(self, executable: str, master_port: int, out_port: int, workdir: Path) -> None:
        self.command = [executable, f"--master=udpin:127.0.0.1:{master_port}", f"--out=udpout:127.0.0.1:{out_port}",
                        "--daemon", "--non-interactive", "--nowait", "--mav20", "--default-modules=",
                        "--streamrate=-1", "--no-state", f"--state-basedir={workdir}"]
        self.master_port = master_port
        self.log = Path(workdir) / "mavproxy.log"
        self.proc: subprocess.Popen | None = None

    def start(self) -> None:
        """Start it and wait (at most :data:`START_S`) until it holds the master port."""
        self.log.parent.mkdir(parents=True, exist_ok=True)
        with open(self.log, "wb") as out:
            self.proc = subprocess.Popen(self.command, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                         start_new_session=True)
        if not wait_for_udp_listener(self.master_port, self.proc, START_S):
            self.stop()
            raise RuntimeError(f"MAVProxy did not bind udp 127.0.0.1:{self.master_port} within {START_S:.0f} s: "
                               f"{self.output()[-2000:]}")

    def stop(self) -> None:
        """SIGTERM, then SIGKILL after 5 s."""
        if self.proc is None or self.proc.poll() is not None:
            return
        self.proc.terminate()
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(timeout=5)

    def output(self) -> str:
        return self.log.read_text(errors="replace") if self.log.exists() else ""
