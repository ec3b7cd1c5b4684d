"""mavsim: a PX4-like MAVLink kinematic simulator with scripted obstacles.

It stands in for PX4 SITL: a kinematic multicopter (first-order velocity response,
acceleration limit, ground at z = 0 in local NED) behind PX4's offboard contract
(modes, arming, setpoint stream and loss failsafe, commands, parameters, telemetry
rates), plus scripted obstacles reported as their own MAVLink systems.

Layers (the folders of a transport stack, sockets only at the edge):

- :mod:`mavsim.scenario`  -- scenario file (TOML) to frozen dataclasses
- :mod:`mavsim.vehicle`   -- pure kinematics, ``step(state, command, dt)``
- :mod:`mavsim.params`    -- parameter store (PARAM_* encoding)
- :mod:`mavsim.personalities` -- the autopilot imitated, one module each (PX4, ArduPilot):
  HEARTBEAT identity, modes, commander (arming, offboard, failsafe), parameters, streams
- :mod:`mavsim.autopilot` -- the autopilot's MAVLink face: messages to commander calls
- :mod:`mavsim.telemetry` -- telemetry messages
- :mod:`mavsim.obstacles` -- scripted obstacle motion and their MAVLink systems
- :mod:`mavsim.truth`     -- collisions, minimum distances, goal, summary
- :mod:`mavsim.core`      -- the simulator: bytes in, timed packets out, no clock
- :mod:`mavsim.lockstep`  -- in-process deterministic byte interface
- :mod:`mavsim.tlog`      -- tlog writer
- :mod:`mavsim.udp`       -- real-time UDP endpoint like PX4 SITL (sockets, clock)
- :mod:`mavsim.cli`       -- ``mavsim`` command (``python -m mavsim``)
- :mod:`mavsim.traffic`   -- traffic player: scripted obstacles into a real autopilot
- :mod:`mavsim.referee`   -- the player's smallest distances and goal
- :mod:`mavsim.traffic_cli` -- ``mavsim traffic`` command
"""

from mavsim.errors import MavsimError, ScenarioError, SimulationError

__all__ = ["MavsimError", "ScenarioError", "SimulationError"]
