"""``companion fly --identify``: the identification flight, one command on a new vehicle.

Flown here in real time against mavsim's ArduPilot (its engagement is the longer one); against
real PX4 in tests/px4/test_ulog_identify.py. What identification makes of mavsim's PX4 profile is
checked in lockstep (tests/offline/test_identify_mavsim.py).
"""

from __future__ import annotations

import threading

import pytest

from companion.cli import main as companion_main
from companion.offline.identify import identify, load_response_log
from mavsim.core import Simulator
from mavsim.scenario import scenario_from_dict
from mavsim.udp import LinkAddress, UdpServer
from tests.support.ports import free_udp_port


def _run(capsys, argv: list[str]) -> tuple[int, str, str]:
    try:
        code = companion_main(argv)
    except SystemExit as exc:
        code = exc.code
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.mark.parametrize("argv, needle", [
    (["fly", "--identify"], "--identify needs --tlog"),
    (["fly"], "--scenario FILE is required"),
])
def test_that_a_missing_argument_is_one_line(capsys, argv, needle):
    code, _, err = _run(capsys, argv)
    assert code == 2 and err.count("\n") == 1 and needle in err and "Traceback" not in err


def test_that_no_autopilot_is_one_line_after_the_bounded_wait(capsys, tmp_path, monkeypatch):
    monkeypatch.setattr("companion.commands.fly_identify.HEARTBEAT_WAIT_S", 0.5)
    port = free_udp_port()
    code, _, err = _run(capsys, ["fly", "--identify", "--connect", f"udpin:127.0.0.1:{port}",
                                 "--tlog", str(tmp_path / "s.tlog")])
    assert code == 2 and "no autopilot HEARTBEAT" in err and err.count("\n") == 1


def _fly_identify(capsys, tmp_path, vehicle: str, *extra: str):
    """``fly --identify --arm --takeoff-alt 5`` against mavsim on the ground with ``vehicle``'s
    personality, in real time over loopback; the exit code, stdout and the identification."""
    api = free_udp_port()
    sim = Simulator(scenario_from_dict({"vehicle": {"start_ned_m": [0.0, 0.0, 0.0]}, "sim": {"vehicle": vehicle}}),
                    seed=3, links=("api",), **({"personality": vehicle} if vehicle != "px4" else {}))
    server = UdpServer(sim, [LinkAddress("api", 0, api)], speed=1.0)
    thread = threading.Thread(target=server.run, args=(200.0,), daemon=True)
    thread.start()
    tlog = tmp_path / "steps.tlog"
    try:
        code, out, _ = _run(capsys, ["fly", "--identify", *extra, "--connect", f"udpin:127.0.0.1:{api}", "--arm",
                                     "--takeoff-alt", "5", "--tlog", str(tlog)])
    finally:
        server.stop()
        thread.join(timeout=5)
        server.close()
    return code, out, (identify(load_response_log(tlog)) if code == 0 else None)


@pytest.mark.realtime
def test_that_the_identification_flight_engages_mavsims_ardupilot_in_guided_and_identifies_it(capsys, tmp_path):
    """ArduPilot's engagement before the steps: streams requested, the EKF's readiness waited for (5 s on
    the ground), GUIDED before arming, the takeoff's param7 above home; steps in GUIDED, LOITER after."""
    code, out, result = _fly_identify(capsys, tmp_path, "ardupilot", "--autopilot", "ardupilot")
    assert code == 0 and "final mode LOITER" in out
    lag, model = result.figures["lag 0.3 s"], result.figures["model"]
    assert lag["one_step_rms_all"] > 2 * model["one_step_rms_all"]
