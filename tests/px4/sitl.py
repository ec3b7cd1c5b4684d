"""Start and stop the PX4 SITL (SIH quadrotor) build for the ``make px4-test`` suite.

The build is found at ``PX4_SITL_DIR`` or ``../shared/px4-sitl`` from the repository
root; its ``start-sih WORK_DIR`` script starts PX4 as a daemon and prints its PID.
Ports are PX4's: offboard link 14580 -> 14540, ground station 18570 -> 14550, SIH
ground truth (HIL_STATE_QUATERNION) 19450 -> 19410.

A fleet runs several instances side by side (``Sitl(..., instance=i, home=(lat, lon, alt))``):
PX4's ``-i i`` shifts those ports by ``i`` (the ground station's 14550 stays), gives the
vehicle system id ``i + 1``, and SIH starts the vehicle at ``home`` (``PX4_HOME_LAT`` /
``_LON`` / ``_ALT``), so each vehicle has its own EKF origin there. ``start-sih`` takes no
instance, so an instance is started as it does (the same environment and parameters),
with PX4's own ``-i``.
"""

from __future__ import annotations

import logging
import os
import shutil
import signal
import subprocess
import tarfile
import time
from pathlib import Path

logger = logging.getLogger(__name__)

REPO = Path(__file__).resolve().parents[2]
OFFBOARD_URL = "udpin:127.0.0.1:14540"
TRUTH_PORT = 19410
# PX4 parameters set at boot (start-sih applies PX4_PARAM_<NAME>). NAV_MC_ALT_RAD: PX4 ends
# AUTO.TAKEOFF once within this of the target altitude (default 0.8 m, measured: 4.28 to 4.67 m
# of 5 m at the switch, held at 4.7 to 4.85 m in Hold); 0.2 m lets the takeoff end at the
# requested altitude.
PARAMS = {"NAV_MC_ALT_RAD": 0.2}


# The flight's processes (PX4, the companion and its planner, the traffic player) run at this
# nice value where allowed: they are real-time processes, and on a shared 2-core machine at a
# load of 15 the planner at nice 0 returned a plan every 0.6 s instead of every 0.3 s and the
# drone flew stale plans into an obstacle. Set PX4_TEST_NICE=0 to run them at normal priority.
REALTIME_NICE = int(os.environ.get("PX4_TEST_NICE", "-10"))


def raise_priority() -> None:
    """Set this process's nice value to :data:`REALTIME_NICE` (a ``preexec_fn``); unchanged when not allowed."""
    try:
        os.setpriority(os.PRIO_PROCESS, 0, REALTIME_NICE)
    except OSError:
        pass


def sitl_dir() -> Path | None:
    """The PX4 SITL build directory (with ``start-sih``), or None when there is none."""
    env = os.environ.get("PX4_SITL_DIR")
    path = Path(env) if env else REPO.parent / "shared" / "px4-sitl"
    if not path.is_absolute():
        path = REPO / path
    return path if (path / "start-sih").is_file() else None


