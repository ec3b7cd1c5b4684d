"""The real-time edge around the pure loop: the setpoint stream, the planning process, what they
measure, the tlog marks a replay needs, and how a live run ends."""
