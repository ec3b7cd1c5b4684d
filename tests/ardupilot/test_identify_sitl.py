"""``companion identify`` on ArduCopter SITL: ``companion fly --identify --autopilot ardupilot`` flown live.

Starts ArduCopter SITL (instance N >= 3 with free ports; ``ARDUPILOT_SITL_FIRST_INSTANCE`` raises
the first), flies the identification steps in GUIDED (the companion waits for the EKF's absolute
position, about 42 s, requests the streams, GUIDED, arms, takes off to 5 m above home), hands back
to LOITER with the sticks centred, and identifies the tlog: one step (0.3 s) ahead at least 3x better
than the 0.3 s lag, the model close to the one recorded in ``configs/antipodal_ardupilot.toml``
(identified from ``tests/data/ardupilot_steps.tlog``, a flight like this one). About 2.5 minutes.
"""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import pytest

from companion.offline.identify import _axis_data, _states, GRID_S, identify, load_response_log
from companion.core.planner.vehicle_model import AxisResponse
from tests.ardupilot.sitl import REPO, CentredSticks, Sitl, available, free_instance
from tests.offline.test_ardupilot_identify import assert_arducopter_model, recorded_model

pytestmark = pytest.mark.ardupilot

#: Seconds after SITL's start before the sticks go to mid: after arming (refused with the throttle up),
#: before the LOITER hand-back at the end (where a throttle held down would land the vehicle).
STICKS_AFTER_S = 90.0


@pytest.mark.quarantine(reason="not yet through 20 rounds of make flake-check (the ArduCopter stage)")
def test_that_identify_on_an_arducopter_sitl_flight_predicts_at_least_3x_better_than_the_lag(tmp_path):
    if not available():
        pytest.fail("no ArduCopter SITL build: set ARDUPILOT_SITL_DIR or put one at ../shared/ardupilot-sitl "
                    "(start-arducopter and arducopter-sitl.tar.gz)")
    instance = free_instance()
    tlog = tmp_path / "steps.tlog"
    with Sitl(tmp_path / "sitl", instance) as sitl, CentredSticks(instance) as sticks:
        t0 = time.monotonic()
        fly = subprocess.Popen([sys.executable, "-m", "companion.cli", "fly", "--identify", "--autopilot", "ardupilot",
                                "--arm", "--takeoff-alt", "5", "--tlog", str(tlog),
                                "--connect", f"udpin:127.0.0.1:{sitl.companion_port}"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
        try:
            while fly.poll() is None and time.monotonic() - t0 < 400:
                if time.monotonic() - t0 > STICKS_AFTER_S:
                    sticks.start()
                time.sleep(0.5)
        finally:
            if fly.poll() is None:
                fly.kill()
            out, err = fly.communicate(timeout=10)
    print(out)
    assert fly.returncode == 0, err[-3000:]
    assert "final mode LOITER" in out
    result = identify(load_response_log(tlog))
    print(result.figures, result.horizontal, result.vertical)
    assert_arducopter_model(result)
    # the same vehicle as the shipped model's flight: the two models' open-loop velocities under this
    # flight's commands differ far less than either model's error against the lag
    log = load_response_log(tlog)
    shipped = recorded_model()
    for group, axes in (("horizontal", (0, 1)), ("vertical", (2,))):
        ours, theirs = getattr(result, group), AxisResponse(**shipped[group])
        diff = np.concatenate([_states(ours, GRID_S, c, v[0])[:, 1] - _states(theirs, GRID_S, c, v[0])[:, 1]
                               for c, v in _axis_data(log, axes)])
        assert float(np.sqrt(np.mean(diff**2))) < 0.5 * result.figures["lag 0.3 s"][f"fit_rms_{group}"], group
