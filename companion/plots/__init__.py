"""Figures (matplotlib, Agg backend); pure cores never import this package."""
