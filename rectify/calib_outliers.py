"""Outlier views: fit, reject the views far above the median error, refit until none is.

Every step of the calibration (each camera alone, then the pair) runs
:func:`reject_outliers` around its fit. A view whose RMS reprojection error
exceeds ``max(outlier_factor * median, outlier_floor_px)`` is rejected, with
its reason, and the step is repeated; a round that would leave fewer than
``min_views`` views rejects none, so rejection never fails a calibration
that works without it.
"""

from collections.abc import Callable, Sequence
from typing import TypeVar

import numpy as np

from lenspair.rectify.calib_logging import log
from lenspair.rectify.calib_types import CalibrationOptions, RejectedView
from lenspair.rectify.errors import RectifyError

T = TypeVar("T")


def reject_outliers(
    views: list[int],
    fit: Callable[[list[int]], tuple[T, np.ndarray]],
    stage: str,
    names: Sequence[str],
    options: CalibrationOptions,
) -> tuple[T, list[int], np.ndarray, list[RejectedView]]:
    """Fit, drop views far above the median error, refit until none is."""
    rejected: list[RejectedView] = []
    rounds = 0
    while True:
        if len(views) < options.min_views:
            raise RectifyError(
                f"{stage}: only {len(views)} usable board views, need at least {options.min_views}"
            )
        result, errors = fit(views)
        median = float(np.median(errors))
        threshold = max(options.outlier_factor * median, options.outlier_floor_px)
        bad = [k for k, e in enumerate(errors) if e > threshold]
        # most views "bad" means a wrong model or board spec, not bad views: keep them;
        # and never reject down to too few views (a factor near 1 on evenly noisy views
        # dropped half of them a round until the calibration failed)
        too_few = len(views) - len(bad) < options.min_views
        if bad and too_few and rounds < options.max_rounds and len(bad) <= len(views) // 2:
            log.warning(
                "%s: kept %d views above the %.2f px rejection threshold (%s): rejecting them "
                "would leave fewer than %d; more views, or a larger --outlier-factor",
                stage,
                len(bad),
                threshold,
                ", ".join(names[views[k]] for k in bad),
                options.min_views,
            )
        if not bad or len(bad) > len(views) // 2 or rounds == options.max_rounds or too_few:
            return result, views, errors, rejected
        rounds += 1
        scaled = options.outlier_factor * median
        source = (
            f"{options.outlier_factor:g} x median {median:.3f} px"
            if scaled >= options.outlier_floor_px
            else f"the {options.outlier_floor_px:g} px floor; {options.outlier_factor:g} x "
            f"median {median:.3f} px is less"
        )
        for k in bad:
            reason = f"reprojection error {errors[k]:.2f} px > {threshold:.2f} px ({source})"
            rejected.append(
                RejectedView(views[k], names[views[k]], stage, float(errors[k]), reason)
            )
        views = [v for k, v in enumerate(views) if k not in bad]
