"""Stereo calibration from board views: each camera alone, then the pair with intrinsics fixed.

The procedure (see DESIGN.md, "Geometry notes"):

1. Each camera is calibrated alone from every view where it sees the board:
   ``cv2.calibrateCamera`` with ``k3`` fixed to 0 for ``pinhole-radtan``
   (Kalibr's radtan has four coefficients), ``cv2.fisheye.calibrate`` for
   ``pinhole-equi`` (Kalibr's equidistant model).
2. Views where both cameras see the board are matched corner by corner
   (ChArUco: by id; a plain chessboard may be numbered from a different
   corner in each camera, e.g. when cam1 is mounted upside down, so its
   numbering is chosen per view to agree with the rig's relative pose).
3. ``cv2.stereoCalibrate`` / ``cv2.fisheye.stereoCalibrate`` with the
   intrinsics fixed estimates the rigid transform cam0 -> cam1.
4. The same call, starting from each camera's intrinsics, refines both
   cameras' intrinsics with the rig over the views step 3 kept, where it can
   and where each camera's own views still fit the result
   (:func:`_refine_jointly`): each camera's own focal error would otherwise
   become baseline error. The intrinsics and the baseline come with 1-sigma
   deviations from the corner residuals (:mod:`~lenspair.rectify.calib_fits`).

At every step a view whose RMS reprojection error exceeds
``max(outlier_factor * median, outlier_floor_px)`` is rejected, and the step
is repeated until none is; each rejection is recorded with its reason. A
round that would leave fewer than ``min_views`` views rejects none: outlier
rejection never fails a calibration that works without it.
Each camera's fit and the stereo step's views are then checked
(:mod:`~lenspair.rectify.fit_checks`): a board that stood still or was seen at
too few distinct poses, or a fit with pixels no camera has, is refused; a
camera that fits its views far worse than the other is warned about.
Reprojection errors are RMS over corners of the Euclidean pixel residual.
"""

import contextlib
import dataclasses
import logging
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Literal, TypeVar

import cv2
import numpy as np

from lenspair.core.progress import progress
from lenspair.rectify.boards import Board, Detection, detect_corners
from lenspair.rectify.calib_fits import (
    INTRINSIC_NAMES,
    Points,
    RigDeviations,
    deviations,
    fit_camera,
    fit_stereo,
    intrinsic_covariance,
    match_views,
    refinable,
    refit_poses,
    rig_deviations,
    rms,
    stereo_residuals,
    view_error,
)
from lenspair.rectify.errors import RectifyError
from lenspair.rectify.fit_checks import (
    check_distinct_poses,
    check_fit,
    check_pose_spread,
    rms_balance_warnings,
)
from lenspair.rectify.layout import unsupported_layout
from lenspair.rectify.rectification import StereoRectification, project_rays, row_disagreement
from lenspair.rectify.rig import CameraModel, DistortionModel, StereoRig

log = logging.getLogger(__name__)

CalibrationModel = Literal["pinhole-radtan", "pinhole-equi"]
MODELS: dict[str, DistortionModel] = {"pinhole-radtan": "radtan", "pinhole-equi": "equidistant"}
T = TypeVar("T")
_COVERAGE_GRID = np.array([8, 6])
_LOW_COVERAGE = 0.5


def parse_model(name: str) -> CalibrationModel:
    """Check a ``--model`` name; raises ``RectifyError`` listing the valid ones."""
    if name not in MODELS:
        raise RectifyError(f"model: unknown {name!r}; valid: {', '.join(MODELS)}")
    return name  # type: ignore[return-value]


@dataclass(frozen=True)
class CalibrationOptions:
    """Knobs of :func:`calibrate_stereo`.

    Attributes:
        outlier_factor: reject views above this multiple of the median view error.
        outlier_floor_px: never reject a view whose error is below this (pixels).
        max_rounds: rejection rounds per step.
        min_views: fewest views a step may be left with.
        pose_tolerance_deg: a view whose cam0 -> cam1 rotation (from the two
            board poses) differs more than this from the consensus is rejected.
        alpha: rectification ``alpha`` used for the row-disagreement figure.
        refine_jointly: refine both cameras' intrinsics with the rig after the
            stereo step (:func:`_refine_jointly`); False keeps each camera's own.

    """

    outlier_factor: float = 3.0
    outlier_floor_px: float = 0.5
    max_rounds: int = 10
    min_views: int = 5
    pose_tolerance_deg: float = 3.0
    alpha: float = 0.0
    refine_jointly: bool = True