class Sitl:
    """PX4 SIH in a fresh working directory; a context manager that always stops it.

    Parameters
    ----------
    work_dir : path
        Created fresh by ``start-sih``; PX4's console output goes to ``work_dir/px4.log``.
    params : dict, optional
        PX4 parameters to set at boot (name -> value); default :data:`PARAMS`.
    boot_timeout_s : float
        Seconds to wait for "Ready for takeoff!" in the console log.
    instance : int
        PX4's instance (``px4 -i``): ports shifted by it, system id ``instance + 1``.
    home : (lat deg, lon deg, alt m AMSL), optional
        Where SIH starts the vehicle (default: PX4's, 47.397742, 8.545594, 488).
    """

    def __init__(self, work_dir: str | os.PathLike, boot_timeout_s: float = 60.0,
                 params: dict[str, float] | None = None, instance: int = 0,
                 home: tuple[float, float, float] | None = None) -> None:
        base = sitl_dir()
        if base is None:
            raise RuntimeError("no PX4 SITL build: set PX4_SITL_DIR or put one at ../shared/px4-sitl")
        self.script = base / "start-sih"
        self.work_dir = Path(work_dir)
        self.boot_timeout_s = boot_timeout_s
        self.params = dict(PARAMS if params is None else params)
        self.instance, self.home = int(instance), home
        self.pid: int | None = None
        self._proc: subprocess.Popen | None = None   # an instance started here: this process reaps it

    @property
    def offboard_port(self) -> int:
        """Where PX4's offboard (API) link sends: the companion listens here."""
        return 14540 + self.instance

    @property
    def gcs_port(self) -> int:
        """PX4's ground-station link (it answers whoever sends to it)."""
        return 18570 + self.instance

    @property
    def truth_port(self) -> int:
        """Where SIH's ground truth (HIL_STATE_QUATERNION) is sent."""
        return 19410 + self.instance

    def __enter__(self) -> Sitl:
        env = {**os.environ, **{f"PX4_PARAM_{name}": str(value) for name, value in self.params.items()}}
        if self.home is not None:
            env.update(PX4_HOME_LAT=repr(float(self.home[0])), PX4_HOME_LON=repr(float(self.home[1])),
                       PX4_HOME_ALT=repr(float(self.home[2])))
        self.pid = self._start_sih(env) if self.instance == 0 else self._start_instance(env)
        logger.info("PX4 SITL started, pid %d, in %s", self.pid, self.work_dir)
        deadline = time.monotonic() + self.boot_timeout_s
        log = self.work_dir / "px4.log"
        while time.monotonic() < deadline:
            if log.is_file() and "Ready for takeoff" in log.read_text(errors="replace"):
                return self
            if not self.alive():
                self.stop()
                raise RuntimeError(f"PX4 SITL exited during boot; see {log}")
            time.sleep(0.5)
        self.stop()
        raise RuntimeError(f"PX4 SITL not ready after {self.boot_timeout_s:.0f} s; see {log}")

    def _start_sih(self, env: dict) -> int:
        out = subprocess.run([str(self.script), str(self.work_dir)], check=True, capture_output=True, text=True,
                             timeout=120, env=env, preexec_fn=raise_priority)
        return int(out.stdout.strip().splitlines()[-1])

    def _start_instance(self, env: dict) -> int:
        """What ``start-sih`` does, with ``-i``: a fresh directory, the build unpacked, PX4 as a daemon."""
        shutil.rmtree(self.work_dir, ignore_errors=True)
        (self.work_dir / "run").mkdir(parents=True)
        with tarfile.open(self.script.parent / "px4-sitl.tar.gz") as tar:
            tar.extractall(self.work_dir, filter="fully_trusted")
        env = {**env, "PX4_SYS_AUTOSTART": "10040", "PX4_SIM_MODEL": "sihsim_quadx", "PX4_SIMULATOR": "sihsim"}
        env.setdefault("PX4_PARAM_COM_RC_IN_MODE", "4")
        env.setdefault("PX4_PARAM_COM_RCL_EXCEPT", "4")
        build = self.work_dir / "px4-sitl"
        with open(self.work_dir / "px4.log", "wb") as log:
            proc = subprocess.Popen([str(build / "bin" / "px4"), "-i", str(self.instance), "-d", "-w",
                                     str(self.work_dir / "run"), str(build / "etc")],
                                    cwd=self.work_dir / "run", env=env, stdout=log, stderr=subprocess.STDOUT,
                                    stdin=subprocess.DEVNULL, start_new_session=True,
                                    preexec_fn=raise_priority)
        (self.work_dir / "px4.pid").write_text(f"{proc.pid}\n")
        self._proc = proc
        return proc.pid

    def alive(self) -> bool:
        if self.pid is None:
            return False
        if self._proc is not None:
            return self._proc.poll() is None
        try:
            os.kill(self.pid, 0)
        except ProcessLookupError:
            return False
        return True

    def stop(self) -> None:
        """Stop PX4 (SIGTERM, then SIGKILL after 5 s); safe to call twice."""
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
                if self._proc is not None:
                    if self._proc.poll() is not None:
                        return
                    time.sleep(0.1)
                    continue
                try:
                    os.kill(pid, 0)
                except ProcessLookupError:
                    return
                time.sleep(0.1)

    def __exit__(self, *exc) -> None:
        self.stop()
