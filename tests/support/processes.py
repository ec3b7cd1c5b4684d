"""Ending the processes a test started: a process group killed, its output drained, bounded in time."""

from __future__ import annotations

import os
import signal
import subprocess

#: Seconds to wait for a killed group's leader to be reaped (its pipes drained).
REAP_TIMEOUT_S = 10.0


def kill_process_group(proc: subprocess.Popen) -> None:
    """SIGKILL the process group ``proc`` leads (started with ``start_new_session=True``: a ``companion
    fly`` with its planning process) and reap it; a group already gone, or a leader not reaped within
    :data:`REAP_TIMEOUT_S`, is left as it is (never raises)."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    try:
        proc.communicate(timeout=REAP_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        pass
