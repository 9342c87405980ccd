"""Registration on synthetic two-view scenes with known truth."""

import cv2
import numpy as np
import pytest

from lenspair.core.quality import to_grey
from lenspair.rectify.errors import RegistrationError
from lenspair.rectify.registration import (
    EstimationParams,
    VerifyParams,
    compensate_gain,
    estimate_homography,
    implausible_turn,
    match_views,
)
from lenspair.rectify.remap import apply_homography, pixel_grid
from lenspair.rectify.verification import measure_shift, verify_pair
from tests.images import texture

PARAMS = VerifyParams()


def _drops(
    image: np.ndarray, rng: np.random.Generator, count: int
) -> tuple[np.ndarray, np.ndarray]:
    """Disks showing a flipped, blurred view of the scene (crude raindrops) and their mask."""
    out, mask = image.copy(), np.zeros(image.shape, bool)
    h, w = image.shape
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    for _ in range(count):
        cx, cy, r = rng.uniform(0, w), rng.uniform(0, h), rng.uniform(6, 22)
        disk = (xs - cx) ** 2 + (ys - cy) ** 2 < r * r
        sx = np.clip(cx - 0.5 * (xs - cx), 0, w - 1)
        sy = np.clip(cy - 0.5 * (ys - cy), 0, h - 1)
        flipped = cv2.GaussianBlur(cv2.remap(image, sx, sy, cv2.INTER_LINEAR), (0, 0), 2)
        out[disk] = 0.8 * flipped[disk] + 0.1
        mask |= disk
    return out, mask


BIG = texture((420, 620), 3)


