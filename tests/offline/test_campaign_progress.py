"""Campaign progress: a bar with runs done, rate and time left; a one-line log off a terminal."""

from __future__ import annotations

import dataclasses
import io

import pytest

from companion.offline.campaign import EpisodeResult, EpisodeScore
from companion.offline.campaign.progress import Progress


def _result(collided: bool | None) -> EpisodeResult:
    score = None
    if collided is not None:
        neutral = {f.name: 0 for f in dataclasses.fields(EpisodeScore)}
        score = EpisodeScore(**{**neutral, "collided": collided, "truth": {}})
    return EpisodeResult(episode=0, method="paper", family="antipodal", seed=1, sim_seed=2, score=score,
                         error=None if score else "RuntimeError: x")


class _FakeTerminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_that_off_a_terminal_progress_is_a_periodic_line_with_rate_and_time_left():
    out = io.StringIO()
    p = Progress("campaign antipodal", total=10, done=4, log_every_s=0.0, stream=out)
    assert p.mode == "log"
    for collided in (True, False, None):
        p.update(_result(collided))
    p.close()
    lines = out.getvalue().splitlines()
    assert len(lines) == 4  # one per run (every 0 s) and one at the end
    assert lines[-1].startswith("campaign antipodal: 7/10 runs (4 from the results file), 1 with collision, 1 error(s), ")
    assert "runs/min" in lines[-1] and " left" in lines[-1] and "\r" not in out.getvalue()


def test_that_a_slow_log_waits_for_its_period():
    out = io.StringIO()
    p = Progress("c", total=3, log_every_s=3600.0, stream=out)
    p.update(_result(False))
    assert out.getvalue() == ""
    p.close()
    assert out.getvalue().count("\n") == 1


def test_that_on_a_terminal_progress_is_a_bar_with_done_rate_and_time_left():
    term = _FakeTerminal()
    p = Progress("campaign crossing", total=4, done=1, stream=term)
    assert p.mode == "bar"
    p.update(_result(False))
    p.update(_result(True))
    p.close()
    text = term.getvalue()
    last = text.split("\r")[-1]
    assert last.startswith("campaign crossing:  75%") and "3/4 [" in last   # done of total
    assert "<00:00" in last and "run/s" in last                                # elapsed<left, rate
    assert "collisions=1, errors=0" in last


def test_that_an_unknown_progress_mode_is_refused():
    with pytest.raises(ValueError, match="progress mode"):
        Progress("c", total=1, mode="fancy")
