"""Checker: the static checks of a chart and a plant (G1xx errors, G2xx/G3xx warnings)."""
