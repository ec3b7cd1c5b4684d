"""Identification of the vehicle's velocity response from a tlog (companion identify)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.cli import main
from companion.core.planner.vehicle_model import AxisResponse
from companion.mavlink import messages
from companion.mavlink.autopilots import px4
from companion.mavlink.tlog import TlogWriter
from companion.offline.identify import IdentifyError, identify, load_response_log, step_sequence

T0 = 1_800_000_000.0
TRUE_H = AxisResponse(1.6, 0.35, 0.8, 0.2)      # PX4-like: two-part horizontal response
TRUE_V = AxisResponse(4.0, 0.0, 0.0, 0.0)      # a 0.25 s lag


def _pack(msg, sysid, compid):
    mav = mavlink2.MAVLink(None, sysid, compid)
    return bytes(msg.pack(mav))


def write_step_log(path, seed=0, noise_mps=0.01, offboard=True, steps=None):
    """A tlog of ``steps`` (default: the step sequence) flown by a vehicle with TRUE_H / TRUE_V,
    LOCAL_POSITION_NED at 50 Hz."""
    rng = np.random.default_rng(seed)
    dt = 0.002
    axes = (TRUE_H, TRUE_H, TRUE_V)
    mats = [ax.matrices() for ax in axes]
    x = [ax.steady_state(0.0) for ax in axes]
    mode = px4.OFFBOARD if offboard else px4.POSCTL
    t = 0.0
    with TlogWriter(path) as log:
        for duration, v_cmd in (step_sequence() if steps is None else steps):
            end = t + duration
            while t < end - 1e-9:
                k = int(round(t / dt))
                if k % 500 == 0:
                    hb = mavlink2.MAVLink_heartbeat_message(2, 12, 145 if offboard else 209, mode, 4, 3)
                    log.write(T0 + t, _pack(hb, 1, 1))
                if k % 25 == 0:
                    log.write(T0 + t, _pack(messages.velocity_setpoint(int(t * 1000), v_cmd), 1, 191))
                if k % 10 == 0:
                    v = [xi[1] + rng.normal(0, noise_mps) for xi in x]
                    lpn = mavlink2.MAVLink_local_position_ned_message(int(t * 1000), *(xi[0] for xi in x), *v)
                    log.write(T0 + t, _pack(lpn, 1, 1))
                for i, (a, b) in enumerate(mats):
                    x[i] = x[i] + dt * (a @ x[i] + b * v_cmd[i])
                t += dt
    return path


@pytest.fixture(scope="module")
def step_log(tmp_path_factory):
    return write_step_log(tmp_path_factory.mktemp("identify") / "steps.tlog")


def test_that_identification_recovers_the_response_and_predicts_better_than_the_lag(step_log):
    log = load_response_log(step_log)
    assert log.kinds["velocity"] > 1000 and log.duration_s > 60
    result = identify(log)
    h = result.horizontal
    assert h.p_gain_per_s == pytest.approx(TRUE_H.p_gain_per_s, rel=0.15)
    assert h.i_gain_per_s2 == pytest.approx(TRUE_H.i_gain_per_s2, rel=0.2)
    assert h.drag_per_s == pytest.approx(TRUE_H.drag_per_s, rel=0.2)
    model, lag = result.figures["model"], result.figures["lag 0.3 s"]
    assert model["fit_rms_horizontal"] < 0.03
    assert lag["one_step_rms_horizontal"] > 3 * model["one_step_rms_horizontal"]


def test_that_identify_prints_the_table_and_writes_the_scenario_table(step_log, tmp_path, capsys):
    table = tmp_path / "response.toml"
    assert main(["identify", str(step_log), "--write-scenario", str(table)]) == 0
    out = capsys.readouterr().out
    assert "horizontal" in out and "lag 0.3 s" in out and "prediction error of the lag / of the model" in out
    import tomllib

    from companion.core.planner import PlannerConfig

    parsed = tomllib.loads(table.read_text())["planner"]
    cfg = PlannerConfig.from_toml_table(parsed)
    assert cfg.vehicle_response[0].p_gain_per_s == pytest.approx(TRUE_H.p_gain_per_s, rel=0.15)


def test_that_a_log_never_in_offboard_cannot_be_identified(tmp_path, capsys):
    path = write_step_log(tmp_path / "posctl.tlog", offboard=False)
    with pytest.raises(IdentifyError, match="no OFFBOARD stretch"):
        load_response_log(path)
    assert main(["identify", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "posctl.tlog" in err[0]


# --- logs that cannot be identified, arguments, and merging into a scenario ---------------------------

ROOT = Path(__file__).resolve().parents[2]


def _one_line(capsys, argv):
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return code, err.rstrip("\n")


def test_that_a_hover_log_is_refused_naming_the_missing_step(tmp_path, capsys):
    path = write_step_log(tmp_path / "hover.tlog", steps=[(40.0, (0.0, 0.0, 0.0))])
    code, err = _one_line(capsys, ["identify", str(path)])
    assert code == 2
    assert err == (f"companion identify: error: {path}: no velocity step of at least 0.5 m/s on the horizontal "
                   "(north or east) axis in OFFBOARD (largest 0.00 m/s): the response cannot be identified; "
                   "fly the identification steps (companion fly --identify)")


def test_that_a_log_with_horizontal_steps_only_is_refused_naming_the_vertical(tmp_path, capsys):
    steps = [(3.0, (0.0, 0.0, 0.0)), (8.0, (1.0, 0.0, 0.0)), (8.0, (0.0, 0.0, 0.0)), (6.0, (0.0, 2.0, 0.0)), (6.0, (0.0, 0.0, 0.0))]
    path = write_step_log(tmp_path / "flat.tlog", steps=steps)
    code, err = _one_line(capsys, ["identify", str(path)])
    assert code == 2
    assert err.startswith(f"companion identify: error: {path}: no velocity step of at least 0.5 m/s on the vertical (down) axis")


@pytest.mark.parametrize(
    ("argv", "line"),
    [
        (["--horizon", "0"], "argument --horizon: must be from 0.05 to 5 s, got 0"),
        (["--horizon", "-1"], "argument --horizon: must be from 0.05 to 5 s, got -1"),
        (["--horizon", "nan"], "argument --horizon: must be a finite number, got nan"),
        (["--reference-lag", "0"], "argument --reference-lag: must be from 0.01 to 10 s, got 0"),
        (["--into", "antipodal"], "--into SCENARIO needs --write-scenario FILE (where to write the copy)"),
    ],
)
def test_that_bad_identify_arguments_are_one_line(tmp_path, capsys, argv, line):
    code, err = _one_line(capsys, ["identify", str(tmp_path / "any.tlog"), *argv])
    assert code == 2
    assert err in (f"companion identify: error: {line} (see --help)", f"companion identify: error: {line}")


def test_that_identify_help_shows_the_defaults(capsys):
    with pytest.raises(SystemExit):
        main(["identify", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "the planner's step), 0.05 to 5 (default: 0.3)" in out
    assert "lag model to compare with, seconds, 0.01 to 10 (default: 0.3)" in out


@pytest.mark.parametrize("shipped", ["antipodal_px4.toml", "antipodal.toml"])
def test_that_into_writes_a_copy_of_the_scenario_with_the_response_replaced(step_log, tmp_path, capsys, shipped):
    source = ROOT / "configs" / shipped
    copy = tmp_path / "mine.toml"
    assert main(["identify", str(step_log), "--into", str(source), "--write-scenario", str(copy)]) == 0
    assert f"scenario: {copy} (a copy of {source} with this response)" in capsys.readouterr().out
    import tomllib

    from companion.loop.config import load_scenario

    before, after = tomllib.loads(source.read_text()), tomllib.loads(copy.read_text())
    response = after["planner"].pop("vehicle_response")
    before["planner"].pop("vehicle_response", None)
    assert after == before                                    # nothing else changed
    assert response["horizontal"]["p_gain_per_s"] == pytest.approx(TRUE_H.p_gain_per_s, rel=0.15)
    assert load_scenario(copy).planner.vehicle_response is not None
    assert copy.read_text().count("vehicle_response") == 2      # the old lines are gone, not shadowed


def test_that_the_table_appends_to_a_scenario_without_a_response(step_log, tmp_path, capsys):
    table = tmp_path / "response.toml"
    assert main(["identify", str(step_log), "--write-scenario", str(table)]) == 0
    capsys.readouterr()
    from companion.loop.config import load_scenario

    appended = tmp_path / "appended.toml"
    appended.write_text((ROOT / "configs" / "antipodal.toml").read_text() + "\n" + table.read_text())
    assert load_scenario(appended).planner.vehicle_response is not None


def test_that_merging_keeps_table_forms_and_comments():
    from companion.commands.identify import merge_into_scenario

    text = ("# top\n[planner]\nstep_s = 0.3  # s\n\n[planner.vehicle_response]\n"
            "horizontal = { p_gain_per_s = 1.0 }\nvertical = { p_gain_per_s = 2.0 }\n\n[map]\n")
    merged = merge_into_scenario(text, ["vehicle_response.horizontal = { p_gain_per_s = 3.0 }",
                                        "vehicle_response.vertical = { p_gain_per_s = 4.0 }"])
    assert merged == ("# top\n[planner]\nstep_s = 0.3  # s\nvehicle_response.horizontal = { p_gain_per_s = 3.0 }\n"
                      "vehicle_response.vertical = { p_gain_per_s = 4.0 }\n\n[map]\n")
