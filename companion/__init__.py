"""PX4 companion: overlap-of-Gaussians chance-constrained MPC among moving obstacles.

Layers (the pure core never imports the MAVLink edge):

- ``companion.core.overlap``: overlap of two Gaussians (minmax procedure), numpy with a compiled (numba) 3x3 kernel.
- ``companion.core.planner``: sequential convex programming MPC on OSQP, pure.
- ``companion.mavlink.link`` and friends: the MAVLink edge (connections, PX4 modes, offboard).
- ``companion.commands``: one module per ``companion`` subcommand.
"""

__version__ = "0.1.0"
