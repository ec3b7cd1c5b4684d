"""Project-wide pytest hooks: a failing flight test prints its flight (tests/support/flight_summary.py)."""

from __future__ import annotations

import os

import pytest

# Under pytest-xdist (`make test` runs two workers on CI's two cores) every worker has one core: BLAS
# and OpenMP pools of one thread each, set before numpy is first imported. Two threads a worker spin
# against the other worker: the slowest identification test took 95 s instead of 27 s.
if os.environ.get("PYTEST_XDIST_WORKER"):
    for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_name, "1")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    if report.when == "call" and report.failed:
        for name, value in item.user_properties:
            if name == "flight":
                report.sections.append(("the flight", str(value)))
