"""Project-wide pytest hooks: a failing flight test prints its flight (tests/support/flight_summary.py)."""

from __future__ import annotations

import pytest


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    if report.when == "call" and report.failed:
        for name, value in item.user_properties:
            if name == "flight":
                report.sections.append(("the flight", str(value)))
