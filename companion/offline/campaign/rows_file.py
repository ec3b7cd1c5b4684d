"""A campaign's results file of its own kind: JSON lines, a header, then one row per finished run.

The fleet (``--family swap``) and mission (``--family mission``) campaigns keep their runs this
way: the first line is a header naming the file's ``format`` and what the runs were flown with;
every finished run is appended and flushed at once, so an interrupted campaign loses at most the
runs in flight. ``resume`` reads the rows back and the campaign flies only the missing ones; a
file whose header differs is refused (its runs were flown with something else). An unfinished
last line (a killed writer) is dropped; a line longer than :data:`MAX_LINE_BYTES` or not JSON is
one clear error naming the file and line.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any, Callable, Sequence, TextIO

from companion.errors import ConfigError
from companion.offline.campaign.progress import Progress
from companion.offline.campaign.run import fly_tasks

logger = logging.getLogger(__name__)

#: A results row longer than this is not one a campaign wrote.
MAX_LINE_BYTES = 1024 * 1024


def read_rows(path: Path, fmt: str, what: str, make_row: Callable[[dict], Any]) -> tuple[dict | None, dict]:
    """The header and the rows (``make_row(obj)``, keyed by ``row.key``) of a results file of format
    ``fmt`` (``what`` names it in errors); a later row of a run replaces an earlier one."""
    header, rows = None, {}
    with open(path, "rb") as f:
        for n, raw in enumerate(iter(lambda: f.readline(MAX_LINE_BYTES + 1), b"")):   # bounded reads
            if len(raw) > MAX_LINE_BYTES:
                raise ConfigError(f"{path}: line {n + 1} is longer than {MAX_LINE_BYTES} bytes: not a {what} results file")
            if not raw.endswith(b"\n"):
                logger.warning("%s: the unfinished last line is dropped", path)
                break
            try:
                obj = json.loads(raw)
            except json.JSONDecodeError:
                raise ConfigError(f"{path}: line {n + 1} is not JSON") from None
            if n == 0:
                if not isinstance(obj, dict) or obj.get("format") != fmt:
                    raise ConfigError(f"{path}: not a {what} results file (no {fmt} header)")
                header = obj
                continue
            try:
                row = make_row(obj)
            except TypeError as exc:
                raise ConfigError(f"{path}: line {n + 1}: {exc}") from None
            rows[row.key] = row
    return header, rows


def open_rows(path: str | Path | None, header: dict, resume: bool, what: str,
              make_row: Callable[[dict], Any]) -> tuple[TextIO | None, dict]:
    """The file to append rows to (None without ``path``) and the runs it already holds.

    A new (or empty) file gets ``header``; an existing one is continued only with ``resume`` and
    only if its header is ``header``."""
    if path is None:
        return None, {}
    path = Path(path)
    if path.exists() and path.stat().st_size > 0:
        if not resume:
            raise ConfigError(f"{path} exists: --resume to continue it, or name another file with --results")
        old_header, done = read_rows(path, header["format"], what, make_row)
        if old_header != header:
            raise ConfigError(f"{path}: its runs were flown with {json.dumps(old_header)}, not {json.dumps(header)}")
        return open(path, "a", encoding="utf-8"), done
    path.parent.mkdir(parents=True, exist_ok=True)
    out = open(path, "w", encoding="utf-8")
    out.write(json.dumps(header) + "\n")
    out.flush()
    return out, {}


def append_row(out: TextIO | None, row: dict) -> None:
    """One finished run, written and flushed at once (nothing without a file)."""
    if out is not None:
        out.write(json.dumps(row) + "\n")
        out.flush()


class RunRow:
    """What a run's row (a dataclass with ``error``) shares: its JSON, and its score for the progress bar."""

    error: str | None

    @property
    def score(self):
        """Itself once scored (what the progress bar counts), None for an error."""
        return None if self.error is not None else self

    def to_json(self) -> dict:
        return asdict(self)


def fly_rows(run: Callable, todo: Sequence, workers: int, scheduler: str | None, out: TextIO | None, done: dict,
             bar: Progress) -> tuple[int, int, float]:
    """``run`` every task (:func:`companion.offline.campaign.run.fly_tasks`), each finished row kept in
    ``done``, appended to ``out`` and counted on ``bar``; both closed at the end. Returns (workers,
    runs lost, wall seconds)."""
    t0 = time.perf_counter()

    def finished(row) -> None:
        done[row.key] = row
        append_row(out, row.to_json())
        bar.update(row)

    try:
        n_workers, lost = fly_tasks(run, todo, workers, scheduler, finished)
    finally:
        bar.close()
        if out is not None:
            out.close()
    return n_workers, lost, time.perf_counter() - t0


def dash(value: float | None, digits: int) -> str:
    """A table cell: ``value`` with ``digits`` decimals, ``-`` for None."""
    return "-" if value is None else f"{value:.{digits}f}"
