"""How alike a rig's two cameras expose: the summary of the pairs' exposure ratios.

The clean camera's frame is the training target, so a difference in exposure
or gain between the cameras goes into every target and a network learns to
re-expose frames. From the pairs alone it cannot be told from the anomaly
(wet glass's veil and brightened drops also move a frame's overall level:
the ``ours`` drops over natural images give ratios of about 0.9 to 0.96), so
nothing is corrected: ``report.json`` records the kept pairs' ratios
(:func:`exposure_summary`), and two patterns that the glass does not make are
said in the log (:func:`exposure_warnings`): a median far from 1, and a ratio
that changes from pair to pair (auto-exposure on one camera or both).
"""

import logging
from pathlib import Path

import numpy as np

from lenspair.capture.ingested import ExposureSummary, PairRecord

log = logging.getLogger(__name__)

EXPOSURE_MEDIAN_RANGE = (0.8, 1.25)
"""Median ratios outside this range are warned of: more than drops or a veil move it."""

EXPOSURE_SPREAD = 1.15
"""A 90th-to-10th percentile quotient above this is warned of as exposure changing."""


def exposure_summary(records: list[PairRecord]) -> ExposureSummary | None:
    """The kept pairs' ``exposure_ratio``: median, 10th and 90th percentiles; None without one."""
    ratios = [
        r.exposure_ratio for r in records if r.status == "kept" and r.exposure_ratio is not None
    ]
    if not ratios:
        return None
    low, median, high = np.percentile(ratios, [10.0, 50.0, 90.0])
    return ExposureSummary(
        median=round(float(median), 4),
        low=round(float(low), 4),
        high=round(float(high), 4),
        pairs=len(ratios),
    )


def exposure_warnings(summary: ExposureSummary | None) -> list[str]:
    """What the log says of ``summary``: a level far from 1, a ratio that changes."""
    if summary is None:
        return []
    said = []
    low, high = EXPOSURE_MEDIAN_RANGE
    if not low <= summary.median <= high:
        darker = "darker" if summary.median < 1 else "brighter"
        said.append(
            f"the clean camera's frames are {darker} than the obstructed camera's (median "
            f"target/input grey ratio {summary.median:.2f} over {summary.pairs} pairs), beyond "
            "what drops or a veil do: the targets carry the cameras' exposure difference, "
            "and a network trained on them learns to change exposure; set both cameras' "
            "exposure and gain alike (README, Limitations)"
        )
    if summary.low > 0 and summary.high / summary.low > EXPOSURE_SPREAD:
        said.append(
            f"the target/input grey ratio changes from pair to pair ({summary.low:.2f} to "
            f"{summary.high:.2f}, 10th to 90th percentile, over {summary.pairs} pairs): the "
            "cameras' exposure differs frame to frame (auto-exposure on?), and the targets "
            "carry it"
        )
    return said


def summarise_exposure(recording: Path, records: list[PairRecord]) -> ExposureSummary | None:
    """:func:`exposure_summary` of a recording's pairs, its warnings logged, naming it."""
    summary = exposure_summary(records)
    for said in exposure_warnings(summary):
        log.warning("%s: %s", recording, said)
    return summary
