"""Training: typed config, paired and synthetic data, losses, the step, the loop, validation."""
