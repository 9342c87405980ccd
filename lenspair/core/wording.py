"""Words for counts in the lines people read: "1 frame", "2 frames"."""


def counted(count: int, noun: str, plural: str | None = None) -> str:
    """``count`` and ``noun``, plural unless ``count`` is 1 (``plural``: default noun + "s")."""
    return f"{count} {noun if count == 1 else plural or noun + 's'}"
