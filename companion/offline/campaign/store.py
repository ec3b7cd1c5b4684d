"""The results file: every finished (episode, method) run appended as one JSON line, flushed.

An interrupted campaign loses at most the runs in flight: ``--resume`` reads the file,
skips the runs already in it and appends the rest; the summary, table and figures are
computed from the file. The first line is a header naming what the rows depend on
(family, seed, ``c_min``, episode duration, noise correlation time); resuming with different values is refused.
Methods and episode indices may differ between sessions: a campaign can be extended.

Format (one JSON object per line)::

    {"format": "ogccmpc-campaign-results", "version": 4, "family": ..., "seed": ..., "c_min": ..., "duration_s": ...,
     "noise_correlation_s": ...}
    {"episode": 0, "method": "hyperplane", ..., "wall_time_s": 4.2}
    ...
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any, Iterable

from companion.errors import ConfigError
from companion.offline.campaign.results import EpisodeResult

logger = logging.getLogger(__name__)

FORMAT = "ogccmpc-campaign-results"
VERSION = 4  # 2: slack violation fields in the rows; 3: promise bins; 4: the plan's promise bins, obstacle noise correlation
#: A row longer than this is not one the campaign wrote (bounded reads of a file given on the command line).
MAX_LINE_BYTES = 16 * 1024 * 1024


def campaign_header(family: str, seed: int, c_min: float, duration_s: float,
                    noise_correlation_s: float = 0.0, vehicle: str = "lag",
                    response_state: str | None = None, autopilot: str | None = None,
                    solver: str = "osqp") -> dict[str, Any]:
    """The header line: what every row of the file depends on (``vehicle`` only when it is
    not the default lag profile; ``response_state``, where the plans start the response
    model's internal state, only when given: a file written before it was recorded then
    refuses to resume under it; ``autopilot``, the autopilot mavsim imitates, only when it is
    not mavsim's default PX4: a file flown against PX4's personality refuses to resume under it;
    ``solver``, the planner's QP backend, only when it is not OSQP)."""
    header = {"format": FORMAT, "version": VERSION, "family": family, "seed": int(seed),
              "c_min": float(c_min), "duration_s": float(duration_s),
              "noise_correlation_s": float(noise_correlation_s)}
    if vehicle != "lag":
        header["vehicle"] = vehicle
    if response_state is not None:
        header["response_state"] = response_state
    if autopilot is not None:
        header["autopilot"] = autopilot
    if solver != "osqp":
        header["solver"] = solver
    return header


def read_results_file(path: str | Path) -> tuple[dict[str, Any], list[EpisodeResult], int]:
    """Read a results file: its header, its rows (a later row of the same run replaces an
    earlier one) and the length in bytes of its complete lines (an unfinished last line,
    left by an interrupted campaign, is dropped with a warning).

    Raises
    ------
    ConfigError
        Not a results file (no header, a line that is not a result row, a line longer than
        :data:`MAX_LINE_BYTES`); names the file and line.
    """
    path = Path(path)
    header: dict[str, Any] = {}
    rows: dict[tuple[int, str], EpisodeResult] = {}
    good = 0
    try:
        f = path.open("rb")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the results file ({exc.strerror or exc})") from None
    with f:
        for number, raw in enumerate(iter(lambda: f.readline(MAX_LINE_BYTES), b""), start=1):
            if not raw.endswith(b"\n"):
                if len(raw) >= MAX_LINE_BYTES:
                    raise ConfigError(f"{path}:{number}: line longer than {MAX_LINE_BYTES} bytes: not a results file")
                logger.warning("%s:%d: unfinished last line dropped (the campaign was interrupted)", path, number)
                break
            try:
                doc = json.loads(raw)
            except ValueError:
                raise ConfigError(f"{path}:{number}: not a JSON line") from None
            if number == 1:
                if not isinstance(doc, dict) or doc.get("format") != FORMAT:
                    raise ConfigError(f"{path}:1: not a campaign results file (no {FORMAT!r} header)")
                header = doc
            else:
                try:
                    result = EpisodeResult.from_json(doc)
                except (KeyError, TypeError, ValueError) as exc:
                    raise ConfigError(f"{path}:{number}: not a campaign result row ({exc})") from None
                rows[result.key] = result
            good += len(raw)
    if not header:
        raise ConfigError(f"{path}: empty or unfinished header: not a campaign results file")
    return header, list(rows.values()), good


class ResultsFile:
    """An open results file, appending one line per finished run.

    Parameters
    ----------
    path : the JSON-lines file (created with its parent folder when missing).
    header : :func:`campaign_header` of this campaign.
    resume : continue a file that already holds results; without it such a file is refused
        (``ConfigError``), so that hours of results are never overwritten by mistake.

    Raises
    ------
    ConfigError
        The file holds results and ``resume`` is false; its header differs from ``header``;
        a line (other than an unfinished last one) is not a result row.
    """

    def __init__(self, path: str | Path, header: dict[str, Any], *, resume: bool = False) -> None:
        self.path = Path(path)
        self.header = header
        self._rows: dict[tuple[int, str], EpisodeResult] = {}
        existing = self.path.exists() and self.path.stat().st_size > 0
        if existing and not resume:
            raise ConfigError(f"{self.path}: already holds campaign results; pass --resume to continue it, "
                              f"or name another --results file")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if existing:
            good_bytes = self._read()
            with self.path.open("r+b") as f:  # drop an unfinished last line (killed mid-write)
                f.truncate(good_bytes)
            self._file = self.path.open("a", encoding="utf-8")
        else:
            self._file = self.path.open("w", encoding="utf-8")
            self._write(header)
        logger.info("%s: %d run(s) already there", self.path, len(self._rows))

    def _read(self) -> int:
        """Load the rows; returns the length in bytes of the complete lines."""
        header, rows, good = read_results_file(self.path)
        for key, value in self.header.items():
            if header.get(key) != value:
                raise ConfigError(f"{self.path}: was written for {key} = {header.get(key)!r}, this campaign has {value!r}")
        self._rows = {r.key: r for r in rows}
        return good

    def _write(self, doc: dict) -> None:
        self._file.write(json.dumps(doc, default=float, allow_nan=False) + "\n")
        self._file.flush()
        os.fsync(self._file.fileno())

    def __contains__(self, key: tuple[int, str]) -> bool:
        return key in self._rows

    def __len__(self) -> int:
        return len(self._rows)

    def append(self, result: EpisodeResult) -> None:
        """Append one finished run (flushed to disk before returning)."""
        self._write(result.to_json(pooled=True))
        self._rows[result.key] = EpisodeResult.from_json(result.to_json(pooled=True))

    def results(self, keys: Iterable[tuple[int, str]]) -> list[EpisodeResult]:
        """The rows for ``keys`` that the file holds, in the order of ``keys``."""
        return [self._rows[k] for k in keys if k in self._rows]

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> "ResultsFile":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
