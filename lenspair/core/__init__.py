"""Helpers every stage shares: errors, config loader, image I/O, atomic writes, progress, reports.

Nothing here imports a stage package (``lenspair.capture``, ``lenspair.model``, ...).
"""
