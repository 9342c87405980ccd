"""Registering the clean view onto the obstructed view.

**Per recording** (:func:`estimate_homography`): SIFT features on rectified
views of up to ~30 frames spread over the recording are matched with the
ratio test and a loose same-row test (rectified views agree on rows), pooled,
and fitted by MAGSAC++ (``cv2.USAC_MAGSAC``). Matches inside anomaly regions
(pixels where the first fit leaves a large residual: drops, dirt, near
objects) are then excluded and the homography fitted again, and finally
refined by least squares on the inliers. MAGSAC's sampler is seeded, so the
result is a pure function of the inputs.

**Gain compensation and anomaly regions**, on grey ``float32 [0, 1]`` views
of one size, serve both the estimation above and the per-frame checks of
:mod:`lenspair.rectify.verification` (whose thresholds, :class:`VerifyParams`, are
defined here for that reason):

- :func:`compensate_gain`: the target is fitted to the input by a local
  linear model ``a * target + b`` (box windows of ``gain_window_px``),
  because the two cameras differ in exposure and dust acts as a smooth
  ``a, b``.
- :func:`anomaly_regions`: where the blurred (sigma ``anomaly_blur_px``)
  compensated residual exceeds ``max(anomaly_threshold, 4 * median)``,
  dilated by ``anomaly_dilate_px``. A blur of 3 px hides misalignment of a
  pixel or two but not drops, dirt or large parallax.

**Registration error** (how accuracy is measured, ``tests/capture``): for a
grid of output pixels, the distance in raw clean pixels between where the
composed target map samples the clean image and where the simulator's true
far-plane homography (``truth/geometry.json``, through the true calibration)
says the same scene point is. On the rain, dust_swapped, parallax and
rotated samples its median is under 0.01 px (the requirement is 0.25 px).
"""

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from lenspair.rectify.errors import RegistrationError


@dataclass(frozen=True)
class EstimationParams:
    """Thresholds of the per-recording homography estimation (pixels are rectified px)."""

    max_frames: int = 30
    max_features: int = 3000
    ratio: float = 0.75
    max_row_offset_fraction: float = 0.1
    inlier_threshold_px: float = 1.5
    min_inliers: int = 30
    max_corner_std_px: float = 1.5
    """Largest predicted error (standard deviation) of the fit at the view's corners.

    A homography fitted to matches in a narrow band (texture along a horizon
    only) or in one corner fits them to a fraction of a pixel and is
    undetermined away from them: matches of 0.2 px noise in a band 8 px tall
    left the corners 2-5 px off, in a 60x40 px corner patch about 7 px, while
    every per-frame check passed. The error is predicted from the inliers'
    positions and residual (:func:`corner_std_px`), so dense matches in a band
    with a few spread over the view are accepted; one standard deviation of
    1.5 px stays within the 2 px registration residual curation allows.
    """
    match_std_floor_px: float = 0.25
    """Least localisation error assumed of a match: exact simulated matches
    (residual 0) would otherwise predict no error anywhere."""


@dataclass(frozen=True)
class VerifyParams:
    """Thresholds of the per-frame verification (the rule: :mod:`lenspair.rectify.verification`)."""

    gain_window_px: int = 63
    anomaly_blur_px: float = 3.0
    anomaly_threshold: float = 0.05
    anomaly_dilate_px: int = 5
    min_correlation: float = 0.6
    refine_px: float = 0.3
    max_shift_px: float = 2.0
    parallax_px: float = 1.0
    mask_dilate_px: int = 8
    max_mask_fraction: float = 0.4
    inlier_px: float = 1.0
    min_inliers: int = 8
    min_inlier_fraction: float = 0.6
    max_photometric_residual: float = 0.06


@dataclass(frozen=True)
class HomographyEstimate:
    """The recording's clean -> obstructed homography and how well it is supported.

    Attributes:
        matrix: 3x3 float64, rectified clean px -> rectified obstructed px.
        inliers: pooled matches consistent with it after the final fit.
        matches: pooled matches that entered the final fit.
        inliers_per_frame: inliers from each sampled frame, in input order.
        rms_px: RMS transfer error of the inliers, pixels.

    """

    matrix: np.ndarray
    inliers: int
    matches: int
    inliers_per_frame: tuple[int, ...]
    rms_px: float


def to_u8(gray: np.ndarray, stretch: bool = False) -> np.ndarray:
    """Grey ``float32 [0, 1]`` -> ``uint8``; ``stretch`` maps the 1st-99th percentile to 0-255."""
    if stretch:
        low, high = np.percentile(gray, [1.0, 99.0])
        gray = (gray - low) / max(float(high - low), 1e-6)
    return np.asarray(np.clip(gray * 255.0 + 0.5, 0, 255).astype(np.uint8))


