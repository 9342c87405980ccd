"""Verifying every registered frame: global shift, parallax mask and verdict.

**Per frame** (:func:`measure_shift` then :func:`verify_pair`), on the
cropped, registered pair, in grey ``float32 [0, 1]``, with the thresholds of
:class:`lenspair.rectify.registration.VerifyParams`:

1. *Gain compensation* (:func:`lenspair.rectify.registration.compensate_gain`): the
   target is fitted to the input by a local linear model ``a * target + b``
   (box windows of ``gain_window_px``).
2. *Anomaly regions* (:func:`lenspair.rectify.registration.anomaly_regions`): where
   the blurred (sigma ``anomaly_blur_px``) compensated residual exceeds
   ``max(anomaly_threshold, 4 * median)``, dilated by ``anomaly_dilate_px``.
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
"""

from dataclasses import dataclass

import cv2
import numpy as np

from lenspair.rectify.registration import (
    VerifyParams,
    anomaly_regions,
    compensate_gain,
    disk,
    to_u8,
)


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
    closed = cv2.morphologyEx(kept, cv2.MORPH_CLOSE, disk(7))
    return np.asarray(cv2.dilate(closed, disk(params.mask_dilate_px)) > 0)


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
