"""Calibration, stereo rectification, clean-to-obstructed registration and cropping."""
