"""The ArduCopter SITL starter restarts an instance that hangs at its start, once.

Against a stand-in ``start-arducopter`` (no ArduPilot needed): a shell script that starts a
``sleep`` as the "instance" and writes the console output a real start writes, either all of
it or only up to where one real start in about 75 stopped ("Smoothing reset at 0.001").
"""

from __future__ import annotations

import logging
import os
import stat
import time

import pytest

from tests.ardupilot import sitl

HEALTHY = "Starting sketch 'ArduCopter'\\nSmoothing reset at 0.001\\nbind port 5792 for SERIAL1\\nvalidate_structures:528: Validating structures\\n"
HUNG = "Starting sketch 'ArduCopter'\\nSmoothing reset at 0.001\\n"


def _fake_start(tmp_path, outputs: list[str]):
    """A ``start-arducopter`` whose k-th start writes ``outputs[k]`` (the last one after) and
    prints the pid of a detached ``sleep 30``; it counts its starts in ``starts`` and lists the pids in ``pids``."""
    script = tmp_path / "start-arducopter"
    cases = "\n".join(f"  {k}) out='{text}' ;;" for k, text in enumerate(outputs[:-1]))
    script.write_text(f"""#!/usr/bin/env bash
set -eu
run_dir=$1
mkdir -p "$run_dir"
n=$(cat {tmp_path}/starts 2>/dev/null || echo 0)
echo $((n + 1)) > {tmp_path}/starts
case $n in
{cases}
  *) out='{outputs[-1]}' ;;
esac
setsid sleep 30 > /dev/null 2>&1 < /dev/null &
printf "$out" > "$run_dir/arducopter.log"
echo $! >> {tmp_path}/pids
echo $!
""")
    script.chmod(script.stat().st_mode | stat.S_IXUSR)
    return script


@pytest.fixture
def fake_build(tmp_path, monkeypatch):
    build = tmp_path / "build"
    (build / "bin").mkdir(parents=True)
    monkeypatch.setattr(sitl, "build_dir", lambda: build)
    monkeypatch.setattr(sitl, "START_TIMEOUT_S", 1.0)

    def use(outputs):
        script = _fake_start(tmp_path, outputs)
        monkeypatch.setattr(sitl, "_script", lambda: script)
        return lambda: [int(p) for p in (tmp_path / "pids").read_text().split()]
    return use


def _gone(pid: int) -> bool:
    deadline = time.monotonic() + 3.0
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.05)
    return False


def test_a_healthy_start_is_started_once(fake_build, tmp_path):
    started = fake_build([HEALTHY])
    with sitl.Sitl(tmp_path / "run", 3) as s:
        assert s.alive() and started() == [s.pid]
    assert _gone(started()[0])


def test_an_instance_that_hangs_at_its_start_is_stopped_and_started_again(fake_build, tmp_path, caplog):
    started = fake_build([HUNG, HEALTHY])
    t0 = time.monotonic()
    with caplog.at_level(logging.WARNING, logger=sitl.__name__), sitl.Sitl(tmp_path / "run", 3) as s:
        hung, second = started()
        assert s.pid == second and s.alive() and _gone(hung)
        assert time.monotonic() - t0 < 5.0
    assert _gone(second)
    assert "did not open its ports within 1 s" in caplog.text and "Smoothing reset" in caplog.text


def test_two_hung_starts_raise_with_the_end_of_the_console_output(fake_build, tmp_path):
    started = fake_build([HUNG])
    with pytest.raises(RuntimeError, match=r"did not open its ports within 1 s twice; .*arducopter.log ends .*Smoothing reset"):
        with sitl.Sitl(tmp_path / "run", 3):
            pass
    assert len(started()) == 2 and all(_gone(pid) for pid in started())
