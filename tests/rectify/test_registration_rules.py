"""The rules of registration, each pinned where a changed constant would show.

The scene tests of ``test_registration.py`` check that registration works;
these check its rules one at a time on inputs built so that the rule decides:
the same-row test of matching, the adaptive anomaly threshold, the inlier
count the final fit must reach and the threshold behind the reported figures.
"""

import numpy as np
import pytest

from lenspair.rectify.errors import RegistrationError
from lenspair.rectify.registration import (
    EstimationParams,
    VerifyParams,
    anomaly_regions,
    estimate_homography,
    match_views,
)
from tests.images import texture

HEIGHT, WIDTH = 360, 540
SCENE = texture((HEIGHT + 60, WIDTH), 5)
VALID = np.ones((HEIGHT, WIDTH), bool)


@pytest.mark.parametrize(("row_shift", "kept"), [(20, True), (50, False)])
def test_matches_more_than_a_tenth_of_the_height_apart_in_rows_are_dropped(
    row_shift: int, kept: bool
) -> None:
    # rectified views agree on rows: 20 px of 360 is within the 10 % allowed,
    # 50 px is not (and would be within 10 % of the width, 54 px)
    obstructed = SCENE[60 : 60 + HEIGHT].copy()
    clean = SCENE[60 - row_shift : 60 - row_shift + HEIGHT].copy()
    src, dst = match_views(obstructed, clean, VALID, VALID, EstimationParams())
    if kept:
        assert len(src) > 100
        assert np.mean(np.abs(src[:, 1] - dst[:, 1] - row_shift) < 0.5) > 0.95
    else:
        assert len(src) <= 2  # the ratio test leaves a chance match or two at most


def test_the_anomaly_threshold_is_four_times_the_median_residual_when_that_is_larger() -> None:
    # a residual of 0.03 everywhere (median 0.03, so the threshold is 0.12, not 0.05)
    # and three patches above it: only those beyond 4 x 0.03 are anomalies
    reference = np.zeros((200, 300), np.float32)
    compensated = np.full_like(reference, 0.03)
    patches = {0.08: (20, 20), 0.11: (20, 120), 0.13: (120, 120)}
    for level, (y, x) in patches.items():
        compensated[y : y + 50, x : x + 50] = level
    regions = anomaly_regions(reference, compensated, VerifyParams())
    centre = {level: bool(regions[y + 25, x + 25]) for level, (y, x) in patches.items()}
    assert centre == {0.08: False, 0.11: False, 0.13: True}
    assert not regions[180, 280]  # the uniform residual itself is no anomaly


def _matches(exact: int, offsets: list[float], seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``exact`` identity matches, then one per offset moved by that many px in x."""
    rng = np.random.default_rng(seed)
    count = exact + len(offsets)
    src = np.column_stack([rng.uniform(20, WIDTH - 20, count), rng.uniform(20, HEIGHT - 20, count)])
    dst = src.copy()
    dst[exact:, 0] += np.asarray(offsets)
    return src, dst


def _frames() -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    view = SCENE[:HEIGHT].copy()  # identical views: no anomaly excludes a match
    return [(view, view, VALID, VALID)]


@pytest.mark.parametrize("supported", [29, 30])
def test_the_final_fit_needs_min_inliers_supporting_matches(supported: int) -> None:
    # 40 matches pass the count before fitting; only ``supported`` fit one homography
    outliers = [float(v) for v in np.random.default_rng(1).uniform(30, 120, 40 - supported)]
    src, dst = _matches(supported, outliers)
    params = EstimationParams()
    if supported < params.min_inliers:
        with pytest.raises(RegistrationError, match=rf"only {supported} matches support"):
            estimate_homography(_frames(), params, matches=[(src, dst)])
    else:
        assert estimate_homography(_frames(), params, matches=[(src, dst)]).inliers == supported


def test_the_reported_inliers_and_rms_use_the_inlier_threshold() -> None:
    # 400 exact matches, 20 1.4 px off either way (within 1.5 px, where MAGSAC's own mask
    # is undecided; too few to pull the final fit), 10 three pixels off: 420 inliers,
    # RMS 1.4 * sqrt(20 / 420) = 0.31 px
    src, dst = _matches(400, [1.4, -1.4] * 10 + [3.0] * 10)
    estimate = estimate_homography(_frames(), EstimationParams(), matches=[(src, dst)])
    assert estimate.matches == 430
    assert estimate.inliers == 420 and estimate.inliers_per_frame == (420,)
    assert estimate.rms_px == pytest.approx(1.4 * np.sqrt(20 / 420), abs=0.01)


@pytest.mark.parametrize(("band", "refused"), [(4, True), (25, True), (40, False), (120, False)])
def test_inliers_in_a_band_narrower_than_an_eleventh_of_the_view_are_refused(
    band: int, refused: bool
) -> None:
    # matches along a horizon only: the fit is within a fraction of a pixel there and
    # undetermined away from it (a 4 px band put the corners 10-20 px off, unsaid)
    rng = np.random.default_rng(1)
    rows = 180 + rng.uniform(-band / 2, band / 2, 400)
    src = np.stack([rng.uniform(10, WIDTH - 10, 400), rows], axis=1)
    dst = src + np.array([4.0, 0.0]) + rng.normal(0.0, 0.2, src.shape)
    view = SCENE[:HEIGHT]
    frames = [(view, view, VALID, VALID)]
    if refused:
        with pytest.raises(RegistrationError, match=r"of its height \(need >= 8% of each\)"):
            estimate_homography(frames, matches=[(src, dst)])
        return
    estimate = estimate_homography(frames, matches=[(src, dst)])
    corners = np.array(
        [[0, 0, 1], [WIDTH - 1, 0, 1], [0, HEIGHT - 1, 1], [WIDTH - 1, HEIGHT - 1, 1]]
    )
    mapped = corners @ estimate.matrix.T
    drift = np.abs(mapped[:, :2] / mapped[:, 2:] - corners[:, :2] - (4.0, 0.0))
    assert drift.max() < 1.5