@dataclass(frozen=True)
class RejectedView:
    """A view left out of the calibration, and why.

    Attributes:
        view: index in the input sequence.
        name: the caller's name for it (e.g. timestamps).
        stage: ``cam0``, ``cam1`` (single-camera step) or ``stereo``.
        error_px: its RMS reprojection error when rejected, if measured.
        reason: one line for people.

    """

    view: int
    name: str
    stage: str
    error_px: float | None
    reason: str


@dataclass(frozen=True, eq=False)
class CameraCalibration:
    """Result of calibrating one camera alone.

    Attributes:
        camera: the estimated camera model.
        rms_px: RMS reprojection error over all corners of the used views.
        views: indices of the views used.
        view_errors_px: RMS error of each used view, same order.
        rvecs: ``(V, 3)`` board -> camera rotation vectors of the used views.
        tvecs: ``(V, 3)`` board -> camera translations, metres.
        coverage: fraction of the cells of an 8x6 grid over the image that
            hold a corner of a used view; where the board never went, the
            distortion is extrapolated.
        intrinsics_covariance: ``(8, 8)`` covariance of the intrinsics and
            distortion coefficients (:data:`~lenspair.rectify.calib_fits.INTRINSIC_NAMES`)
            from the corner residuals
            (:func:`~lenspair.rectify.calib_fits.intrinsic_covariance`).

    Where the intrinsics were refined with the rig (``CalibrationResult.refinement``),
    the camera, its covariance (of the joint fit), ``rms_px``, the view errors and
    poses are those of the refined intrinsics, over the same views.
    """

    camera: CameraModel
    rms_px: float
    views: tuple[int, ...]
    view_errors_px: tuple[float, ...]
    rvecs: np.ndarray
    tvecs: np.ndarray
    coverage: float
    intrinsics_covariance: np.ndarray

    @property
    def intrinsics_std(self) -> tuple[float, ...]:
        """1-sigma deviations (:data:`~lenspair.rectify.calib_fits.INTRINSIC_NAMES` order)."""
        return tuple(float(d) for d in deviations(self.intrinsics_covariance))

    @property
    def focal_std(self) -> float:
        """The larger 1-sigma deviation of ``fx`` and ``fy``, as a share of the focal length."""
        fx, fy = self.camera.intrinsics[:2]
        return max(self.intrinsics_std[0] / fx, self.intrinsics_std[1] / fy)


