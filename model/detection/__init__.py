"""Camera-anomaly detection: training data, training, judging and scoring."""
