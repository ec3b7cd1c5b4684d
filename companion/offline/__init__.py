"""Offline tools: the lockstep harness, tlog replay, Monte Carlo campaigns, reports."""