@dataclass(frozen=True, eq=False)
class CalibrationResult:
    """Everything :func:`calibrate_stereo` found out.

    Attributes:
        rig: the calibrated rig (write it with :func:`lenspair.rectify.rig.write_kalibr`).
        board: the board used.
        model: ``pinhole-radtan`` or ``pinhole-equi``.
        cameras: the single-camera calibrations of cam0 and cam1.
        stereo_rms_px: RMS reprojection error of the stereo step, both cameras.
        stereo_views: indices of the views used by the stereo step.
        stereo_view_errors_px: RMS error of each of those views.
        row_disagreement_px: RMS of rectified row differences of matched corners;
            None for a rig that is not side by side (top/bottom, or cam1 in front
            of cam0: :func:`~lenspair.rectify.layout.unsupported_layout`), which
            is not rectified.
        rejected: views left out, in the order they were rejected.
        counts: ``views``, ``cam0_detected``, ``cam1_detected``, ``both_detected``.
        warnings: what the calibration warned about as it ran (a marker size
            off, too little tilt, kept outliers), for the report; the board's
            coverage warnings are added by :meth:`report`.
        baseline_std_m: 1-sigma deviation of the baseline, metres, as fitted
            (the refined rig's, or the fixed-intrinsics fit's with both cameras'
            intrinsics errors in it); None where the views leave it undetermined.
        refinement: whether the intrinsics were refined with the rig, and why not.

    """

    rig: StereoRig
    board: Board
    model: CalibrationModel
    cameras: tuple[CameraCalibration, CameraCalibration]
    stereo_rms_px: float
    stereo_views: tuple[int, ...]
    stereo_view_errors_px: tuple[float, ...]
    row_disagreement_px: float | None
    rejected: tuple[RejectedView, ...]
    counts: dict[str, int]
    warnings: tuple[str, ...] = ()
    baseline_std_m: float | None = None
    refinement: str = ""

    def coverage_warnings(self) -> list[str]:
        """A warning per camera whose views left much of the image without the board."""
        return [
            f"{name}: the board never reached much of the image; show it near the edges and "
            "corners too, or the distortion there is a guess"
            for name, cam in zip(("cam0", "cam1"), self.cameras, strict=True)
            if cam.coverage < _LOW_COVERAGE
        ]

    def summary(self) -> list[str]:
        """Lines for people: RMS figures, baseline, row disagreement, rejected views."""
        lines = [
            f"views: {self.counts['views']}, board found in cam0 {self.counts['cam0_detected']}, "
            f"cam1 {self.counts['cam1_detected']}, both {self.counts['both_detected']}"
        ]
        for name, cam in zip(("cam0", "cam1"), self.cameras, strict=True):
            fx, fy, cx, cy = cam.camera.intrinsics
            sfx, sfy, scx, scy = cam.intrinsics_std[:4]
            lines.append(
                f"{name}: RMS {cam.rms_px:.3f} px over {len(cam.views)} views; "
                f"f = ({fx:.2f} +/- {sfx:.2f}, {fy:.2f} +/- {sfy:.2f}), "
                f"c = ({cx:.2f} +/- {scx:.2f}, {cy:.2f} +/- {scy:.2f}) (1 sigma); "
                f"board covered {cam.coverage:.0%} of the image"
            )
        lines += [f"warning: {warning}" for warning in self.coverage_warnings()]
        baseline = self.rig.baseline_m
        spread = (
            ""
            if self.baseline_std_m is None
            else f" +/- {100 * self.baseline_std_m / baseline:.3f} % (1 sigma)"
        )
        lines.append(
            f"stereo: RMS {self.stereo_rms_px:.3f} px over {len(self.stereo_views)} views; "
            f"baseline {baseline:.4f} m{spread}; intrinsics {self.refinement}"
        )
        if self.row_disagreement_px is None:
            lines.append("rectified row disagreement: n/a (only side-by-side rigs are rectified)")
        else:
            lines.append(f"rectified row disagreement: {self.row_disagreement_px:.3f} px RMS")
        for r in self.rejected:
            error = "" if r.error_px is None else f" ({r.error_px:.2f} px)"
            lines.append(f"rejected {r.name} [{r.stage}]{error}: {r.reason}")
        return lines

    def report(self) -> dict[str, Any]:
        """Plain JSON-serialisable report."""

        def camera(cam: CameraCalibration) -> dict[str, Any]:
            return {
                "intrinsics": list(cam.camera.intrinsics),
                "distortion_model": cam.camera.distortion_model,
                "distortion_coeffs": list(cam.camera.distortion),
                "resolution": list(cam.camera.resolution),
                "rms_px": cam.rms_px,
                "views": list(cam.views),
                "view_errors_px": list(cam.view_errors_px),
                "coverage": cam.coverage,
                "intrinsics_std": {  # None: the views leave it undetermined (no JSON inf)
                    name: value if np.isfinite(value) else None
                    for name, value in zip(INTRINSIC_NAMES, cam.intrinsics_std, strict=True)
                },
            }

        return {
            "board": self.board.spec(),
            "model": self.model,
            "counts": dict(self.counts),
            "cam0": camera(self.cameras[0]),
            "cam1": camera(self.cameras[1]),
            "stereo": {
                "rms_px": self.stereo_rms_px,
                "views": list(self.stereo_views),
                "view_errors_px": list(self.stereo_view_errors_px),
                "T_cam1_cam0": self.rig.T_cam1_cam0.tolist(),
                "baseline_m": self.rig.baseline_m,
                "baseline_std_m": self.baseline_std_m,
                "intrinsics": self.refinement,
            },
            "row_disagreement_px": self.row_disagreement_px,
            "rejected": [vars(r) for r in self.rejected],
            "warnings": [*self.warnings, *self.coverage_warnings()],
        }


