"""Start and stop ArduCopter SITL for the ``make ardupilot-test`` suite.

The build is ``ARDUPILOT_SITL_DIR`` or ``../shared/ardupilot-sitl`` from the repository root: either
the unpacked ``arducopter-sitl/`` (``bin/arducopter``) or the directory holding ``start-arducopter``
and ``arducopter-sitl.tar.gz``, which is then unpacked to a temporary directory once per session.
``start-arducopter RUN_DIR -I N`` starts instance N: its companion link (SERIAL2) sends to
127.0.0.1:(14540+N), its ground-station link (SERIAL0) to 127.0.0.1:(14550+N), both from ephemeral
ports. :func:`free_instance` picks an N >= 3 whose ports are free (PX4 SITL uses 14540/14550/14580).
Readiness (the EKF's absolute position) takes about 42 s after the start; the companion waits for it.
"""

from __future__ import annotations

import atexit
import logging
import os
import shutil
import signal
import socket
import subprocess
import tarfile
import tempfile
import time
from pathlib import Path

from tests.support.ports import udp_port_taken

logger = logging.getLogger(__name__)

REPO = Path(__file__).resolve().parents[2]
SCRIPT = "start-arducopter"
#: 0..2 are left to PX4 SITL and others (14540..14542); ARDUPILOT_SITL_FIRST_INSTANCE raises it
#: (a machine where other sessions fly instances 3 and 4)
FIRST_INSTANCE = int(os.environ.get("ARDUPILOT_SITL_FIRST_INSTANCE", "3"))
_unpacked: Path | None = None
#: lines arducopter prints once its serial ports are open (its start took under a second in ~75
#: starts; once it stopped after "Smoothing reset at 0.001", before opening any link, and the
#: companion heard nothing for 150 s)
STARTED_MARKERS = ("Validating structures", "Waiting for internal clock")
START_TIMEOUT_S = 15.0


def _shared() -> Path:
    env = os.environ.get("ARDUPILOT_SITL_DIR")
    path = Path(env) if env else REPO.parent / "shared" / "ardupilot-sitl"
    return path if path.is_absolute() else REPO / path


def _script() -> Path | None:
    """``start-arducopter``: in ARDUPILOT_SITL_DIR, beside it, or in ../shared/ardupilot-sitl."""
    base = _shared()
    for cand in (base / SCRIPT, base.parent / SCRIPT, REPO.parent / "shared" / "ardupilot-sitl" / SCRIPT):
        if cand.is_file():
            return cand
    return None


def _unpacked_tree(base: Path) -> Path | None:
    """``base`` or ``base/arducopter-sitl`` when it holds ``bin/arducopter``, else None."""
    for cand in (base, base / "arducopter-sitl"):
        if (cand / "bin" / "arducopter").is_file():
            return cand
    return None


def build_dir() -> Path | None:
    """The unpacked ``arducopter-sitl`` directory (``bin/arducopter``), unpacking the tarball to a
    temporary directory when only it is there; None when there is no build."""
    global _unpacked
    base = _shared()
    tree = _unpacked_tree(base)
    if tree is not None:
        return tree
    tarball = base / "arducopter-sitl.tar.gz"
    if not tarball.is_file():
        return None
    if _unpacked is None:
        tmp = Path(tempfile.mkdtemp(prefix="arducopter-sitl-"))
        with tarfile.open(tarball) as tar:
            tar.extractall(tmp, filter="data")
        atexit.register(shutil.rmtree, tmp, True)
        _unpacked = tmp / "arducopter-sitl"
    return _unpacked


def available() -> bool:
    return _script() is not None and build_dir() is not None


def present() -> bool:
    """Whether a build is there (``start-arducopter`` and the tarball or its unpacked tree), without
    unpacking it: what ``.ci/run`` and ``make flake-check`` ask before they run the ArduCopter stage."""
    base = _shared()
    return _script() is not None and (_unpacked_tree(base) is not None or (base / "arducopter-sitl.tar.gz").is_file())


def _tcp_free(port: int) -> bool:
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        s.bind(("0.0.0.0", port))
        return True
    except OSError:
        return False
    finally:
        s.close()


def free_instance() -> int:
    """The first instance N >= :data:`FIRST_INSTANCE` whose UDP ports 14540+N, 14550+N and RC 5501+10N
    and TCP 5762+10N are free."""
    for n in range(FIRST_INSTANCE, 10):
        if all(not udp_port_taken(p) for p in (14540 + n, 14550 + n, 5501 + 10 * n)) and _tcp_free(5762 + 10 * n):
            return n
    raise RuntimeError(f"no free ArduCopter SITL instance ({FIRST_INSTANCE}..9): ports 1454{FIRST_INSTANCE}..14549 / "
                       f"1455{FIRST_INSTANCE}..14559 in use")


