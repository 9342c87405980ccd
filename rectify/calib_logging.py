"""The calibration's logger, and holding back or noting what it says.

Every step of a calibration logs to the one logger :data:`log`, named for
:mod:`~lenspair.rectify.calibration` whatever module the step lives in: the
entry point watches that one logger, to hold back what a pass that is not
kept said (:func:`held`, :func:`release`) and to copy every warning into the
calibration's report (:func:`noted`).
"""

import contextlib
import logging
from collections.abc import Iterator

log = logging.getLogger("lenspair.rectify.calibration")
"""The logger of every calibration step; its records all carry this one name."""


@contextlib.contextmanager
def held(logger: logging.Logger, records: list[logging.LogRecord]) -> Iterator[None]:
    """Keep what ``logger`` is told meanwhile in ``records`` instead of saying it."""

    def hold(record: logging.LogRecord) -> bool:
        records.append(record)
        return False

    logger.addFilter(hold)
    try:
        yield
    finally:
        logger.removeFilter(hold)


def release(records: list[logging.LogRecord]) -> None:
    """Say what :func:`held` kept, in order."""
    for record in records:
        log.handle(record)


class _Noted(logging.Handler):
    """Keeps the messages of the warnings a logger's handlers are given."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())


@contextlib.contextmanager
def noted(logger: logging.Logger) -> Iterator[list[str]]:
    """The warnings ``logger`` says meanwhile (those :func:`held` back only once released).

    They go into the calibration's report even where the application silenced
    ``lenspair``'s logging (a level above WARNING on it or an ancestor): the
    logger is then opened to warnings for the block but kept from passing
    them on, so the report holds them and the console stays as quiet as asked
    (a logger disabled by ``logging.config.dictConfig`` too). ``logging.disable``
    still silences both. The logger is shared: calibrations run at once in
    threads of one process would see each other's warnings.
    """
    handler = _Noted()
    silenced = logger.disabled or not logger.isEnabledFor(logging.WARNING)
    level, propagate, disabled = logger.level, logger.propagate, logger.disabled
    logger.addHandler(handler)
    if silenced:
        logger.setLevel(logging.WARNING)
        logger.propagate = False
        logger.disabled = False
    try:
        yield handler.messages
    finally:
        logger.removeHandler(handler)
        if silenced:
            logger.setLevel(level)
            logger.propagate = propagate
            logger.disabled = disabled
