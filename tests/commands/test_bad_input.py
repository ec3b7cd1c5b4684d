"""Bad input on either command line: exit 2 and one line naming the file and key (or the argument).

One test per row of the bad-input list of issue 14, through the real entry points
(``companion.cli.main``, ``mavsim.cli.main``), in process except where a second
process is the point.
"""

from __future__ import annotations

import os
import socket
import struct
from pathlib import Path

import numpy as np
import pytest

from companion.cli import main as companion_main
from mavsim.cli import main as mavsim_main

ROOT = Path(__file__).resolve().parents[2]
ANTIPODAL = (ROOT / "configs" / "antipodal.toml").read_text()


def run_companion(capsys, argv: list[str]) -> tuple[int, str]:
    try:
        code = companion_main(argv)
    except SystemExit as exc:  # argparse
        code = exc.code
    return code, capsys.readouterr().err


def run_mavsim(capsys, argv: list[str]) -> tuple[int, str]:
    try:
        code = mavsim_main(argv)
    except SystemExit as exc:
        code = exc.code
    return code, capsys.readouterr().err


def assert_one_line(code: int, err: str, *needles: str) -> None:
    assert code == 2, err
    assert err.endswith("\n") and err.count("\n") == 1, f"not one line: {err!r}"
    assert "Traceback" not in err
    for needle in needles:
        assert needle in err, f"{needle!r} not in {err!r}"