class CentredSticks:
    """A pilot's transmitter with its sticks at rest: RC input to SITL instance ``instance`` (UDP
    127.0.0.1:5501+10N, 8 x uint16 PWM per datagram, :data:`RATE_HZ`), a context manager.

    SITL's own RC input without a sender is ArduPilot's default: sticks centred, throttle 1000
    (down), mode channel 1800. In LOITER (the hand-back) throttle is the pilot's climb rate, so a
    throttle held down descends and lands: measured, "SIM Hit ground at 2.44 m/s" 3.3 s after the
    companion handed a vehicle at 5 m back to LOITER. A pilot ready to take over holds the
    throttle at mid (1500): LOITER holds the altitude there. The other channels keep SITL's values.
    Call :meth:`start` once airborne: arming with the throttle at mid is refused (the companion
    gave up after 11 attempts when the sticks were sent from the SITL's start).
    """

    PWM = (1500, 1500, 1500, 1500, 1800, 1000, 1000, 1800)
    RATE_HZ = 50.0

    def __init__(self, instance: int) -> None:
        import threading

        self.address = ("127.0.0.1", 5501 + 10 * int(instance))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="centred-sticks", daemon=True)

    def _run(self) -> None:
        import struct

        packet = struct.pack(f"<{len(self.PWM)}H", *self.PWM)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            while not self._stop.wait(1.0 / self.RATE_HZ):
                sock.sendto(packet, self.address)

    def start(self) -> None:
        if not self._thread.is_alive() and not self._stop.is_set():
            self._thread.start()

    def __enter__(self) -> CentredSticks:
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=1.0)


class Sitl:
    """ArduCopter SITL instance ``instance`` in ``run_dir``; a context manager that always stops it."""

    def __init__(self, run_dir: str | os.PathLike, instance: int, params: dict[str, float] | None = None,
                 companion_device: str | None = None) -> None:
        script, build = _script(), build_dir()
        if script is None or build is None:
            raise RuntimeError("no ArduCopter SITL build: set ARDUPILOT_SITL_DIR or put one at ../shared/ardupilot-sitl")
        self.script, self.build = script, build
        self.run_dir, self.instance = Path(run_dir), int(instance)
        self.params = dict(params or {})
        self.companion_device = companion_device
        self.pid: int | None = None

    @property
    def companion_port(self) -> int:
        return 14540 + self.instance

    @property
    def gcs_port(self) -> int:
        return 14550 + self.instance

    @property
    def log_path(self) -> Path:
        """The console output of the instance (``start-arducopter`` truncates it at every start)."""
        return self.run_dir / "arducopter.log"

    def __enter__(self) -> Sitl:
        """Start the instance and wait until it has opened its serial ports (:data:`STARTED_MARKERS` in
        its console output, normally within a second); one that has not within :data:`START_TIMEOUT_S`
        is stopped and started afresh once, with a warning. Raises RuntimeError when the second does
        not start either, with the end of its console output."""
        for attempt in (1, 2):
            self._start()
            if self._started(START_TIMEOUT_S):
                return self
            tail = self._log_tail()
            self.stop()
            if attempt == 1:
                logger.warning("ArduCopter SITL instance %d did not open its ports within %.0f s (its console "
                               "output ends %r); stopped, starting it again", self.instance, START_TIMEOUT_S, tail)
        raise RuntimeError(f"ArduCopter SITL instance {self.instance} did not open its ports within "
                           f"{START_TIMEOUT_S:.0f} s twice; {self.log_path} ends {tail!r}")

    def _start(self) -> None:
        env = {**os.environ, "ARDUPILOT_SITL_DIR": str(self.build)}
        if self.params:
            env["ARDUCOPTER_PARAMS"] = " ".join(f"{k}={v}" for k, v in self.params.items())
        if self.companion_device:
            env["ARDUCOPTER_COMPANION"] = self.companion_device
        out = subprocess.run([str(self.script), str(self.run_dir), "-I", str(self.instance)], check=True,
                             capture_output=True, text=True, timeout=60, env=env)
        self.pid = int(out.stdout.strip().splitlines()[-1])
        logger.info("ArduCopter SITL instance %d started, pid %d, in %s", self.instance, self.pid, self.run_dir)

    def _started(self, timeout_s: float) -> bool:
        """Whether the console output shows a marker of :data:`STARTED_MARKERS` within ``timeout_s``
        (False at once when the process has gone)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if any(m in self._log_head(65536) for m in STARTED_MARKERS):
                return True
            if not self.alive():
                return False
            time.sleep(0.1)
        return False

    def _log_head(self, size: int) -> str:
        try:
            with open(self.log_path, "rb") as f:
                return f.read(size).decode("utf-8", "replace")
        except OSError:
            return ""

    def _log_tail(self, size: int = 160) -> str:
        try:
            with open(self.log_path, "rb") as f:
                f.seek(0, os.SEEK_END)
                f.seek(max(0, f.tell() - size))
                return f.read().decode("utf-8", "replace")
        except OSError:
            return ""

    def alive(self) -> bool:
        if self.pid is None:
            return False
        try:
            os.kill(self.pid, 0)
        except ProcessLookupError:
            return False
        return True

    def stop(self) -> None:
        """SIGTERM, then SIGKILL after 5 s; safe to call twice."""
        if self.pid is None:
            return
        pid, self.pid = self.pid, None
        for sig, wait_s in ((signal.SIGTERM, 5.0), (signal.SIGKILL, 2.0)):
            try:
                os.kill(pid, sig)
            except ProcessLookupError:
                return
            deadline = time.monotonic() + wait_s
            while time.monotonic() < deadline:
                try:
                    os.kill(pid, 0)
                except ProcessLookupError:
                    return
                time.sleep(0.1)

    def __exit__(self, *exc) -> None:
        self.stop()


if __name__ == "__main__":      # `python -m tests.ardupilot.sitl --present`: exit 0 when a build is there
    import sys

    if sys.argv[1:] != ["--present"]:
        print("usage: python -m tests.ardupilot.sitl --present", file=sys.stderr)
        sys.exit(2)
    sys.exit(0 if present() else 1)
