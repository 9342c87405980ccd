"""Anomaly effects rendered on the glass of the obstructed camera, one module per effect."""
