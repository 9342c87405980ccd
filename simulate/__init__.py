"""Scene-driven stereo rig simulator and the anomaly renderer (raindrops, dust, dirt)."""
