"""The control loop: configuration, estimation, request building, planning, commands."""
