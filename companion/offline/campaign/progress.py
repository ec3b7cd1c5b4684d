"""Campaign progress people can see: a bar on a terminal, a periodic one-line log otherwise.

The bar is tqdm's (runs done, rate, time left); it is a dependency because writing a
correct rate and ETA estimator with terminal handling is exactly what it already does
well, in pure Python with no dependencies of its own. Off a terminal (a batch job, a
pipe) a bar would fill the log with carriage returns, so one line is written every
``log_every_s`` seconds and once at the end.
"""

from __future__ import annotations

import logging
import sys
import time
from typing import TextIO

from tqdm import tqdm

from companion.offline.campaign.results import EpisodeResult

logger = logging.getLogger(__name__)

MODES = ("auto", "bar", "log", "off")


class Progress:
    """Reports finished runs of a campaign.

    Parameters
    ----------
    label : what is running (e.g. ``"campaign antipodal"``).
    total : runs in the campaign, including those already done.
    done : runs already done (resumed from the results file).
    mode : ``"bar"``, ``"log"``, ``"off"``, or ``"auto"``: a bar when ``stream`` is a terminal, else the log.
    log_every_s : seconds between log lines (wall clock).
    stream : where to write (standard error by default).
    """

    def __init__(self, label: str, total: int, done: int = 0, *, mode: str = "auto",
                 log_every_s: float = 30.0, stream: TextIO | None = None) -> None:
        if mode not in MODES:
            raise ValueError(f"progress mode must be one of {', '.join(MODES)}, got {mode!r}")
        self.stream = stream if stream is not None else sys.stderr
        if mode == "auto":
            mode = "bar" if self.stream.isatty() else "log"
        self.mode, self.label, self.total, self.resumed = mode, label, total, done
        self.done, self.collided, self.errors = done, 0, 0
        self.log_every_s = log_every_s
        self._t0 = self._last_log = time.monotonic()
        self._bar = None
        if mode == "bar":
            self._bar = tqdm(total=total, initial=done, desc=label, unit="run", file=self.stream,
                             dynamic_ncols=True, smoothing=0.05)

    def update(self, result: EpisodeResult) -> None:
        """Count one finished run."""
        self.done += 1
        self.errors += result.score is None
        self.collided += bool(result.score is not None and result.score.collided)
        if self._bar is not None:
            self._bar.set_postfix(collisions=self.collided, errors=self.errors, refresh=False)
            self._bar.update(1)
        elif self.mode == "log" and time.monotonic() - self._last_log >= self.log_every_s:
            self._log()

    def line(self) -> str:
        """The one-line status: runs done, collisions, errors, rate, time left."""
        elapsed = time.monotonic() - self._t0
        ran = self.done - self.resumed
        rate = ran / elapsed if elapsed > 0 else 0.0
        left = (self.total - self.done) / rate if rate > 0 else float("nan")
        resumed = f" ({self.resumed} from the results file)" if self.resumed else ""
        eta = f"{_duration(left)} left" if left == left else "time left unknown"
        return (f"{self.label}: {self.done}/{self.total} runs{resumed}, {self.collided} with collision, "
                f"{self.errors} error(s), {rate * 60:.1f} runs/min, {eta}")

    def _log(self) -> None:
        self._last_log = time.monotonic()
        self.stream.write(self.line() + "\n")
        self.stream.flush()

    def close(self) -> None:
        """Finish the bar, or write the last log line."""
        if self._bar is not None:
            self._bar.close()
        elif self.mode == "log":
            self._log()


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    if seconds < 120:
        return f"{seconds} s"
    if seconds < 7200:
        return f"{seconds // 60} min"
    return f"{seconds // 3600} h {seconds % 3600 // 60:02d} min"
