"""Registering the clean view onto the obstructed view, and verifying every frame.

**Per recording** (:func:`estimate_homography`): SIFT features on rectified
views of up to ~30 frames spread over the recording are matched with the
ratio test and a loose same-row test (rectified views agree on rows), pooled,
and fitted by MAGSAC++ (``cv2.USAC_MAGSAC``). Matches inside anomaly regions
(pixels where the first fit leaves a large residual: drops, dirt, near
objects) are then excluded and the homography fitted again, and finally
refined by least squares on the inliers. MAGSAC's sampler is seeded, so the
result is a pure function of the inputs.

**Per frame** (:func:`measure_shift` then :func:`verify_pair`), on the
cropped, registered pair, in grey ``float32 [0, 1]``:

1. *Gain compensation*: the target is fitted to the input by a local linear
   model ``a * target + b`` (box windows of ``gain_window_px``), because the
   two cameras differ in exposure and dust acts as a smooth ``a, b``.
2. *Anomaly regions*: where the blurred (sigma ``anomaly_blur_px``)
   compensated residual exceeds ``max(anomaly_threshold, 4 * median)``,
   dilated by ``anomaly_dilate_px``. A blur of 3 px hides misalignment of a
   pixel or two but not drops, dirt or large parallax.
3. *Global shift*: corners outside anomaly regions are tracked into the
   target (pyramidal Lucas-Kanade, forward-backward checked); the median of
   their motion starts ECC (``cv2.findTransformECC``, translation, half
   resolution), which runs outside anomaly regions and away from corners
   that disagree with the median (parallax). Fewer than ``min_inliers``
   corners, ECC failing, correlation < ``min_correlation``, ECC and the
   median disagreeing by over ``inlier_px``, or ``|shift| > max_shift_px``
   -> **rejected**.
   ``|shift| > refine_px`` -> the caller composes the shift into the target
   map (one remap still) and verifies the refined pair.
4. *Parallax*: rectified views differ only along rows, so residual parallax
   (about ``f * B / Z`` minus the far plane's) is a horizontal disparity.
   StereoBM between input and target finds it; pixels with
   ``|disparity| >= parallax_px`` (speckle-filtered), closed and dilated by
   ``mask_dilate_px``, form the **mask** (255 = not trustworthy).
   Mask fraction > ``max_mask_fraction`` -> **rejected**.
5. *Corner check*: corners are tracked again on the final pair. The
   median displacement is the frame's ``residual_px``; corners outside the
   mask that move less than ``inlier_px`` are its ``inliers``. Fewer than
   ``min_inliers``, or under ``min_inlier_fraction`` of the tracked corners
   outside the mask -> **rejected** (misaligned in a way the mask does not
   cover, e.g. vertically).
6. *Photometric residual*: mean ``|input - compensated target|`` outside
   anomaly regions and the mask, full-scale units; above
   ``max_photometric_residual`` -> **rejected**.

Anything else is **kept**, with its mask when the mask is not empty.

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

from rectify.errors import RectifyError


class RegistrationError(RectifyError):
    """No trustworthy homography between the two views could be estimated."""


@dataclass(frozen=True)
class EstimationParams:
    """Thresholds of the per-recording homography estimation (pixels are rectified px)."""

    max_frames: int = 30
    max_features: int = 3000
    ratio: float = 0.75
    max_row_offset_fraction: float = 0.1
    inlier_threshold_px: float = 1.5
    min_inliers: int = 30


@dataclass(frozen=True)
class VerifyParams:
    """Thresholds of the per-frame verification; see the module docstring for the rule."""

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


@dataclass(frozen=True)
class Shift:
    """ECC's measurement of how far the target is off: ``target(x + shift) ~ input(x)``."""

    dx: float
    dy: float
    correlation: float
    anomaly: np.ndarray
    failure: str | None = None

    @property
    def magnitude(self) -> float:
        """Length of the shift, pixels."""
        return float(np.hypot(self.dx, self.dy))


