"""Evaluation and deployment: scores, reports, latency, accuracy-versus-time, export."""
