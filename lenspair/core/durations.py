"""Budgets and intervals as a user types them: a whole number of steps, or a time.

One grammar for every command: ``500`` is 500 steps, ``90s``, ``10m`` and
``1h`` are times (``train --checkpoint-every``, ``tradeoff --budget``);
where only a time makes sense (``train --max-seconds``), a bare number is
seconds.
"""

import math
import re

UNIT_SECONDS = {"s": 1.0, "m": 60.0, "h": 3600.0}
"""Seconds in one of each unit a time may carry."""

_FORM = re.compile(r"\s*((?:\d+\.?\d*|\.\d+)(?:e[+-]?\d+)?)\s*([smh]?)\s*")
"""A number as Python writes one (``90``, ``.5``, ``1e3``; no sign, ``inf`` or ``nan``),
then an optional unit."""


def steps_or_seconds(text: str) -> tuple[int | None, float | None]:
    """``"500"`` -> ``(500, None)``; ``"90s"``, ``"10m"``, ``"1h"`` -> ``(None, seconds)``.

    Raises:
        ValueError: not that form, not positive, too large to be finite
            (``1e400``), or a fractional step count (the message says which,
            without naming the option).
    """
    match = _FORM.fullmatch(text.lower())
    if match is None:
        raise ValueError(f"expected STEPS or a time like 90s, 10m, 1h; got {text!r}")
    value, unit = float(match.group(1)), match.group(2)
    if value <= 0:
        raise ValueError(f"must be positive, got {text!r}")
    if not math.isfinite(value * UNIT_SECONDS.get(unit, 1.0)):
        # float() reads 1e400 as inf: recorded in config.yaml, that refused the run's checkpoint
        raise ValueError(f"too large to be a number of steps or seconds, got {text!r}")
    if not unit:
        if value != int(value):
            raise ValueError(f"steps must be a whole number, got {text!r}")
        return int(value), None
    return None, value * UNIT_SECONDS[unit]


def seconds(text: str) -> float:
    """A positive time: ``"90"`` or ``"90s"`` -> 90.0, ``"10m"`` -> 600.0, ``"1h"`` -> 3600.0.

    Raises:
        ValueError: not a positive number with an optional unit s, m or h, or
            one too large to be finite (``1e400``, which ``float`` reads as inf).
    """
    return _duration(text, "s", "like 90, 90s, 10m, 1h", "seconds")


def minutes(text: str) -> float:
    """A positive time in minutes: ``"5"`` or ``"5m"`` -> 5.0, ``"90s"`` -> 1.5, ``"1h"`` -> 60.0.

    A bare number is minutes; with a unit it reads as :func:`seconds` does.

    Raises:
        ValueError: as :func:`seconds`, in minutes' words.
    """
    example = "in minutes like 4, or with a unit: 90s, 5m, 1h"
    return _duration(text, "m", example, "minutes") / 60.0


def _duration(text: str, bare_unit: str, example: str, noun: str) -> float:
    """Seconds of ``text``; a bare number is in ``bare_unit`` (:func:`seconds`, :func:`minutes`)."""
    match = _FORM.fullmatch(text.lower())
    if match is None or float(match.group(1)) <= 0:
        raise ValueError(f"expected a positive time {example}; got {text!r}")
    value = float(match.group(1)) * UNIT_SECONDS[match.group(2) or bare_unit]
    if not math.isfinite(value):
        raise ValueError(f"too large to be a number of {noun}, got {text!r}")
    return value
