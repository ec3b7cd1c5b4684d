"""The pure planning core: overlap of Gaussians and the SCP/OSQP planner.

Functions of their inputs only: no MAVLink, sockets, threads, clocks or plotting.
"""
