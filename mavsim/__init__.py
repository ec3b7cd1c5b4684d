"""mavsim package."""