def _pair(
    shift: tuple[float, float] = (0.0, 0.0),
    near: tuple[int, int, int, int, float] | None = None,
    drops: int = 30,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(obstructed, clean, drop mask): 540x360, clean shifted by ``shift`` and darker."""
    obstructed, drop_mask = _drops(BIG[30:390, 40:580].copy(), np.random.default_rng(1), drops)

    def view(dx: float, dy: float) -> np.ndarray:
        M = np.float32([[1, 0, 40 + dx], [0, 1, 30 + dy]])
        flags = cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP
        return np.asarray(cv2.warpAffine(BIG, M, (540, 360), flags=flags))

    clean = view(*shift)
    if near is not None:
        x, y, w, h, disparity = near
        clean[y : y + h, x : x + w] = view(disparity, 0.0)[y : y + h, x : x + w]
    clean = np.clip(clean * 0.8 + 0.05, 0, 1).astype(np.float32)  # another exposure
    return obstructed.astype(np.float32), clean, drop_mask


def test_to_grey_scales_by_bit_depth() -> None:
    assert to_grey(np.full((2, 2), 65535, np.uint16)).max() == pytest.approx(1.0)
    rgb = np.zeros((2, 2, 3), np.uint8)
    rgb[..., 1] = 255
    assert to_grey(rgb)[0, 0] == pytest.approx(0.587, abs=1e-3)


def test_gain_compensation_removes_exposure_difference() -> None:
    obstructed, clean, _ = _pair(drops=0)
    before = np.abs(obstructed - clean).mean()
    after = np.abs(obstructed - compensate_gain(obstructed, clean, PARAMS)).mean()
    assert after < 0.1 * before


def test_homography_recovered_despite_drops_and_exposure() -> None:
    truth = np.array([[1.003, 0.001, 6.5], [0.0005, 0.999, 0.3], [2e-6, 0.0, 1.0]])
    big = texture((520, 800), 7)
    rng = np.random.default_rng(2)
    frames = []
    for i in range(3):
        scene = np.roll(big, -9 * i, axis=1)[20:500, 20:772].copy()
        obstructed, _ = _drops(scene, rng, 40)
        clean = cv2.warpPerspective(scene, np.linalg.inv(truth), (752, 480), flags=cv2.INTER_CUBIC)
        clean = np.clip(clean * 0.8 + 0.05, 0, 1).astype(np.float32)
        valid = np.ones(obstructed.shape, bool)
        frames.append((obstructed.astype(np.float32), clean, valid, valid))
    params = EstimationParams(max_features=1500)
    matches = [match_views(o, c, ov, cv, params) for o, c, ov, cv in frames]
    estimate = estimate_homography(frames, params, matches=matches)
    # the second pass leaves out the matches on drops (the refracted scene in them
    # matches somewhere else): with it gone, every match entered the final fit
    assert estimate.matches < sum(len(m[0]) for m in matches)
    points = pixel_grid(106, 60, 540, 360)
    error = np.linalg.norm(
        apply_homography(estimate.matrix, points) - apply_homography(truth, points), axis=1
    )
    assert np.median(error) < 0.05 and error.max() < 0.15
    assert len(estimate.inliers_per_frame) == 3 and min(estimate.inliers_per_frame) > 100
    assert estimate.rms_px < 0.5


def test_homography_from_flat_views_is_a_clear_error() -> None:
    flat = np.full((120, 160), 0.5, np.float32)
    valid = np.ones(flat.shape, bool)
    with pytest.raises(RegistrationError, match=r"only 0 feature matches .*\(need >= 30\)"):
        estimate_homography([(flat, flat, valid, valid)])


def test_aligned_pair_is_kept_without_mask() -> None:
    obstructed, clean, _ = _pair()
    shift = measure_shift(obstructed, clean, PARAMS)
    assert shift.failure is None and shift.magnitude < 0.05 and shift.correlation > 0.95
    verdict = verify_pair(obstructed, clean, shift.anomaly, PARAMS)
    assert verdict.reason is None
    assert verdict.mask_fraction < 0.02
    assert verdict.residual_px is not None and verdict.residual_px < 0.1
    assert verdict.inliers > 100 and verdict.photometric_residual < 0.02


def test_drops_are_anomalies_not_parallax() -> None:
    obstructed, clean, drops = _pair(drops=60)
    shift = measure_shift(obstructed, clean, PARAMS)
    assert shift.anomaly[drops].mean() > 0.6  # most of the drop area is excluded
    verdict = verify_pair(obstructed, clean, shift.anomaly, PARAMS)
    assert verdict.reason is None
    assert verdict.mask[drops].mean() < 0.1  # drops stay trainable


@pytest.mark.parametrize("true_shift", [(0.7, -0.4), (-1.5, 0.0), (0.0, 1.2)])
def test_global_shift_is_measured(true_shift: tuple[float, float]) -> None:
    obstructed, clean, _ = _pair(shift=true_shift)
    shift = measure_shift(obstructed, clean, PARAMS)
    assert shift.failure is None
    # target(x + shift) ~ input(x): the clean view sampled at +true_shift needs -true_shift
    assert shift.dx == pytest.approx(-true_shift[0], abs=0.1)
    assert shift.dy == pytest.approx(-true_shift[1], abs=0.1)


def test_large_shift_is_rejected() -> None:
    obstructed, clean, _ = _pair(shift=(4.0, 0.0))
    shift = measure_shift(obstructed, clean, PARAMS)
    assert shift.failure is not None
    assert shift.failure.startswith("registration failed: target off by 3.")


def test_vertical_misalignment_is_never_kept() -> None:
    obstructed, clean, _ = _pair(shift=(0.0, 1.2))
    shift = measure_shift(obstructed, clean, PARAMS)
    verdict = verify_pair(obstructed, clean, shift.anomaly, PARAMS)  # without refinement
    assert verdict.reason is not None and "registration" in verdict.reason


def test_a_pair_most_of_whose_corners_disagree_is_refused_however_many_agree() -> None:
    # 110 corners agree (enough by count), but the left 300 columns sit 1.5 px lower:
    # with the share rule gone the pair was kept, misregistered over most of the frame
    obstructed, clean, _ = _pair()
    moved = cv2.warpAffine(
        BIG, np.float32([[1, 0, 40], [0, 1, 31.5]]), (540, 360),
        flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP,
    )  # fmt: skip
    clean[:, :300] = np.clip(moved[:, :300] * 0.8 + 0.05, 0, 1)
    verdict = verify_pair(obstructed, clean, np.zeros(clean.shape, bool), PARAMS)
    assert verdict.inliers >= PARAMS.min_inliers
    assert verdict.reason is not None
    assert verdict.reason.startswith("registration failed: only ")


def test_near_object_is_masked() -> None:
    x, y, w, h = 200, 100, 120, 100
    obstructed, clean, _ = _pair(near=(x, y, w, h, 6.0))
    shift = measure_shift(obstructed, clean, PARAMS)
    assert shift.failure is None and shift.magnitude < 0.1
    verdict = verify_pair(obstructed, clean, shift.anomaly, PARAMS)
    assert verdict.reason is None
    assert verdict.mask[y : y + h, x : x + w].mean() > 0.9
    outside = np.ones_like(verdict.mask)
    outside[y - 20 : y + h + 20, x - 20 : x + w + 20] = False
    assert verdict.mask[outside].mean() < 0.02


def test_mostly_near_frame_is_rejected_and_does_not_bias_the_shift() -> None:
    obstructed, clean, _ = _pair(near=(0, 0, 400, 300, 6.0))
    shift = measure_shift(obstructed, clean, PARAMS)
    assert shift.magnitude < PARAMS.refine_px  # the far part decides
    verdict = verify_pair(obstructed, clean, shift.anomaly, PARAMS)
    assert verdict.reason is not None and verdict.reason.startswith("parallax: ")


def test_flat_frame_cannot_be_verified() -> None:
    flat = np.full((360, 540), 0.4, np.float32)
    shift = measure_shift(flat, flat, PARAMS)
    assert shift.failure is not None and shift.failure.startswith("registration unverified")


def _turned(degrees: float, scale: float = 1.0, mirror: bool = False) -> np.ndarray:
    c, s = np.cos(np.radians(degrees)) * scale, np.sin(np.radians(degrees)) * scale
    flip = -1.0 if mirror else 1.0
    return np.array([[c, -s * flip, 700.0], [s, c * flip, 500.0], [1e-5, 2e-5, 1.0]])


def test_a_registration_that_turns_mirrors_or_scales_the_view_is_doubted() -> None:
    # another rig's camchain registered every pair exactly through a 180 deg turn, unsaid
    shift = np.array([[1.0, 0.002, -14.0], [-0.001, 0.998, 0.6], [0.0, 0.0, 1.0]])
    assert implausible_turn(shift) is None  # rectified views: a shift and a little residual
    assert implausible_turn(_turned(3.0, 1.04)) is None
    assert implausible_turn(_turned(180.0)) == "turns the view by 180 deg"
    assert implausible_turn(_turned(-25.0)) == "turns the view by -25 deg"
    assert implausible_turn(_turned(0.0, 1.5)) == "scales it by 1.50"
    assert implausible_turn(_turned(0.0, mirror=True)) == "mirrors the view"
    assert (
        implausible_turn(2.0 * _turned(90.0, 0.5))
        == "turns the view by 90 deg and scales it by 0.50"
    )


@pytest.mark.parametrize("seed", range(3))
def test_inliers_are_the_matches_within_the_threshold_of_the_final_fit(seed: int) -> None:
    # the count and the RMS are of the final least-squares fit, not of the robust fit's
    # inlier mask: near the threshold the two disagree, and an RMS over the mask's matches
    # could exceed the threshold it reports against
    params = EstimationParams()
    rng = np.random.default_rng(seed)
    truth = np.array([[1.01, 0.002, 3.0], [0.001, 0.99, -2.0], [1e-6, 2e-6, 1.0]])
    src = rng.uniform([30, 30], [510, 330], (400, 2))
    dst = cv2.perspectiveTransform(src.reshape(-1, 1, 2), truth).reshape(-1, 2)
    angle, radius = rng.uniform(0, 2 * np.pi, 400), rng.uniform(0, 2.0, 400)
    dst += np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1)
    view, valid = np.full((360, 540), 0.5, np.float32), np.ones((360, 540), bool)
    estimate = estimate_homography([(view, view, valid, valid)], matches=[(src, dst)])
    projected = cv2.perspectiveTransform(src.reshape(-1, 1, 2), estimate.matrix).reshape(-1, 2)
    error = np.linalg.norm(projected - dst, axis=1)
    within = error <= params.inlier_threshold_px
    assert estimate.matches == 400
    assert estimate.inliers == within.sum() == estimate.inliers_per_frame[0]
    assert estimate.rms_px == pytest.approx(np.sqrt(np.mean(error[within] ** 2)), rel=1e-9)