def disk(radius: int) -> np.ndarray:
    """Filled elliptical structuring element: ``uint8 (2 * radius + 1,) * 2``, 1 inside."""
    return np.asarray(cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1,) * 2))


# -- per recording ---------------------------------------------------------------------


def _features(gray: np.ndarray, valid: np.ndarray, params: EstimationParams) -> tuple[Any, Any]:
    # SIFT, not ORB: ORB's keypoints on its pyramid levels carried a 0.2 px bias
    # into the pooled homography on the simulator's truth; SIFT's stay under 0.01 px.
    sift = cv2.SIFT.create(nfeatures=params.max_features)
    mask = np.where(cv2.erode(valid.astype(np.uint8), disk(4)) > 0, 255, 0).astype(np.uint8)
    keys, descriptors = sift.detectAndCompute(to_u8(gray, stretch=True), mask)
    return keys, descriptors


def match_views(
    obstructed: np.ndarray,
    clean: np.ndarray,
    obstructed_valid: np.ndarray,
    clean_valid: np.ndarray,
    params: EstimationParams,
) -> tuple[np.ndarray, np.ndarray]:
    """SIFT matches between two rectified grey views (ratio test, same-row test).

    Returns:
        ``(clean_points, obstructed_points)``, each ``(N, 2)`` float64 rectified px.

    """
    keys_o, desc_o = _features(obstructed, obstructed_valid, params)
    keys_c, desc_c = _features(clean, clean_valid, params)
    empty = np.zeros((0, 2))
    if desc_o is None or desc_c is None or len(keys_o) < 2 or len(keys_c) < 2:
        return empty, empty
    pairs = cv2.BFMatcher(cv2.NORM_L2).knnMatch(desc_c, desc_o, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < params.ratio * p[1].distance]
    src = np.array([keys_c[m.queryIdx].pt for m in good], dtype=np.float64).reshape(-1, 2)
    dst = np.array([keys_o[m.trainIdx].pt for m in good], dtype=np.float64).reshape(-1, 2)
    same_row = np.abs(src[:, 1] - dst[:, 1]) <= params.max_row_offset_fraction * obstructed.shape[0]
    return src[same_row], dst[same_row]


def _fit(
    src: np.ndarray, dst: np.ndarray, params: EstimationParams
) -> tuple[np.ndarray, np.ndarray]:
    if len(src) < max(params.min_inliers, 4):
        raise RegistrationError(
            f"only {len(src)} feature matches between the views (need >= {params.min_inliers}); "
            "the scene is too textureless or the views do not overlap"
        )
    matrix, inliers = cv2.findHomography(
        src, dst, cv2.USAC_MAGSAC, params.inlier_threshold_px, maxIters=10000, confidence=0.9999
    )
    if matrix is None or inliers is None:
        raise RegistrationError("no homography fits the feature matches")
    return np.asarray(matrix, dtype=np.float64), inliers.ravel().astype(bool)


