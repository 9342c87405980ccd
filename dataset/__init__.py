"""Curation, ground-truth side bookkeeping, leak-free splits, and dataset readers."""