@dataclass(frozen=True)
class Verification:
    """The verdict on one registered pair (see the module docstring).

    Attributes:
        reason: why the pair is rejected, else None.
        mask: ``(H, W)`` bool, True where the pair is not trustworthy.
        mask_fraction: mean of ``mask``.
        residual_px: median corner displacement input -> target, px (None: no corners).
        inliers: corners outside the mask that agree within ``inlier_px``.
        photometric_residual: mean compensated difference outside anomalies, full scale.

    """

    reason: str | None
    mask: np.ndarray
    mask_fraction: float
    residual_px: float | None
    inliers: int
    photometric_residual: float


def to_u8(gray: np.ndarray, stretch: bool = False) -> np.ndarray:
    """Grey ``float32 [0, 1]`` -> ``uint8``; ``stretch`` maps the 1st-99th percentile to 0-255."""
    if stretch:
        low, high = np.percentile(gray, [1.0, 99.0])
        gray = (gray - low) / max(float(high - low), 1e-6)
    return np.asarray(np.clip(gray * 255.0 + 0.5, 0, 255).astype(np.uint8))


def _disk(radius: int) -> np.ndarray:
    return np.asarray(cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1,) * 2))


# -- per recording ---------------------------------------------------------------------


def _features(gray: np.ndarray, valid: np.ndarray, params: EstimationParams) -> tuple[Any, Any]:
    # SIFT, not ORB: ORB's keypoints on its pyramid levels carried a 0.2 px bias
    # into the pooled homography on the simulator's truth; SIFT's stay under 0.01 px.
    sift = cv2.SIFT.create(nfeatures=params.max_features)
    mask = np.where(cv2.erode(valid.astype(np.uint8), _disk(4)) > 0, 255, 0).astype(np.uint8)
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
        RegistrationError: too few matches or inliers; the message says how many.

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
    per_frame = tuple(int(np.sum(final & (owner == i))) for i in range(len(frames)))
    rms = float(np.sqrt(np.mean(error[final] ** 2))) if final.any() else float("nan")
    return HomographyEstimate(matrix, int(final.sum()), len(src), per_frame, rms)


# -- per frame -------------------------------------------------------------------------


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
    return np.asarray(cv2.dilate(regions, _disk(params.anomaly_dilate_px)) > 0)


