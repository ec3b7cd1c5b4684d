"""``python -m mavsim``: the ``mavsim`` command (:mod:`mavsim.cli`)."""

import sys

from mavsim.cli import main

sys.exit(main())
