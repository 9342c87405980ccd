"""Sample scene specs, a sample Kalibr camchain and board sets, shipped as package data.

Installed as ``lenspair.calib_samples``; find files with :func:`lenspair.core.samples.sample_path`.
"""
