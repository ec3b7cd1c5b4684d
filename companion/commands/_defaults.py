"""Names and defaults the subcommands' parsers show, without importing what defines them.

The parsers are built on every ``companion`` start (``--version`` and ``--help`` included),
so they may not import numpy, scipy, filterpy, osqp, numba, pymavlink or matplotlib; the
modules that define these values import all of them. Each value here is a copy of the one
named beside it: ``tests/commands/test_startup.py`` checks each against its source.
"""

from __future__ import annotations

#: companion.mavlink.link.DEFAULT_URL
DEFAULT_URL = "udpin:0.0.0.0:14540"
#: companion.core.planner.config.FORMULATIONS
FORMULATIONS: tuple[str, ...] = ("hyperplane", "paper", "deterministic", "bhattacharyya")
#: companion.core.planner.config.SOLVERS
SOLVERS: tuple[str, ...] = ("osqp", "piqp")
#: companion.mavlink.offboard.TAKEOVER_CHOICES
TAKEOVER_CHOICES = ("always", "watch", "guard")
#: companion.offline.campaign.generate.METHODS
METHODS = ("hyperplane", "paper", "deterministic", "bhattacharyya")
#: companion.offline.campaign.generate.FAMILIES
FAMILIES = ("antipodal", "crossing", "corridor", "random")
#: companion.loop.fleet_config.COORDINATION_MODES
COORDINATION_MODES = ("decentralised", "distributed", "prioritised")
#: companion.offline.campaign.generate.VEHICLES
VEHICLES = ("lag", "px4", "ardupilot")
#: companion.offline.campaign.generate.DEFAULT_DURATION_S
DEFAULT_DURATION_S = 40.0
#: companion.offline.campaign.generate.MAX_DURATION_S
MAX_DURATION_S = 3600.0
#: companion.offline.campaign.run.MAX_EPISODES
MAX_EPISODES = 100_000
#: companion.offline.campaign.run.WORKERS_PER_CPU
WORKERS_PER_CPU = 4
#: companion.offline.campaign.generate.EKF_CORRELATION_S
EKF_CORRELATION_S = 60.0
#: companion.offline.campaign.progress.MODES
PROGRESS_MODES = ("auto", "bar", "log", "off")
#: companion.offline.identify.HORIZON_RANGE_S
IDENTIFY_HORIZON_RANGE_S = (0.05, 5.0)
#: companion.offline.identify.REFERENCE_LAG_RANGE_S
IDENTIFY_REFERENCE_LAG_RANGE_S = (0.01, 10.0)
#: companion.offline.crowd.MAX_SYSTEMS
MAX_SYSTEMS = 200
