"""Obstacle intake: traffic from every link, each source on its own clock, onto the tracks."""
