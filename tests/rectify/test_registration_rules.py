"""The rules of registration, each pinned where a changed constant would show.

The scene tests of ``test_registration.py`` check that registration works;
these check its rules one at a time on inputs built so that the rule decides:
the same-row test of matching, the adaptive anomaly threshold, the inlier
count the final fit must reach and the threshold behind the reported figures.
"""

import cv2
import numpy as np
import pytest

from lenspair.rectify import registration
from lenspair.rectify.errors import RegistrationError
from lenspair.rectify.registration import (
    EstimationParams,
    VerifyParams,
    anomaly_regions,
    corner_std_px,
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


def _corner_drift(matrix: np.ndarray, shift: tuple[float, float]) -> float:
    corners = np.array(
        [[0, 0, 1], [WIDTH - 1, 0, 1], [0, HEIGHT - 1, 1], [WIDTH - 1, HEIGHT - 1, 1]]
    )
    mapped = corners @ matrix.T
    return float(np.abs(mapped[:, :2] / mapped[:, 2:] - corners[:, :2] - shift).max())


PLACES = {
    "a band 4 px tall": ((10, WIDTH - 10), (178, 182), 0),
    "a band 40 px tall": ((10, WIDTH - 10), (160, 200), 0),
    "a 60x40 px patch in a corner": ((20, 80), (300, 340), 0),
    "a band 6 px tall, and 60 matches over the view": ((10, WIDTH - 10), (177, 183), 60),
}


@pytest.mark.parametrize(
    ("place", "refused"),
    [
        ("a band 4 px tall", True),
        ("a band 40 px tall", False),
        ("a 60x40 px patch in a corner", True),
        ("a band 6 px tall, and 60 matches over the view", False),
    ],
)
def test_inliers_that_leave_the_corners_undetermined_are_refused(place: str, refused: bool) -> None:
    # matches along a horizon only, or in one corner: the fit is within a fraction of a
    # pixel there and undetermined away from it (a 4 px band put the corners 10-20 px off,
    # unsaid); dense matches in a band with some spread over the view are fine
    (x0, x1), (y0, y1), spread = PLACES[place]
    rng = np.random.default_rng(1)
    src = np.stack([rng.uniform(x0, x1, 400), rng.uniform(y0, y1, 400)], axis=1)
    over = np.stack([rng.uniform(10, WIDTH - 10, spread), rng.uniform(10, HEIGHT - 10, spread)], 1)
    src = np.concatenate([src, over])
    dst = src + np.array([4.0, 0.0]) + rng.normal(0.0, 0.2, src.shape)
    view = SCENE[:HEIGHT]
    frames = [(view, view, VALID, VALID)]
    if refused:
        with pytest.raises(
            RegistrationError, match=r"its corners [\d.]+ px uncertain \(over 1\.5 px"
        ):
            estimate_homography(frames, matches=[(src, dst)])
        return
    estimate = estimate_homography(frames, matches=[(src, dst)])
    assert _corner_drift(estimate.matrix, (4.0, 0.0)) < 1.5


@pytest.mark.parametrize("place", list(PLACES))
def test_the_predicted_corner_error_is_the_one_noise_gives(place: str) -> None:
    # corner_std_px from the points alone against the corners' spread over noisy fits
    (x0, x1), (y0, y1), spread = PLACES[place]
    rng = np.random.default_rng(2)
    src = np.stack([rng.uniform(x0, x1, 300), rng.uniform(y0, y1, 300)], axis=1)
    over = np.stack([rng.uniform(10, WIDTH - 10, spread), rng.uniform(10, HEIGHT - 10, spread)], 1)
    src = np.concatenate([src, over])
    corner = np.array([[[WIDTH - 1.0, HEIGHT - 1.0]], [[0.0, 0.0]]])
    errors = []
    for _ in range(400):
        dst = src + np.array([4.0, 0.0]) + rng.normal(0.0, 0.3, src.shape)
        matrix, _ = cv2.findHomography(src, dst, 0)
        errors.append(cv2.perspectiveTransform(corner, matrix)[:, 0] - corner[:, 0] - (4.0, 0.0))
    measured = float(np.sqrt(np.sum(np.var(np.array(errors), axis=0), axis=1)).max())
    truth = np.array([[1.0, 0.0, 4.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    predicted = corner_std_px(truth, src, 0.3, (HEIGHT, WIDTH))
    if measured > 5.0:  # far past the limit the first-order error is rough, but as far past
        assert predicted > 5.0
    else:
        assert predicted == pytest.approx(measured, rel=0.15)


def test_matches_repeated_over_the_frames_of_a_still_recording_count_once() -> None:
    # the same band's matches pooled from 30 frames of a robot standing still: the
    # prediction shrank by the square root of 30 and the fit (corners 6 px off) passed
    (x0, x1), (y0, y1), _ = PLACES["a band 4 px tall"]
    rng = np.random.default_rng(3)
    src = np.stack([rng.uniform(x0, x1, 300), rng.uniform(y0, y1, 300)], axis=1)
    dst = src + np.array([4.0, 0.0]) + rng.normal(0.0, 0.2, src.shape)
    view = SCENE[:HEIGHT]
    frames = [(view, view, VALID, VALID)] * 30
    with pytest.raises(RegistrationError, match="px uncertain"):
        estimate_homography(frames, matches=[(src, dst)] * 30)


def test_a_fit_whose_predicted_error_is_not_a_number_is_refused(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # a corner mapped to infinity gives NaN, and NaN > 1.5 is False: it was accepted
    src = np.stack(np.meshgrid(np.linspace(10, 500, 12), np.linspace(10, 350, 8)), -1)
    src = src.reshape(-1, 2)
    monkeypatch.setattr(registration, "corner_std_px", lambda *args: float("nan"))
    with pytest.raises(RegistrationError, match="nan px uncertain"):
        registration._check_determined(
            np.eye(3), src, np.full(len(src), 0.1), (HEIGHT, WIDTH), EstimationParams()
        )
