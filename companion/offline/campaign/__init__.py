"""Monte Carlo safety campaign: randomised encounters flown in lockstep, per planner method.

Does the chance constraint keep its promise? Under the constraint the probability of a
collision with one obstacle at one step is at most ``Phi(-r_min)``,
``r_min = sqrt(chi2_3.ppf(c_min))``. A campaign draws encounters from a seed, flies each
one with every method (``hyperplane``, ``paper``, ``deterministic``, ``bhattacharyya``)
through the real MAVLink path (:func:`companion.offline.harness.run_lockstep`) and counts
what the simulator's truth says happened.

One module per job:

``generate``     episode ``(seed, index)`` as a scenario dict (the encounter families)
``run``          flying the runs: local process pool or a Dask cluster; the campaign loop
``score``        one run's metrics (:class:`EpisodeScore`)
``stats``        intervals, the bound, one :class:`MethodSummary` per method
``results``      the typed records (:class:`EpisodeResult`, :class:`CampaignResult`) with ``to_json``
``store``        the results file (JSON lines, appended as runs finish; ``--resume``)
``progress``     the progress bar or periodic log line
``table``        the terminal table
``toml_writer``  saving a generated episode as a scenario file
"""

from companion.offline.campaign.generate import (
    DEFAULT_DURATION_S,
    EKF_CORRELATION_S,
    FAMILIES,
    METHODS,
    RADIUS_RANGE_M,
    SPAWN_CLEARANCE_M,
    SPEED_MAX_MPS,
    VEHICLES,
    episode_rng,
    episode_sim_seed,
    generate_scenario,
    profile_autopilot,
    random_covariance,
)
from companion.offline.campaign.results import CampaignResult, EpisodeResult
from companion.offline.campaign.run import EpisodeTask, open_executor, run_campaign, run_episode
from companion.offline.campaign.score import ACTIVE_CONTOUR, EpisodeScore, score_run
from companion.offline.campaign.stats import NEES_95, MethodSummary, clopper_pearson, collision_bound, summarise
from companion.offline.campaign.store import ResultsFile, campaign_header
from companion.offline.campaign.table import format_table
from companion.offline.campaign.toml_writer import to_toml, write_scenario

__all__ = [
    "ACTIVE_CONTOUR", "DEFAULT_DURATION_S", "EKF_CORRELATION_S", "FAMILIES", "METHODS", "NEES_95", "RADIUS_RANGE_M", "SPAWN_CLEARANCE_M",
    "SPEED_MAX_MPS", "VEHICLES", "CampaignResult", "EpisodeResult", "EpisodeScore", "EpisodeTask", "MethodSummary", "ResultsFile",
    "campaign_header", "clopper_pearson", "collision_bound", "episode_rng", "episode_sim_seed", "format_table",
    "generate_scenario", "open_executor", "profile_autopilot", "random_covariance", "run_campaign", "run_episode", "score_run",
    "summarise", "to_toml", "write_scenario",
]
