"""``companion identify`` on ArduCopter: the committed excerpt of an ArduCopter SITL identification flight.

``tests/data/ardupilot_steps.tlog`` is the GUIDED stretch of one ``companion fly --identify
--autopilot ardupilot --arm --takeoff-alt 5`` against ArduCopter SITL (V4.7.0-dev, instance 5), cut
by :func:`tests.support.tlog_excerpt.tlog_excerpt` (every second LOCAL_POSITION_NED, 25 Hz; 191 KB
of the 519 KB tlog). ``configs/antipodal_ardupilot.toml`` records the model identified from it (in
comments: the planner there keeps the 0.7 s lag, which flies ArduCopter within its acceleration bound).
``tests/ardupilot/test_identify_sitl.py`` flies it again against SITL (``-m ardupilot``).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import tomllib
from pathlib import Path

from companion.mavlink import messages
from companion.mavlink.tlog import read_tlog
from companion.offline.identify import identify, load_response_log

REPO = Path(__file__).resolve().parents[2]
TLOG = REPO / "tests" / "data" / "ardupilot_steps.tlog"
SCENARIO = REPO / "configs" / "antipodal_ardupilot.toml"


def assert_arducopter_model(result) -> None:
    """What an ArduCopter identification must show: one step (0.3 s) ahead at least 3x better than the
    0.3 s lag, in each axis group, and a PI loop whose integral is small (the S-curve has no slow tail)."""
    lag, model = result.figures["lag 0.3 s"], result.figures["model"]
    for group in ("horizontal", "vertical", "all"):
        assert lag[f"one_step_rms_{group}"] >= 3.0 * model[f"one_step_rms_{group}"], (group, lag, model)
    assert model["one_step_rms_all"] < 0.06
    assert 0.8 < result.horizontal.p_gain_per_s < 2.0 and result.horizontal.i_gain_per_s2 < 1.0
    assert 0.8 < result.vertical.p_gain_per_s < 2.0


def test_that_the_excerpt_is_arducopter_in_guided():
    kinds = {messages.decode_heartbeat(msg).mode for _, msg in read_tlog(TLOG)
             if msg.get_type() == "HEARTBEAT" and messages.decode_heartbeat(msg).is_autopilot}
    assert "GUIDED" in kinds and TLOG.stat().st_size < 300_000


def test_that_identify_on_arducopter_predicts_at_least_3x_better_than_the_lag():
    result = identify(load_response_log(TLOG))
    assert_arducopter_model(result)
    # the figures of docs/ARDUPILOT_SIM.md
    assert math.isclose(result.figures["model"]["one_step_rms_all"], 0.036, abs_tol=0.001)
    assert math.isclose(result.figures["lag 0.3 s"]["one_step_rms_all"], 0.187, abs_tol=0.001)


def recorded_model() -> dict[str, dict[str, float]]:
    """The identified ``vehicle_response`` tables recorded (commented out) in ``antipodal_ardupilot.toml``."""
    lines = [line[2:] for line in SCENARIO.read_text().splitlines() if line.startswith("# vehicle_response.")]
    return tomllib.loads("\n".join(lines))["vehicle_response"]


def test_that_the_ardupilot_scenario_records_the_identified_model():
    result = identify(load_response_log(TLOG))
    recorded = recorded_model()
    for group in ("horizontal", "vertical"):
        fitted = getattr(result, group).as_dict()
        assert set(recorded[group]) == set(fitted)
        for key, value in recorded[group].items():
            assert math.isclose(value, fitted[key], rel_tol=2e-3), (group, key, value, fitted[key])


def test_that_the_command_identifies_the_excerpt(tmp_path):
    out = subprocess.run([sys.executable, "-m", "companion.cli", "identify", str(TLOG), "--json",
                          "--write-scenario", str(tmp_path / "t.toml")],
                         capture_output=True, text=True, cwd=REPO, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "[planner.vehicle_response]" in (tmp_path / "t.toml").read_text()
    assert json.loads(out.stdout)