def track_corners(
    reference: np.ndarray, compensated: np.ndarray, allowed: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Corners of ``reference`` (where allowed) tracked into ``compensated``.

    Pyramidal Lucas-Kanade, kept only when tracking back lands within 0.5 px
    of the start.

    Returns:
        ``(points, displacement)``: ``(N, 2)`` float64 corner positions and
        their ``(dx, dy)`` motion, so that ``compensated(p + d) ~ reference(p)``.

    """
    ref_u8, tgt_u8 = to_u8(reference), to_u8(compensated)
    corners = cv2.goodFeaturesToTrack(
        ref_u8, maxCorners=300, qualityLevel=0.01, minDistance=10, mask=allowed.astype(np.uint8)
    )
    if corners is None:
        return np.zeros((0, 2)), np.zeros((0, 2))
    window = (21, 21)
    # OpenCV's stubs do not allow nextPts=None, which the function accepts.
    forward, ok_f, _ = cv2.calcOpticalFlowPyrLK(  # type: ignore[call-overload]
        ref_u8, tgt_u8, corners, None, winSize=window, maxLevel=2
    )
    back, ok_b, _ = cv2.calcOpticalFlowPyrLK(  # type: ignore[call-overload]
        tgt_u8, ref_u8, forward, None, winSize=window, maxLevel=2
    )
    start = corners.reshape(-1, 2).astype(np.float64)
    consistent = np.linalg.norm(back.reshape(-1, 2) - start, axis=1) < 0.5
    good = ok_f.ravel().astype(bool) & ok_b.ravel().astype(bool) & consistent
    return start[good], forward.reshape(-1, 2)[good].astype(np.float64) - start[good]


def measure_shift(reference: np.ndarray, target: np.ndarray, params: VerifyParams) -> Shift:
    """How far ``target`` is off ``reference`` as a whole (a translation).

    Corners outside anomaly regions are tracked; the median of their motion
    is a robust first estimate, which ECC then refines on the pixels outside
    anomaly regions and away from corners that disagree with it (parallax).

    Args:
        reference: the input (obstructed) view, grey ``float32 [0, 1]``.
        target: the registered clean view, same size.
        params: verification thresholds.

    Returns:
        The shift; ``failure`` says why it could not be measured or is too large.

    """
    compensated = compensate_gain(reference, target, params)
    anomaly = anomaly_regions(reference, compensated, params)
    points, moved = track_corners(reference, compensated, ~anomaly)
    if len(points) < params.min_inliers:
        few = f"{len(points)} corners tracked (need >= {params.min_inliers})"
        return Shift(0.0, 0.0, 0.0, anomaly, f"registration unverified: {few}")
    robust = np.median(moved, axis=0)
    outliers = np.zeros(anomaly.shape, dtype=np.uint8)
    for x, y in points[np.linalg.norm(moved - robust, axis=1) > params.inlier_px]:
        cv2.circle(outliers, (round(x), round(y)), 15, 1, -1)
    half = (reference.shape[1] // 2, reference.shape[0] // 2)
    allowed = ((~anomaly) & (outliers == 0)).astype(np.uint8)
    if allowed.mean() < 0.1:
        return Shift(0.0, 0.0, 0.0, anomaly, "registration failed: anomalies cover the frame")
    mask = cv2.resize(allowed, half, interpolation=cv2.INTER_NEAREST)
    start = np.array([[1.0, 0.0, robust[0] / 2], [0.0, 1.0, robust[1] / 2]], dtype=np.float32)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 60, 1e-5)
    try:
        correlation, warp = cv2.findTransformECC(  # type: ignore[call-overload]
            cv2.resize(reference, half, interpolation=cv2.INTER_AREA),
            cv2.resize(compensated, half, interpolation=cv2.INTER_AREA),
            start, cv2.MOTION_TRANSLATION, criteria, mask, 3,
        )  # fmt: skip
    except cv2.error:
        return Shift(0.0, 0.0, 0.0, anomaly, "registration failed: ECC did not converge")
    shift = Shift(2.0 * float(warp[0, 2]), 2.0 * float(warp[1, 2]), float(correlation), anomaly)
    failure: str | None = None
    if shift.correlation < params.min_correlation:
        failure = f"ECC correlation {shift.correlation:.2f} < {params.min_correlation}"
    elif shift.magnitude > params.max_shift_px:
        failure = f"target off by {shift.magnitude:.2f} px (> {params.max_shift_px} px)"
    elif np.hypot(*(np.array([shift.dx, shift.dy]) - robust)) > params.inlier_px:
        failure = f"ECC and corner tracks disagree by more than {params.inlier_px} px"
    if failure is None:
        return shift
    return Shift(shift.dx, shift.dy, shift.correlation, anomaly, f"registration failed: {failure}")


def _explained_by_shift(
    reference: np.ndarray, compensated: np.ndarray, region: np.ndarray, disparity: float
) -> bool:
    """Does shifting the target by ``disparity`` along rows make ``region`` agree?

    Real parallax does (the content is the same, displaced); a raindrop or
    dirt, where StereoBM may still find a spurious unique match, does not.
    """
    ys, xs = np.nonzero(region)
    top, left = int(ys.min()), int(xs.min())
    box = (slice(top, int(ys.max()) + 1), slice(left, int(xs.max()) + 1))
    grid_x, grid_y = np.meshgrid(
        np.arange(box[1].start, box[1].stop, dtype=np.float32) - np.float32(disparity),
        np.arange(box[0].start, box[0].stop, dtype=np.float32),
    )
    moved = cv2.remap(compensated, grid_x, grid_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    inside = region[box]
    before = float(np.abs(reference[box] - compensated[box])[inside].mean())
    after = float(np.abs(reference[box] - moved)[inside].mean())
    return before > _VISIBLE_RESIDUAL and after < min(
        _EXPLAINED_RATIO * before, _EXPLAINED_RESIDUAL
    )


_VISIBLE_RESIDUAL = 0.015
_EXPLAINED_RATIO = 0.5
_EXPLAINED_RESIDUAL = 0.03
"""A region is parallax when it differs visibly (mean residual over 0.015 of full scale:
flat regions, where a shift changes nothing, are not flagged) and its row shift
leaves under half of that residual, and under 0.03."""


def parallax_mask(
    reference: np.ndarray, compensated: np.ndarray, params: VerifyParams
) -> np.ndarray:
    """Pixels whose horizontal disparity input -> target is ``>= parallax_px``: bool ``(H, W)``.

    StereoBM (input left, target right, disparities -32..31 px) finds where
    the target is displaced along rows; each connected region off by at least
    ``parallax_px`` is kept only when shifting the target by its median
    disparity explains it (:func:`_explained_by_shift`); the kept regions are
    closed and dilated by ``mask_dilate_px``.
    """
    matcher = cv2.StereoBM.create(numDisparities=64, blockSize=15)
    matcher.setMinDisparity(-32)
    matcher.setUniquenessRatio(15)
    matcher.setTextureThreshold(10)
    matcher.setSpeckleWindowSize(150)
    matcher.setSpeckleRange(32)  # 2 px: StereoBM counts it in 1/16 px
    disparity = matcher.compute(to_u8(reference), to_u8(compensated))
    valid = disparity > (matcher.getMinDisparity() - 1) * 16
    moved = (valid & (np.abs(disparity) >= params.parallax_px * 16)).astype(np.uint8)
    count, labels = cv2.connectedComponents(moved, connectivity=8)
    kept = np.zeros(moved.shape, dtype=np.uint8)
    for label in range(1, count):
        region = labels == label
        shift = float(np.median(disparity[region])) / 16.0
        if _explained_by_shift(reference, compensated, region, shift):
            kept[region] = 1
    closed = cv2.morphologyEx(kept, cv2.MORPH_CLOSE, _disk(7))
    return np.asarray(cv2.dilate(closed, _disk(params.mask_dilate_px)) > 0)


def verify_pair(
    reference: np.ndarray, target: np.ndarray, anomaly: np.ndarray, params: VerifyParams
) -> Verification:
    """Check a registered pair; returns the verdict, mask and figures (module docstring).

    Args:
        reference: input (obstructed) view, grey ``float32 [0, 1]``, ``(H, W)``.
        target: registered (and refined) clean view, same size.
        anomaly: anomaly regions from :func:`measure_shift`.
        params: verification thresholds.

    """
    compensated = compensate_gain(reference, target, params)
    mask = parallax_mask(reference, compensated, params)
    mask_fraction = float(mask.mean())
    points, moved = track_corners(reference, compensated, ~anomaly)
    distance = np.linalg.norm(moved, axis=1)
    residual = float(np.median(distance)) if len(distance) else None
    outside = ~mask[np.rint(points[:, 1]).astype(int), np.rint(points[:, 0]).astype(int)]
    inliers = int(np.sum(outside & (distance < params.inlier_px)))
    fraction = inliers / max(int(outside.sum()), 1)
    trusted = ~(anomaly | mask)
    difference = np.abs(reference - compensated)
    photometric = float(difference[trusted].mean()) if trusted.any() else 1.0
    reason = None
    if mask_fraction > params.max_mask_fraction:
        reason = (
            f"parallax: {100 * mask_fraction:.0f}% of the frame is off by >= "
            f"{params.parallax_px} px (> {100 * params.max_mask_fraction:.0f}%)"
        )
    elif inliers < params.min_inliers:
        reason = (
            f"registration unverified: {inliers} corners agree within {params.inlier_px} px "
            f"(need >= {params.min_inliers})"
        )
    elif fraction < params.min_inlier_fraction:
        reason = (
            f"registration failed: only {100 * fraction:.0f}% of tracked corners outside the mask "
            f"agree within {params.inlier_px} px (need >= {100 * params.min_inlier_fraction:.0f}%)"
        )
    elif photometric > params.max_photometric_residual:
        reason = (
            f"photometric residual {photometric:.3f} > {params.max_photometric_residual} "
            "outside anomaly regions"
        )
    return Verification(reason, mask, mask_fraction, residual, inliers, photometric)