def _transfer_error(matrix: np.ndarray, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    projected = cv2.perspectiveTransform(src.reshape(-1, 1, 2), matrix).reshape(-1, 2)
    return np.asarray(np.linalg.norm(projected - dst, axis=1))


def estimate_homography(
    frames: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]],
    params: EstimationParams | None = None,
    verify: VerifyParams | None = None,
    matches: Sequence[tuple[np.ndarray, np.ndarray]] | None = None,
) -> HomographyEstimate:
    """Estimate the clean -> obstructed homography from features pooled over frames.

    Args:
        frames: ``(obstructed, clean, obstructed_valid, clean_valid)`` per
            sampled frame: rectified grey ``float32 [0, 1]`` views of one
            size and bool masks of where each has data.
        params: estimation thresholds.
        verify: thresholds used to find anomaly regions between the passes.
        matches: :func:`match_views` of each frame when already computed
            (e.g. in worker processes); computed here when None.

    Raises:
        RegistrationError: too few matches or inliers (the message says how
            many), or inliers that leave the fit undetermined at the view's
            corners (:attr:`EstimationParams.max_corner_std_px`).

    """
    params = params or EstimationParams()
    verify = verify or VerifyParams()
    if matches is None:
        matches = [match_views(o, c, ov, cv, params) for o, c, ov, cv in frames]
    src = np.concatenate([m[0] for m in matches] or [np.zeros((0, 2))])
    dst = np.concatenate([m[1] for m in matches] or [np.zeros((0, 2))])
    owner = np.concatenate([np.full(len(m[0]), i) for i, m in enumerate(matches)] or [np.zeros(0)])
    first, _ = _fit(src, dst, params)
    keep = np.ones(len(src), dtype=bool)
    for index, (obstructed, clean, _, clean_valid) in enumerate(frames):
        size = obstructed.shape[::-1]
        warped = cv2.warpPerspective(clean, first, size, flags=cv2.INTER_LINEAR)
        covered = cv2.warpPerspective(clean_valid.astype(np.uint8), first, size) > 0
        anomaly = anomaly_regions(obstructed, compensate_gain(obstructed, warped, verify), verify)
        anomaly |= ~covered
        mine = np.flatnonzero(owner == index)
        cols = np.clip(np.rint(dst[mine, 0]).astype(int), 0, size[0] - 1)
        rows = np.clip(np.rint(dst[mine, 1]).astype(int), 0, size[1] - 1)
        keep[mine] = ~anomaly[rows, cols]
    src, dst, owner = src[keep], dst[keep], owner[keep]
    _, inliers = _fit(src, dst, params)
    if inliers.sum() < params.min_inliers:
        raise RegistrationError(
            f"only {int(inliers.sum())} matches support a homography (need >= {params.min_inliers})"
        )
    matrix, _ = cv2.findHomography(src[inliers], dst[inliers], 0)
    matrix = np.asarray(matrix / matrix[2, 2], dtype=np.float64)
    error = _transfer_error(matrix, src, dst)
    final = error <= params.inlier_threshold_px
    if frames:
        _check_determined(matrix, src[final], error[final], frames[0][0].shape, params)
    per_frame = tuple(int(np.sum(final & (owner == i))) for i in range(len(frames)))
    rms = float(np.sqrt(np.mean(error[final] ** 2))) if final.any() else float("nan")
    return HomographyEstimate(matrix, int(final.sum()), len(src), per_frame, rms)


def corner_std_px(
    matrix: np.ndarray, src: np.ndarray, sigma_px: float, shape: tuple[int, ...]
) -> float:
    """Predicted error of ``matrix`` at the view's corners, from the points it was fitted to.

    The homography's eight parameters (``h33 = 1``, source points normalised)
    fitted by least squares to ``src`` with matches of ``sigma_px`` noise have
    covariance ``sigma^2 (A^T A)^-1``, ``A`` the Jacobian of the mapped points; the
    error of a mapped corner follows through its own Jacobian. Returns the
    largest standard deviation (both axes together) over the four corners;
    infinite where the points cannot determine the parameters.
    """
    centre = src.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((src - centre) ** 2, axis=1)) / 2.0)) or 1.0
    normalise = np.array(
        [[1 / scale, 0, -centre[0] / scale], [0, 1 / scale, -centre[1] / scale], [0, 0, 1]]
    )
    fitted = matrix @ np.linalg.inv(normalise)
    fitted = fitted / fitted[2, 2]
    height, width = shape[:2]
    corners = np.array([[0, 0], [width - 1, 0], [0, height - 1], [width - 1, height - 1]], float)

    def jacobian(points: np.ndarray) -> np.ndarray:
        x, y = ((points - centre) / scale).T
        w = fitted[2, 0] * x + fitted[2, 1] * y + 1.0
        u = (fitted[0, 0] * x + fitted[0, 1] * y + fitted[0, 2]) / w
        v = (fitted[1, 0] * x + fitted[1, 1] * y + fitted[1, 2]) / w
        zero, one = np.zeros_like(x), np.ones_like(x)
        rows_u = np.stack([x, y, one, zero, zero, zero, -u * x, -u * y], axis=1) / w[:, None]
        rows_v = np.stack([zero, zero, zero, x, y, one, -v * x, -v * y], axis=1) / w[:, None]
        return np.concatenate([rows_u, rows_v])

    design = jacobian(src)
    information = design.T @ design
    eigenvalues = np.linalg.eigvalsh(information)
    if eigenvalues[0] <= 1e-12 * eigenvalues[-1]:
        return float("inf")
    covariance = sigma_px**2 * np.linalg.inv(information)
    at_corners = jacobian(corners)  # rows: the four corners' u, then their v
    variance = np.einsum("ij,jk,ik->i", at_corners, covariance, at_corners)
    return float(np.sqrt(variance[:4] + variance[4:]).max())


