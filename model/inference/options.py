"""Choices and defaults of ``lenspair restore``, importable without torch (for ``--help``)."""

PRECISIONS = ("auto", "fp32", "bf16", "fp16")
"""``--precision``: ``auto`` is the fastest native one (``lenspair.model.precision``)."""

CAMERA_CHOICES = ("auto", "cam0", "cam1", "both")
"""``--camera``: ``auto`` = the obstructed camera of ``rig.yaml``, else both."""

MIN_TILE = 16
"""Smallest tile side, pixels (``--tile``)."""

DEFAULT_OVERLAP = 32
"""``--overlap``: pixels shared by neighbouring tiles."""

DEFAULT_BATCH_SIZE = 1
"""``--batch-size`` on the CPU: frames per network call. Batching buys a CPU nothing at
camera sizes (``python -m benchmarks.bench_restore``, 540x360 on a 2-core AMD EPYC, two
runs: batch 4 took 1.02-1.11x batch 1's time per frame), and at batch 1 restore writes
exactly the bytes :class:`~lenspair.model.inference.restorer.Restorer` returns (the
CPU's kernels may round a few pixels one 8-bit code apart at another batch size)."""

CUDA_BATCH_SIZE = 4
"""``--batch-size`` on a GPU, where a batch fills the device."""

DEFAULT_JPEG_QUALITY = 95
"""``--jpeg-quality``: the quality of every restored JPEG (files and ``CompressedImage``
messages), 1-100. OpenImageIO does not report the quality a JPEG was written at, so the
input's cannot be matched; its own default (about 98) wrote a quality-80 frame back about
1.8x larger. 95 is OpenCV's default, which bags' JPEG messages were written at before."""

MAX_JPEG_QUALITY = 100
"""``--jpeg-quality``'s largest value (the smallest is 1), as libjpeg takes it."""


def default_batch_size(device_type: str) -> int:
    """``--batch-size``'s default for a device type (``cpu``, ``cuda``)."""
    return CUDA_BATCH_SIZE if device_type == "cuda" else DEFAULT_BATCH_SIZE
