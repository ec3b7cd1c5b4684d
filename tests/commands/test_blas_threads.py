"""The ``companion`` entry point asks for one BLAS thread before numpy loads, unless told otherwise.

Idle BLAS worker threads spin: against PX4 SITL the process of ``fly`` used 55 to 61 % of a
core with OpenBLAS's default threads and 11 % with one. Checked in fresh interpreters (the
variables act only where numpy is not imported yet).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

_PROBE = r"""
import json, os, sys
from companion.cli import BLAS_THREAD_VARIABLES, main
assert "numpy" not in sys.modules
try:
    main(["plan", "--help"])          # builds the parser: every command module, none loads numpy
except SystemExit:
    pass
assert "numpy" not in sys.modules
main(["overlap", "--confidence", "0.9"])  # a command that runs imports numpy after the request
print(json.dumps({"numpy_loaded": "numpy" in sys.modules, **{k: os.environ.get(k) for k in BLAS_THREAD_VARIABLES}}))
"""


def _probe(env: dict) -> dict:
    out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=120, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def _env_without_blas_variables() -> dict:
    from companion.cli import BLAS_THREAD_VARIABLES

    return {k: v for k, v in os.environ.items() if k not in BLAS_THREAD_VARIABLES}


def test_the_entry_point_asks_for_one_blas_thread_before_numpy_loads():
    got = _probe(_env_without_blas_variables())
    assert got["numpy_loaded"]
    assert got["OPENBLAS_NUM_THREADS"] == got["OMP_NUM_THREADS"] == got["MKL_NUM_THREADS"] == "1"


def test_a_thread_count_the_environment_sets_is_kept():
    got = _probe({**_env_without_blas_variables(), "OPENBLAS_NUM_THREADS": "3"})
    assert got["OPENBLAS_NUM_THREADS"] == "3" and got["OMP_NUM_THREADS"] == "1"