def _check_determined(
    matrix: np.ndarray,
    src: np.ndarray,
    residuals: np.ndarray,
    shape: tuple[int, ...],
    params: EstimationParams,
) -> None:
    """Refuse a homography its inliers leave undetermined at the view's corners."""
    rms = float(np.sqrt(np.mean(residuals**2))) if len(residuals) else 0.0
    sigma = max(rms, params.match_std_floor_px)
    # matches pooled over the frames of a still recording are the same scene points, whose
    # errors do not average out: counted once (30 copies made a 6 px band look determined)
    _, distinct = np.unique(np.round(src), axis=0, return_index=True)
    spread = corner_std_px(matrix, src[np.sort(distinct)], sigma, shape)
    if not spread <= params.max_corner_std_px:  # NaN (a corner mapped to infinity) too
        low, high = np.percentile(src, [5.0, 95.0], axis=0)
        across, down = (high - low) / (shape[1], shape[0])
        raise RegistrationError(
            f"the {len(src)} matches that support the homography lie in {across:.0%} of the "
            f"view's width and {down:.0%} of its height (most of them): away from them it is "
            f"not determined, its corners {spread:.1f} px uncertain (over "
            f"{params.max_corner_std_px:g} px refused); record where the scene has texture "
            "across more of the view"
        )


MAX_TURN_DEG = 10.0
"""A clean -> obstructed homography turning the view more than this is doubted."""

SCALE_RANGE = (0.8, 1.25)
"""... and one scaling it outside this range (two rectified views of one rig differ by a shift)."""


def implausible_turn(matrix: np.ndarray) -> str | None:
    """What is wrong with a registration that turns, mirrors or scales the view, or ``None``.

    Rectified views of one rig differ by a shift (the disparity of the far
    scene) and a little residual: a homography that turns one by 180 degrees
    registers the pairs exactly but says the calibration is not this rig's
    (another rig's camchain, a camera mounted upside down since).
    """
    affine = np.asarray(matrix, dtype=np.float64)[:2, :2] / matrix[2, 2]
    det = float(np.linalg.det(affine))
    if det <= 0:
        return "mirrors the view"
    turn = float(np.degrees(np.arctan2(affine[1, 0] - affine[0, 1], affine[0, 0] + affine[1, 1])))
    scale = float(np.sqrt(det))
    problems = []
    if abs(turn) > MAX_TURN_DEG:
        problems.append(f"turns the view by {turn:.0f} deg")
    if not SCALE_RANGE[0] <= scale <= SCALE_RANGE[1]:
        problems.append(f"scales it by {scale:.2f}")
    return " and ".join(problems) or None


# -- gain compensation and anomaly regions (also used by rectify.verification) ---------


def compensate_gain(reference: np.ndarray, moving: np.ndarray, params: VerifyParams) -> np.ndarray:
    """Match ``moving``'s local brightness and contrast to ``reference``'s.

    ``a * moving + b`` with ``a`` the ratio of local standard deviations and
    ``b`` the difference of local means (box windows of ``gain_window_px``).
    Unlike a local regression, the ratio of deviations does not shrink when
    the views are misaligned, so the compensation cannot pull a shifted
    target towards the reference (which would bias the shift measurements).

    Args:
        reference: grey ``float32 (H, W)``.
        moving: grey ``float32 (H, W)``, same size.
        params: ``gain_window_px`` sets the window.

    Returns:
        Compensated ``moving``, ``float32 (H, W)``.

    """
    size = (params.gain_window_px, params.gain_window_px)

    def mean(x: np.ndarray) -> np.ndarray:
        return np.asarray(cv2.boxFilter(x, -1, size, borderType=cv2.BORDER_REFLECT))

    mean_r, mean_m = mean(reference), mean(moving)
    floor = np.float32(1e-4)  # flat windows: gain -> 1, only the offset is matched
    variance_r = np.maximum(mean(reference * reference) - mean_r * mean_r, 0) + floor
    variance_m = np.maximum(mean(moving * moving) - mean_m * mean_m, 0) + floor
    gain = np.clip(np.sqrt(variance_r / variance_m), 0.25, 4.0)
    return np.asarray(gain * (moving - mean_m) + mean_r, dtype=np.float32)


def anomaly_regions(
    reference: np.ndarray, compensated: np.ndarray, params: VerifyParams
) -> np.ndarray:
    """Where the pair differs beyond a small misalignment: bool ``(H, W)``."""
    sigma = params.anomaly_blur_px
    residual = np.abs(
        cv2.GaussianBlur(reference, (0, 0), sigma) - cv2.GaussianBlur(compensated, (0, 0), sigma)
    )
    threshold = max(params.anomaly_threshold, 4.0 * float(np.median(residual)))
    regions = (residual > threshold).astype(np.uint8)
    return np.asarray(cv2.dilate(regions, disk(params.anomaly_dilate_px)) > 0)