def _reject_outliers(
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


FOCAL_DOUBT = 0.005
"""A camera whose focal length's 1-sigma deviation exceeds this share is warned about:
a 9x6 board 2-3 m from a 720x540 camera with f = 350 px gives about 0.6 %, 0.6-1.4 m
about 0.1 % (after the joint refinement)."""
BASELINE_DOUBT = 0.01
"""A baseline whose 1-sigma deviation exceeds this share is warned about."""


@contextlib.contextmanager
def _held(logger: logging.Logger, records: list[logging.LogRecord]) -> Iterator[None]:
    """Keep what ``logger`` is told meanwhile in ``records`` instead of saying it."""

    def hold(record: logging.LogRecord) -> bool:
        records.append(record)
        return False

    logger.addFilter(hold)
    try:
        yield
    finally:
        logger.removeFilter(hold)


def _release(records: list[logging.LogRecord]) -> None:
    """Say what :func:`_held` kept, in order."""
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
def _noted(logger: logging.Logger) -> Iterator[list[str]]:
    """The warnings ``logger`` says meanwhile (those :func:`_held` back only once released).

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


MARKER_TOLERANCE = 0.15
"""Markers measured this far (relative) from the stated ``MARKER_M`` are reported (warning)."""


def _check_marker_size(
    detections: Sequence[tuple[Detection | None, Detection | None]], board: Board
) -> None:
    """Warn when the images' ChArUco markers are not the size ``--board`` states.

    The measure (:func:`~lenspair.rectify.boards.measured_marker_m`) comes
    out a few per cent small, and a marker size a little off changes the
    calibration by less than its noise; the tolerance catches the typing
    mistakes (a third off and more) that bias the focal length unseen.
    """
    measured = [d.marker_m for pair in detections for d in pair if d and d.marker_m is not None]
    if board.marker_m is None or not measured:
        return
    median = float(np.median(measured))
    if abs(median / board.marker_m - 1.0) > MARKER_TOLERANCE:
        log.warning(
            "board: its markers measure about %.3g m on the images, %s states %.3g m "
            "(MARKER_M); a wrong marker size biases the focal length: check the printed board",
            median,
            board.spec(),
            board.marker_m,
        )


def calibrate_camera(
    detections: Sequence[Detection | None],
    board: Board,
    model: CalibrationModel,
    resolution: tuple[int, int],
    stage: str = "cam0",
    names: Sequence[str] | None = None,
    options: CalibrationOptions | None = None,
) -> tuple[CameraCalibration, list[RejectedView]]:
    """Calibrate one camera from its detections, rejecting outlier views.

    Args:
        detections: per view, the corners found or ``None``.
        board: the board (object points per corner id).
        model: ``pinhole-radtan`` or ``pinhole-equi``.
        resolution: image ``(width, height)``, pixels.
        stage: name used in errors and rejections (``cam0``/``cam1``).
        names: per-view names for rejections; ``view <i>`` by default.
        options: rejection settings.

    Raises:
        RectifyError: too few usable views, or OpenCV failed.

    """
    options = options or CalibrationOptions()
    names = names or [f"view {i}" for i in range(len(detections))]
    distortion_model = MODELS[parse_model(model)]
    objects = board.object_points()
    data = {
        i: (objects[d.ids], d.corners.astype(np.float64))
        for i, d in enumerate(detections)
        if d is not None
    }

    def fit(views: list[int]) -> tuple[tuple[CameraModel, np.ndarray, np.ndarray], np.ndarray]:
        camera, rvecs, tvecs = fit_camera([data[v] for v in views], distortion_model, resolution)
        errors = [view_error(camera, *data[v], rvecs[k], tvecs[k]) for k, v in enumerate(views)]
        return (camera, rvecs, tvecs), np.asarray(errors)

    try:
        (camera, rvecs, tvecs), views, errors, rejected = _reject_outliers(
            sorted(data), fit, stage, names, options
        )
    except RectifyError as exc:
        raise RectifyError(
            f"{stage}: {exc}" if not str(exc).startswith(stage) else str(exc)
        ) from None
    if (few_tilts := check_pose_spread(rvecs, tvecs, stage)) is not None:
        log.warning("%s", few_tilts)
    check_distinct_poses(rvecs, tvecs, stage, options.min_views)
    check_fit(camera, stage)
    residuals = np.concatenate(
        [project_rays(camera, data[v][0] @ cv2.Rodrigues(rvecs[k])[0].T + tvecs[k]) - data[v][1]
         for k, v in enumerate(views)]
    )  # fmt: skip
    corners = np.concatenate([data[v][1] for v in views])
    cells = np.floor(corners / resolution * _COVERAGE_GRID).astype(int)
    inside = np.all((cells >= 0) & (cells < _COVERAGE_GRID), axis=1)
    coverage = len({tuple(c) for c in cells[inside]}) / (_COVERAGE_GRID[0] * _COVERAGE_GRID[1])
    covariance = intrinsic_covariance(camera, [data[v] for v in views], rvecs, tvecs)
    calibration = CameraCalibration(
        camera, rms(residuals), tuple(views), tuple(float(e) for e in errors), rvecs, tvecs,
        coverage, covariance,
    )  # fmt: skip
    return calibration, rejected


def calibrate_from_detections(
    detections: Sequence[tuple[Detection | None, Detection | None]],
    board: Board,
    model: CalibrationModel,
    resolutions: tuple[tuple[int, int], tuple[int, int]],
    names: Sequence[str] | None = None,
    options: CalibrationOptions | None = None,
) -> CalibrationResult:
    """Calibrate a stereo rig from corners already detected (see the module docstring).

    Args:
        detections: per view, ``(cam0 detection or None, cam1 detection or None)``.
        board: the board seen.
        model: ``pinhole-radtan`` or ``pinhole-equi``.
        resolutions: ``(width, height)`` of cam0 and cam1 images, pixels.
        names: per-view names used when reporting rejected views.
        options: outlier rejection and rectification settings.

    Raises:
        RectifyError: too few usable views, OpenCV failure, implausible result.

    """
    with _noted(log) as warnings:
        result = _calibrate(detections, board, model, resolutions, names, options)
        _check_model(detections, board, model, resolutions, result)
    return dataclasses.replace(result, warnings=tuple(warnings))


MODEL_DOUBT_RMS_PX = 0.15
"""Above this RMS (px) a camera's fit is compared with the other lens model's."""

MODEL_DOUBT_RATIO = 0.5
"""... and doubted when the other model's RMS is below this share of it."""


def _check_model(
    detections: Sequence[tuple[Detection | None, Detection | None]],
    board: Board,
    model: CalibrationModel,
    resolutions: tuple[tuple[int, int], tuple[int, int]],
    result: CalibrationResult,
) -> None:
    """Warn when the other lens model fits a camera's views far better.

    A fisheye calibrated as ``pinhole-radtan`` gave a baseline 5 % short with
    RMS 0.46 px, and nothing said so: the RMS alone cannot tell (real corners
    are noisier than simulated ones), but the other model's fit of the same
    views can. Only a camera whose RMS is above :data:`MODEL_DOUBT_RMS_PX` is
    refitted (one calibration of its kept views, no outlier rounds).
    """
    other: CalibrationModel = "pinhole-radtan" if model == "pinhole-equi" else "pinhole-equi"
    plain = CalibrationOptions(max_rounds=0)
    for index, (stage, camera) in enumerate(zip(("cam0", "cam1"), result.cameras, strict=True)):
        if camera.rms_px <= MODEL_DOUBT_RMS_PX:
            continue
        kept = set(camera.views)
        views = [pair[index] if v in kept else None for v, pair in enumerate(detections)]
        try:
            with _held(log, []):  # its own warnings are of a fit not kept
                refit, _ = calibrate_camera(
                    views, board, other, resolutions[index], stage, None, plain
                )
        except RectifyError:
            continue
        if refit.rms_px < MODEL_DOUBT_RATIO * camera.rms_px:
            log.warning(
                "%s: %s fits its views with RMS %.3f px against %.3f px for %s: the lens "
                "model is likely wrong (--model %s), which biases focal length and baseline",
                stage,
                other,
                refit.rms_px,
                camera.rms_px,
                model,
                other,
            )


def _calibrate(
    detections: Sequence[tuple[Detection | None, Detection | None]],
    board: Board,
    model: CalibrationModel,
    resolutions: tuple[tuple[int, int], tuple[int, int]],
    names: Sequence[str] | None,
    options: CalibrationOptions | None,
) -> CalibrationResult:
    options = options or CalibrationOptions()
    names = list(names) if names is not None else [f"view {i}" for i in range(len(detections))]
    if len(names) != len(detections):
        raise ValueError(f"names: expected {len(detections)}, got {len(names)}")
    _check_marker_size(detections, board)

    def each_camera(
        settings: CalibrationOptions,
    ) -> tuple[
        list[CameraCalibration],
        list[RejectedView],
        dict[int, tuple[Detection, Detection]],
        list[logging.LogRecord],
    ]:
        # what each camera's calibration says is held back: only the pass that is kept
        # speaks (the fallback calibrates each camera again, over other views)
        said: list[logging.LogRecord] = []
        monos: list[CameraCalibration] = []
        dropped: list[RejectedView] = []
        try:
            with _held(log, said):
                for index, stage in enumerate(("cam0", "cam1")):
                    per_view = [pair[index] for pair in detections]
                    mono, left_out = calibrate_camera(
                        per_view, board, model, resolutions[index], stage, names, settings
                    )
                    monos.append(mono)
                    dropped += left_out
        except RectifyError:  # this pass ends the calibration: what it said is said
            _release(said)
            raise
        usable = set(monos[0].views) & set(monos[1].views)
        shared = {v: (d0, d1) for v, (d0, d1) in enumerate(detections) if v in usable and d0 and d1}
        return monos, dropped, shared, said

    monos, rejected, pairs, said = each_camera(options)
    if len(pairs) < options.min_views and options.max_rounds > 0:
        # each camera rejected other views, and too few are left to both: calibrated
        # without rejecting, as it would work (a factor near 1 on evenly noisy views)
        plain = dataclasses.replace(options, max_rounds=0)
        again = each_camera(plain)
        if len(again[2]) >= options.min_views:
            log.warning(
                "outlier rejection left %d views that both cameras kept (need %d): "
                "calibrating without rejecting any; a larger --outlier-factor rejects fewer",
                len(pairs),
                options.min_views,
            )
            monos, rejected, pairs, said = again  # the stereo step still rejects its outliers
    _release(said)
    cameras = (monos[0].camera, monos[1].camera)
    errors_px = [mono.view_errors_px for mono in monos]
    for warning in rms_balance_warnings(errors_px, cameras, options.outlier_floor_px):
        log.warning("%s", warning)  # a warning, not a refusal: cameras may differ
    if len(pairs) < options.min_views:  # the stereo step needs views the two cameras share
        raise RectifyError(
            f"stereo: the board was seen by both cameras at once in {len(pairs)} usable views, "
            f"need at least {options.min_views} (cam0 {len(monos[0].views)}, cam1 "
            f"{len(monos[1].views)} views on their own); record views where both see it"
        )
    matched, refused = match_views(pairs, board, cameras, options.pose_tolerance_deg)
    rejected += [RejectedView(v, names[v], "stereo", None, r) for v, r in refused.items()]

    Fit = tuple[np.ndarray, list[np.ndarray], np.ndarray, np.ndarray]

    def fit(views: list[int]) -> tuple[Fit, np.ndarray]:
        _, transform, rvecs, tvecs = fit_stereo([matched[v] for v in views], cameras)
        residuals = [
            stereo_residuals(matched[v], cameras, transform, rvecs[k], tvecs[k])
            for k, v in enumerate(views)
        ]
        return (transform, residuals, rvecs, tvecs), np.asarray([rms(r) for r in residuals])

    try:
        (transform, residuals, rvecs, tvecs), views, errors, dropped = _reject_outliers(
            sorted(matched), fit, "stereo", names, options
        )
    except RectifyError as exc:  # too few views: say why the others were refused
        if not refused:
            raise
        first = next(iter(refused.values()))
        raise RectifyError(
            f"{exc}; {len(refused)} views refused as the cameras' poses disagree (the first: "
            f"{first}): frames paired out of step, or a board spec or model that is wrong"
        ) from None
    rejected += dropped
    check_distinct_poses(rvecs, tvecs, "stereo", options.min_views, "seen by both cameras")
    stereo = [(matched[v], rvecs[k], tvecs[k]) for k, v in enumerate(views)]
    own = (monos[0].intrinsics_covariance, monos[1].intrinsics_covariance)
    fixed = rig_deviations(cameras, stereo, transform, own)
    baseline_std, refinement = fixed.baseline_m, "not refined with the rig: asked not to"
    if options.refine_jointly:
        monos, transform, residuals, baseline_std, refinement = _refine_jointly(
            stereo, monos, detections, board, transform, residuals, fixed
        )
    cameras = (monos[0].camera, monos[1].camera)
    errors = np.asarray([rms(r) for r in residuals])
    try:
        rig = StereoRig(cameras[0], cameras[1], transform)
    except ValueError as exc:
        raise RectifyError(f"stereo calibration gave an invalid transform: {exc}") from None
    rows: float | None = None
    if (layout := unsupported_layout(rig)) is None:
        rows = row_disagreement(
            StereoRectification.from_rig(rig, alpha=options.alpha),
            np.concatenate([matched[v][1] for v in views]),
            np.concatenate([matched[v][2] for v in views]),
        )
    else:  # a valid calibration all the same, for other tools: written, with the warning
        log.warning(
            "stereo: %s: the camchain is written, but capture-ingest rectifies side-by-side "
            "rigs only",
            layout,
        )
    counts = {
        "views": len(detections),
        "cam0_detected": sum(d0 is not None for d0, _ in detections),
        "cam1_detected": sum(d1 is not None for _, d1 in detections),
        "both_detected": sum(d0 is not None and d1 is not None for d0, d1 in detections),
    }
    _warn_uncertain(monos, rig.baseline_m, baseline_std)
    return CalibrationResult(
        rig, board, model, (monos[0], monos[1]), rms(np.concatenate(residuals)), tuple(views),
        tuple(float(e) for e in errors), rows, tuple(rejected), counts,
        baseline_std_m=baseline_std if np.isfinite(baseline_std) else None,
        refinement=refinement,
    )  # fmt: skip


JOINT_FIT_TOLERANCE = (1.2, 0.02)
"""Intrinsics refined with the rig are kept only when each camera's own views still fit
them within ``ratio * RMS + px`` of its own fit's RMS (both with poses solved per view)."""


def _refine_jointly(
    stereo: list[tuple[Points, np.ndarray, np.ndarray]],
    monos: Sequence[CameraCalibration],
    detections: Sequence[tuple[Detection | None, Detection | None]],
    board: Board,
    transform: np.ndarray,
    residuals: list[np.ndarray],
    fixed: RigDeviations,
) -> tuple[list[CameraCalibration], np.ndarray, list[np.ndarray], float, str]:
    """Refine both cameras' intrinsics with the rig over the stereo step's views, if better.

    Each camera calibrated alone has focal lengths off by its own noise; with
    the intrinsics then fixed, the stereo step turns the two cameras' different
    depth errors into baseline: 8 % off for boards 2-3 m away (0.2 % at 1 m),
    where ``cv2.stereoCalibrate`` refining everything together gives 0.4 %
    (0.06 %). But the refinement sees only the views both cameras saw: where
    most views were seen by one camera alone, each camera's own fit is the
    surer one. So the refinement is kept when its baseline deviation is the
    smaller of the two (``fixed``: the fixed-intrinsics fit's, intrinsics
    errors included, :func:`~lenspair.rectify.calib_fits.rig_deviations`),
    the refined rig rectifies, and each camera's own views still fit the
    refined intrinsics (:data:`JOINT_FIT_TOLERANCE`).

    Args:
        stereo: the stereo step's views and their cam0 board poses.
        monos: each camera's own calibration.
        detections: every view's corners, per camera.
        board: the board.
        transform: the fixed-intrinsics fit's cam0 -> cam1.
        residuals: its residuals per view.
        fixed: its deviations.

    Returns:
        The cameras' calibrations (refined or as given), the transform, the
        stereo residuals per view, the baseline's 1-sigma deviation and a line
        saying what was done.
    """
    cameras = (monos[0].camera, monos[1].camera)
    kept = list(monos), transform, residuals, fixed.baseline_m
    data = [item for item, _, _ in stereo]
    if not refinable(data, cameras):
        return *kept, "not refined with the rig: fisheye views with different corner counts"
    try:
        refined, joint, rvecs, tvecs = fit_stereo(data, cameras, refine=True)
    except RectifyError as exc:
        log.warning("stereo: intrinsics not refined with the rig (%s)", exc)
        return *kept, f"not refined with the rig: {exc}"
    try:  # a degenerate set (a board barely tilted) can refine into a rig nothing rectifies
        rig = StereoRig(refined[0], refined[1], joint)
        if (layout := unsupported_layout(rig)) is None:
            StereoRectification.from_rig(rig)
        elif unsupported_layout(StereoRig(cameras[0], cameras[1], transform)) is None:
            raise RectifyError(layout)  # the rig before refining was side by side
    except (ValueError, RectifyError) as exc:
        log.warning(
            "stereo: intrinsics not refined with the rig: the refined rig is unusable (%s)", exc
        )
        return *kept, "not refined with the rig: the refined rig was unusable"
    views = list(zip(data, rvecs, tvecs, strict=True))
    together = rig_deviations(refined, views, joint)
    spreads = (
        f"baseline +/- {_share(together.baseline_m, rig.baseline_m)} refined, "
        f"+/- {_share(fixed.baseline_m, float(np.linalg.norm(transform[:3, 3])))} with each "
        "camera's own"
    )
    if not together.baseline_m < fixed.baseline_m:  # views one camera saw alone weigh more
        return *kept, f"not refined with the rig: each camera's own fits are surer ({spreads})"
    objects = board.object_points()
    updated = []
    for index, (mono, camera) in enumerate(zip(monos, refined, strict=True)):
        found = [detections[v][index] for v in mono.views]
        points = [(objects[d.ids], d.corners.astype(np.float64)) for d in found if d is not None]
        corners = np.array([len(obj) for obj, _ in points])
        before = _pooled(refit_poses(mono.camera, points)[2], corners)
        rvecs_own, tvecs_own, errors = refit_poses(camera, points)
        after = _pooled(errors, corners)
        ratio, extra = JOINT_FIT_TOLERANCE
        if after > ratio * before + extra:
            log.warning(
                "cam%d: the intrinsics refined with the rig fit its own %d views with RMS "
                "%.3f px against %.3f px: kept each camera's own fit (views seen by one camera "
                "alone disagree with those both saw)",
                index,
                len(points),
                after,
                before,
            )
            return *kept, "not refined with the rig: a camera's own views disagree"
        updated.append((camera, errors, rvecs_own, tvecs_own, after))
    residuals = [stereo_residuals(item, refined, joint, r, t) for item, r, t in views]
    calibrations = [
        dataclasses.replace(
            mono,
            camera=camera,
            rms_px=after,
            view_errors_px=tuple(float(e) for e in errors),
            rvecs=rvecs_own,
            tvecs=tvecs_own,
            intrinsics_covariance=together.intrinsics(index),
        )
        for index, (mono, (camera, errors, rvecs_own, tvecs_own, after)) in enumerate(
            zip(monos, updated, strict=True)
        )
    ]
    return calibrations, joint, residuals, together.baseline_m, f"refined with the rig ({spreads})"


def _share(deviation: float, value: float) -> str:
    """A deviation as a percentage of ``value``: ``0.36 %``."""
    return f"{100 * deviation / value:.3g} %" if np.isfinite(deviation) else "undetermined"


def _pooled(view_errors: np.ndarray, corners: np.ndarray) -> float:
    """RMS over all corners from per-view RMS errors and corner counts."""
    return float(np.sqrt(np.sum(corners * view_errors**2) / np.sum(corners)))


def _warn_uncertain(
    monos: Sequence[CameraCalibration], baseline_m: float, baseline_std: float
) -> None:
    """Warn of a focal length or baseline the corners determine poorly."""
    for stage, mono in zip(("cam0", "cam1"), monos, strict=True):
        if mono.focal_std > FOCAL_DOUBT:
            log.warning(
                "%s: the focal length is known to +/- %.2f %% only (1 sigma, from the corner "
                "residuals over %d views); depth and baseline inherit it: show the board "
                "nearer, so that it fills more of the image, and tilted in several directions",
                stage,
                100 * mono.focal_std,
                len(mono.views),
            )
    if baseline_std > BASELINE_DOUBT * baseline_m:
        log.warning(
            "stereo: the baseline is known to +/- %.2f %% only (1 sigma); every depth scales "
            "with it: show the board nearer, to both cameras at once",
            100 * baseline_std / baseline_m,
        )


def detect_views(
    views: Sequence[tuple[np.ndarray, np.ndarray]], board: Board
) -> list[tuple[Detection | None, Detection | None]]:
    """Detect the board in each image of each stereo view (with a progress bar)."""
    return [
        (detect_corners(image0, board), detect_corners(image1, board))
        for image0, image1 in progress(views, "detecting board", total=len(views), unit="view")
    ]


def calibrate_stereo(
    views: Sequence[tuple[np.ndarray, np.ndarray]],
    board: Board,
    model: CalibrationModel,
    names: Sequence[str] | None = None,
    options: CalibrationOptions | None = None,
) -> CalibrationResult:
    """Calibrate a stereo rig from board images.

    Args:
        views: ``(cam0 image, cam1 image)`` pairs taken at the same instant;
            ``uint8``/``uint16``, ``(H, W)`` or ``(H, W, 3)``.
        board: the board seen.
        model: ``pinhole-radtan`` or ``pinhole-equi``.
        names: per-view names used when reporting rejected views.
        options: outlier rejection and rectification settings.

    """
    if not views:
        raise RectifyError("calibration: no views given")
    names = list(names) if names is not None else [f"view {i}" for i in range(len(views))]
    resolutions = (
        (int(views[0][0].shape[1]), int(views[0][0].shape[0])),
        (int(views[0][1].shape[1]), int(views[0][1].shape[0])),
    )
    for name, pair in zip(names, views, strict=False):
        for camera, image, size in zip(("cam0", "cam1"), pair, resolutions, strict=True):
            if (image.shape[1], image.shape[0]) != size:
                raise RectifyError(
                    f"{name}: the {camera} image is {image.shape[1]}x{image.shape[0]}, the first "
                    f"view's {size[0]}x{size[1]}: a camera's views must all have one size"
                )
    return calibrate_from_detections(
        detect_views(views, board), board, model, resolutions, names, options
    )