def scenario(tmp_path: Path, text: str, name: str = "bad.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def edited(old: str, new: str) -> str:
    assert old in ANTIPODAL
    return ANTIPODAL.replace(old, new, 1)


# --- the scenario file, as both programs read it -------------------------------------------------

@pytest.mark.parametrize(
    ("text", "needles"),
    [
        (edited('radius_m = 0.5\nstart_ned_m = [24.0', 'radius_m = "big"\nstart_ned_m = [24.0'),
         ["bad.toml", "world.obstacles[0]", "radius_m", "'big'"]),
        ("mission = 5\n" + ANTIPODAL.replace("[mission]\n", "[mission_old]\n").split("[mission_old]")[0],
         ["bad.toml", "[mission]", "must be a table"]),
        (edited("setpoint_rate_hz = 20.0", "setpoint_rate_hz = inf"), ["bad.toml", "[companion]", "setpoint_rate_hz = inf"]),
        (edited("obstacle_radius_m = 0.5", "obstacle_radius_m = nan"), ["bad.toml", "[companion]", "obstacle_radius_m = nan"]),
        (edited("obstacle_radius_m = 0.5", "obstacle_radius_m = 0.5\nestimate_timeout_s = -1"),
         ["bad.toml", "[companion]", "estimate_timeout_s = -1"]),
        (edited("accel_max_mps2 = 4.0", "accel_max_mps2 = 4.0\nbogus_gain = 2"), ["bad.toml", "[sim]", "bogus_gain"]),
        (edited('name = "head-on"', 'name = "head-on"\nwingspan_m = 3'), ["bad.toml", "world.obstacles", "wingspan_m"]),
        (edited("horizon_steps = 28 ", "horizon_steps = 100000000 "), ["bad.toml", "[planner]", "horizon_steps = 100000000"]),
        (ANTIPODAL + "".join(f"[[world.obstacles]]\nname = 'o{i}'\nstart_ned_m = [{i}.0, 50.0, -5.0]\n"
                             f"velocity_ned_mps = [0.0, 0.0, 0.0]\n" for i in range(300)),
         ["bad.toml", "obstacles", "at most 254"]),
        (ANTIPODAL + "[[map.walls]]\nnormal_ned = [0.0, 1.0, 0.0]\noffset_m = 100.0\n" * 65,
         ["bad.toml", "map.walls", "at most 64"]),
    ],
    ids=["obstacle-radius-big", "mission-5", "rate-inf", "obstacle-radius-nan", "timeout-negative", "sim-unknown-key",
         "obstacle-unknown-key", "horizon-huge", "obstacle-count", "wall-count"],
)
@pytest.mark.parametrize("command", ["plan", "fly"])
def test_that_a_bad_scenario_value_is_one_line_naming_file_and_key(tmp_path, capsys, text, needles, command):
    path = scenario(tmp_path, text)
    argv = ["plan", str(path)] if command == "plan" else ["fly", "--scenario", str(path), "--connect", "udpin:127.0.0.1:0"]
    assert_one_line(*run_companion(capsys, argv), *needles)


def test_that_mavsim_rejects_what_the_companion_rejects_in_its_sections(tmp_path, capsys):
    path = scenario(tmp_path, edited('radius_m = 0.5\nstart_ned_m = [24.0', 'radius_m = "big"\nstart_ned_m = [24.0'))
    assert_one_line(*run_mavsim(capsys, ["--scenario", str(path), "--lockstep", "--duration", "1"]), "bad.toml", "radius_m")


@pytest.mark.parametrize("program", ["companion", "mavsim"])
def test_that_random_bytes_as_a_scenario_are_one_line(tmp_path, capsys, program):
    path = tmp_path / "noise.toml"
    path.write_bytes(np.random.default_rng(7).integers(0, 256, 4000, dtype=np.uint8).tobytes())
    if program == "companion":
        result = run_companion(capsys, ["plan", str(path)])
    else:
        result = run_mavsim(capsys, ["--scenario", str(path), "--lockstep", "--duration", "1"])
    assert_one_line(*result, "noise.toml", "not a UTF-8 text file")


@pytest.mark.parametrize("program", ["companion", "mavsim"])
def test_that_a_directory_as_the_scenario_is_one_line(tmp_path, capsys, program):
    folder = tmp_path / "looks.toml"
    folder.mkdir()
    if program == "companion":
        result = run_companion(capsys, ["plan", str(folder)])
    else:
        result = run_mavsim(capsys, ["--scenario", str(folder), "--lockstep", "--duration", "1"])
    assert_one_line(*result, "looks.toml", "is a directory")


# --- command-line values ---------------------------------------------------------------------------

@pytest.mark.parametrize(
    ("argv", "needles"),
    [
        (["demo", "--seed", "-1"], ["argument --seed", "-1"]),
        (["fly", "--scenario", "antipodal", "--duration", "nan"], ["argument --duration", "nan"]),
        (["fly", "--scenario", "antipodal", "--duration", "inf"], ["argument --duration", "inf"]),
        (["fly", "--scenario", "antipodal", "--takeoff-alt", "-3"], ["argument --takeoff-alt", "-3"]),
        (["fly", "--scenario", "antipodal", "--tlog", "/no/such/dir/x.tlog"], ["argument --tlog", "/no/such/dir"]),
        (["fly", "--scenario", "antipodal", "--takeover", "guard"], ["--takeover guard needs a mission", "--mission"]),
        (["fly", "--scenario", "antipodal", "--takeover", "watch", "--mission", "vehicle", "--exit-after-goal", "1"],
         ["--exit-after-goal does not go with --takeover watch"]),
        (["campaign", "--seed", "-5"], ["argument --seed", "-5"]),
        (["demo", "--speed", "0"], ["argument --speed"]),
    ],
)
def test_that_a_bad_companion_argument_is_one_line_naming_it(capsys, argv, needles):
    assert_one_line(*run_companion(capsys, argv), *needles)


@pytest.mark.parametrize(
    ("argv", "needles"),
    [
        (["--tlog", "/no/such/dir/x.tlog"], ["argument --tlog", "/no/such/dir"]),
        (["--log-level", "BOGUS"], ["argument --log-level", "BOGUS"]),
        (["--seed", "-1"], ["argument --seed", "-1"]),
        (["--api-port", "http"], ["argument --api-port", "http"]),
    ],
)
def test_that_a_bad_mavsim_argument_is_one_line_naming_it(capsys, argv, needles):
    assert_one_line(*run_mavsim(capsys, argv), *needles)


def test_that_mavsim_on_a_port_in_use_is_one_line(capsys):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind(("127.0.0.1", 0))
        port = taken.getsockname()[1]
        code, err = run_mavsim(capsys, ["--api-local-port", str(port), "--no-gcs", "--duration", "0.1"])
    assert_one_line(code, err, "cannot bind", str(port))


def test_that_a_signing_key_that_is_not_hex_is_one_line(tmp_path, capsys):
    key = tmp_path / "key"
    key.write_text("not a key\n")
    os.chmod(key, 0o600)
    assert_one_line(*run_mavsim(capsys, ["--signing-key-file", str(key), "--duration", "0.1"]), str(key), "64 hexadecimal")
    path = scenario(tmp_path, ANTIPODAL, "ok.toml")
    assert_one_line(*run_companion(capsys, ["fly", "--scenario", str(path), "--signing-key-env", "OGCC_NO_SUCH_VAR"]),
                    "OGCC_NO_SUCH_VAR", "not set")


# --- tlogs ---------------------------------------------------------------------------------------------

def _lockstep_tlog(tmp_path: Path) -> Path:
    out = tmp_path / "run"
    assert companion_main(["demo", "single_obstacle", "--out", str(out), "--json"]) == 0
    return out / "companion.tlog"


def test_that_a_first_record_stamped_all_ones_stops_at_once_naming_offset_0(tmp_path, capsys):
    path = tmp_path / "ff.tlog"
    path.write_bytes(b"\xff" * 8 + bytes.fromhex("fd09000000010100000000000000000000000000") + b"\x00" * 400)
    code, err = run_companion(capsys, ["replay", str(path), "--scenario", str(ROOT / "configs" / "antipodal.toml")])
    assert_one_line(code, err, "ff.tlog", "nonsense timestamp 0xffffffffffffffff at byte offset 0")


def test_that_a_corrupted_tlog_stops_naming_the_byte_offset(tmp_path, capsys):
    src = _lockstep_tlog(tmp_path)
    capsys.readouterr()
    data = bytearray(src.read_bytes())
    rng = np.random.default_rng(3)
    start = len(data) // 2
    data[start:start + 2000] = rng.integers(0, 256, 2000, dtype=np.uint8).tobytes()
    bad = tmp_path / "corrupt.tlog"
    bad.write_bytes(bytes(data))
    code, err = run_companion(capsys, ["replay", str(bad), "--scenario", str(ROOT / "configs" / "single_obstacle.toml")])
    assert_one_line(code, err, "corrupt.tlog", "byte offset")
    offset = int(err.split("byte offset ")[1].split()[0])
    assert start - 300 <= offset <= start + 2000


def test_that_a_record_claiming_a_huge_stamp_jump_is_refused(tmp_path, capsys):
    src = _lockstep_tlog(tmp_path)
    capsys.readouterr()
    data = bytearray(src.read_bytes())
    first_len = 8 + (data[9] + 12 if data[8] == 0xFD else data[9] + 8)
    (t0,) = struct.unpack(">Q", data[:8])
    data[first_len:first_len + 8] = struct.pack(">Q", t0 + 10 * 86_400 * 10**6)
    bad = tmp_path / "jump.tlog"
    bad.write_bytes(bytes(data))
    code, err = run_companion(capsys, ["replay", str(bad), "--scenario", str(ROOT / "configs" / "single_obstacle.toml")])
    assert_one_line(code, err, "jump.tlog", f"byte offset {first_len}")
