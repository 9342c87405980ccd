"""``WIDTHxHEIGHT`` sizes, as every lenspair option and file takes them (width first)."""

import re

_SIZE = re.compile(r"\s*(\d+)\s*[xX]\s*(\d+)\s*")


def parse_size(text: str, minimum: int = 1, maximum: int | None = None) -> tuple[int, int]:
    """Parse ``"540x360"`` into ``(540, 360)``: ``(width, height)``.

    Args:
        text: ``WIDTHxHEIGHT`` (``X`` and spaces around it allowed).
        minimum: the least each side may be, pixels.
        maximum: the most each side may be (None: no limit).

    Raises:
        ValueError: one line, saying what was expected and repeating ``text``
            as typed (width first, never turned round).
    """
    match = _SIZE.fullmatch(text)
    if match is None:
        raise ValueError(f"expected WIDTHxHEIGHT such as 540x360, got {text!r}")
    width, height = int(match.group(1)), int(match.group(2))
    if width < minimum or height < minimum:
        raise ValueError(f"expected at least {minimum}x{minimum}, got {text!r}")
    if maximum is not None and (width > maximum or height > maximum):
        raise ValueError(f"expected at most {maximum}x{maximum}, got {text!r}")
    return width, height
