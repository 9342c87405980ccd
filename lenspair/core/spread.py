"""Indices spread evenly over a sequence: the frames, pairs or images a step samples."""


def spread_indices(count: int, limit: int | None) -> list[int]:
    """Up to ``limit`` indices of ``range(count)``, evenly spread, first and last included.

    All of them, in order, when ``limit`` is None, not positive or not below
    ``count``. Deterministic: a rerun samples the same items (caches keyed on
    them stay valid), and over items in time or name order it takes every
    part of the sequence in proportion (a recording's whole length, every
    recording of a split), where the first ``limit`` would take one part.
    """
    if limit is None or limit <= 0 or count <= limit:
        return list(range(count))
    if limit == 1:
        return [0]
    return sorted({round(i * (count - 1) / (limit - 1)) for i in range(limit)})
