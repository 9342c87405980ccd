"""Choices and defaults of ``lenspair restore``, importable without torch (for ``--help``)."""

PRECISIONS = ("auto", "fp32", "bf16", "fp16")
"""``--precision``: ``auto`` is the fastest native one (``lenspair.model.precision``)."""

CAMERA_CHOICES = ("auto", "cam0", "cam1", "both")
"""``--camera``: ``auto`` = the obstructed camera of ``rig.yaml``, else both."""

MIN_TILE = 16
"""Smallest tile side, pixels (``--tile``)."""

DEFAULT_OVERLAP = 32
"""``--overlap``: pixels shared by neighbouring tiles."""

DEFAULT_BATCH_SIZE = 4
"""``--batch-size``: frames per network call."""
