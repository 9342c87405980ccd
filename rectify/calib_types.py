"""What a stereo calibration takes and gives: lens model names, options, results.

:func:`~lenspair.rectify.calibration.calibrate_stereo` takes a lens model
name (:func:`parse_model`) and :class:`CalibrationOptions`, and returns a
:class:`CalibrationResult`: the rig, each camera's own
:class:`CameraCalibration`, the stereo step's figures and every
:class:`RejectedView`, with the lines and the JSON report made of them.
"""

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from lenspair.rectify.boards import Board
from lenspair.rectify.calib_uncertainty import INTRINSIC_NAMES, deviations
from lenspair.rectify.errors import RectifyError
from lenspair.rectify.rig import CameraModel, DistortionModel, StereoRig

CalibrationModel = Literal["pinhole-radtan", "pinhole-equi"]
MODELS: dict[str, DistortionModel] = {"pinhole-radtan": "radtan", "pinhole-equi": "equidistant"}
_LOW_COVERAGE = 0.5


def parse_model(name: str) -> CalibrationModel:
    """Check a ``--model`` name; raises ``RectifyError`` listing the valid ones."""
    if name not in MODELS:
        raise RectifyError(f"model: unknown {name!r}; valid: {', '.join(MODELS)}")
    return name  # type: ignore[return-value]


@dataclass(frozen=True)
class CalibrationOptions:
    """Knobs of :func:`~lenspair.rectify.calibration.calibrate_stereo`.

    Attributes:
        outlier_factor: reject views above this multiple of the median view error.
        outlier_floor_px: never reject a view whose error is below this (pixels).
        max_rounds: rejection rounds per step.
        min_views: fewest views a step may be left with.
        pose_tolerance_deg: a view whose cam0 -> cam1 rotation (from the two
            board poses) differs more than this from the consensus is rejected.
        alpha: rectification ``alpha`` used for the row-disagreement figure.
        refine_jointly: refine both cameras' intrinsics with the rig after the
            stereo step (:func:`~lenspair.rectify.calib_refine.refine_jointly`);
            False keeps each camera's own.

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
            distortion coefficients (:data:`~lenspair.rectify.calib_uncertainty.INTRINSIC_NAMES`)
            from the corner residuals
            (:func:`~lenspair.rectify.calib_uncertainty.intrinsic_covariance`).

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
        """1-sigma deviations, in :data:`INTRINSIC_NAMES` order."""
        return tuple(float(d) for d in deviations(self.intrinsics_covariance))

    @property
    def focal_std(self) -> float:
        """The larger 1-sigma deviation of ``fx`` and ``fy``, as a share of the focal length."""
        fx, fy = self.camera.intrinsics[:2]
        return max(self.intrinsics_std[0] / fx, self.intrinsics_std[1] / fy)


@dataclass(frozen=True, eq=False)
class CalibrationResult:
    """Everything :func:`~lenspair.rectify.calibration.calibrate_stereo` found out.

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
