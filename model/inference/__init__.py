"""Applying a trained network to new data: backends, tiling, the restore pipeline."""
