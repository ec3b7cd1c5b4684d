"""The campaign's typed records: one (episode, method) result, and the whole campaign.

Both have one ``to_json``; an :class:`EpisodeResult` also reads itself back
(:meth:`EpisodeResult.from_json`), which is how the results file (JSON lines, see
:mod:`companion.offline.campaign.store`) becomes the source of the summary, table and figures.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from companion.core.overlap import touch_radius
from companion.offline.campaign.jsonable import to_jsonable
from companion.offline.campaign.score import EpisodeScore
from companion.offline.campaign.stats import MethodSummary, collision_bound

logger = logging.getLogger(__name__)

#: Keys of an episode row that name the run rather than measure it.
_KEY_FIELDS = ("episode", "method", "family", "seed", "sim_seed")
#: Keys of an episode row measured on the host's clock: they differ between two runs of one episode.
TIMING_FIELDS = ("wall_time_s", "solve_times_s")


@dataclass(frozen=True)
class EpisodeResult:
    """One episode flown with one method: its score, or the error that ended it.

    ``wall_time_s`` is the host's time for the run (the only field that differs between
    two runs of the same ``(seed, episode, method)``). ``run`` holds the lockstep run itself
    when asked for (``run_episode(..., keep_records=True)``); it is never serialised.
    """

    episode: int
    method: str
    family: str
    seed: int
    sim_seed: int
    score: EpisodeScore | None = None
    error: str | None = None
    wall_time_s: float = 0.0
    run: Any = field(default=None, compare=False, repr=False)

    @property
    def key(self) -> tuple[int, str]:
        """``(episode, method)``: what identifies the row within a campaign."""
        return self.episode, self.method

    def to_json(self, *, pooled: bool = True) -> dict:
        """One flat row: the key fields, the score's fields (or ``error``), ``wall_time_s``.

        ``pooled=False`` leaves out the per-step lists (:attr:`EpisodeScore.POOLED`).
        """
        row: dict[str, Any] = {k: getattr(self, k) for k in _KEY_FIELDS}
        if self.score is not None:
            row.update(self.score.to_json(pooled=pooled))
        else:
            row["error"] = self.error
        row["wall_time_s"] = self.wall_time_s
        return to_jsonable(row)

    def reproducible_json(self) -> dict:
        """:meth:`to_json` without the host-clock fields (:data:`TIMING_FIELDS`): what any
        run of the same ``(seed, episode, method)``, on any machine, gives again."""
        return {k: v for k, v in self.to_json(pooled=True).items() if k not in TIMING_FIELDS}

    @classmethod
    def from_json(cls, row: dict) -> "EpisodeResult":
        """Inverse of :meth:`to_json` (``pooled=True``)."""
        score = None if "error" in row else EpisodeScore.from_json(row)
        return cls(**{k: row[k] for k in _KEY_FIELDS}, score=score, error=row.get("error"),
                   wall_time_s=float(row.get("wall_time_s") or 0.0))


@dataclass(frozen=True)
class CampaignResult:
    """Everything a campaign measured: per-episode results and per-method summaries."""

    family: str
    seed: int
    episodes: tuple[int, ...]
    methods: tuple[str, ...]
    c_min: float
    duration_s: float
    results: tuple[EpisodeResult, ...]
    summary: dict[str, MethodSummary]
    wall_time_s: float
    workers: int
    lost: int = 0  #: runs whose worker died (not in ``results``; ``--resume`` runs them again)
    noise_correlation_s: float = 0.0  #: correlation time of the simulated position errors (0: white)

    def to_json(self) -> dict:
        """The JSON report (strict JSON: no inf or NaN; per-step lists pooled into the summary)."""
        return to_jsonable({
            "family": self.family, "seed": self.seed, "episodes": list(self.episodes),
            "methods": list(self.methods), "c_min": self.c_min, "duration_s": self.duration_s,
            "noise_correlation_s": self.noise_correlation_s,
            "r_min": float(touch_radius(self.c_min, 3)), "bound_phi_minus_r_min": collision_bound(self.c_min),
            "workers": self.workers, "wall_time_s": self.wall_time_s, "cpu_count": os.cpu_count(),
            "summary": {m: s.to_json() for m, s in self.summary.items()},
            "results": [r.to_json(pooled=False) for r in self.results],
        })

    def plot(self, directory: str | Path) -> list[Path]:
        """Draw the campaign figures into ``directory`` (see :mod:`companion.plots.campaign_figures`)."""
        from companion.plots.campaign_figures import plot_campaign

        noise = f"noise correlation {self.noise_correlation_s:g} s" if self.noise_correlation_s else "white noise"
        title = (f"{self.family} campaign, seed {self.seed}, {len(self.episodes)} episodes, "
                 f"c_min = {self.c_min:.2f}, {noise}")
        return plot_campaign(self.summary, directory, c_min=self.c_min, title=title)
