"""Per-frame work of ``capture-ingest``, runnable in worker processes.

Everything a worker needs travels once, in a picklable :class:`Context`
(:func:`set_context` is the pool initializer); tasks are small
(:class:`SampleTask`, :class:`FrameTask`: two frame references each) and
results are plain values. The work on a frame depends only on its inputs and
the context, never on which process runs it or in what order, so outputs
are identical for any number of workers. Per-frame problems (unreadable
image, wrong size, failed registration) become rejected records, never
exceptions.
"""

import functools
import json
import signal
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from lenspair.capture.ingested import PairRecord
from lenspair.capture.recording import FrameRef, load_frame
from lenspair.capture.rigfile import CameraName
from lenspair.core.bitdepth import widen
from lenspair.core.errors import LenspairError
from lenspair.core.fsutil import sha256_bytes, sha256_file
from lenspair.core.imagewrite import write_image
from lenspair.core.orphans import end_with_parent
from lenspair.core.quality import (
    exposure_fractions,
    exposure_ratio,
    laplacian_variance,
    to_grey,
)
from lenspair.core.sourcefiles import source_fingerprint
from lenspair.rectify.crop import Crop
from lenspair.rectify.rectification import StereoRectification
from lenspair.rectify.registration import EstimationParams, VerifyParams, match_views, to_u8
from lenspair.rectify.remap import RemapGrid, apply, input_map, shifted
from lenspair.rectify.verification import measure_shift, verify_pair

OUTPUT_KINDS = ("input", "target", "mask")


@dataclass(frozen=True, eq=False)
class Context:
    """What every frame's work shares: cameras, rectification, maps, thresholds, output folder.

    Attributes:
        out_dir: ``OUT/<recording_id>``.
        obstructed: the obstructed camera; ``clean`` is the other.
        clean: the clean camera.
        rectification: the rig's rectification (computed once).
        verify: per-frame verification thresholds.
        rectified_maps: full-grid rectification maps ``(map_x, map_y)`` of the
            obstructed and clean view (for the homography samples only; emptied
            by :meth:`with_maps`, so that workers of the frame stage do not
            receive them).
        valid_obstructed: rectified pixels of the obstructed view with data.
        valid_clean: rectified pixels of the clean view with data (both emptied
            by :meth:`with_maps` too).
        crop: the output crop, once chosen.
        input_grid: composed map of the obstructed view (rectify + crop).
        target_grid: composed map of the clean view (rectify + homography +
            crop), with a margin for per-frame shifts.
        bits: the bits each camera's 16-bit frames use
            (:func:`lenspair.core.bitdepth.significant_bits`; a camera not
            named: 16); each camera's frames are read through
            :func:`lenspair.core.bitdepth.widen` with its own (:meth:`bits_of`).

    """

    out_dir: Path
    obstructed: CameraName
    clean: CameraName
    rectification: StereoRectification
    verify: VerifyParams
    rectified_maps: tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
    valid_obstructed: np.ndarray = field(repr=False)
    valid_clean: np.ndarray = field(repr=False)
    crop: Crop | None = None
    input_grid: RemapGrid | None = None
    target_grid: RemapGrid | None = None
    bits: dict[CameraName, int] = field(default_factory=dict)

    @classmethod
    def build(
        cls,
        out_dir: Path,
        obstructed: CameraName,
        rectification: StereoRectification,
        verify: VerifyParams,
        bits: dict[CameraName, int] | None = None,
    ) -> "Context":
        """Context before the crop is known (enough for :func:`sample`)."""
        clean: CameraName = "cam0" if obstructed == "cam1" else "cam1"
        maps = (rectification.maps(obstructed), rectification.maps(clean))

        def valid(camera: CameraName, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
            width, height = rectification.rig.camera(camera).resolution
            return np.asarray(
                (map_x >= 0) & (map_x <= width - 1) & (map_y >= 0) & (map_y <= height - 1)
            )

        return cls(
            out_dir,
            obstructed,
            clean,
            rectification,
            verify,
            maps,
            valid(obstructed, *maps[0]),
            valid(clean, *maps[1]),
            bits=dict(bits or {}),
        )

    def rectified_to_raw_obstructed(self, points: np.ndarray) -> np.ndarray:
        """Rectified -> raw pixel coordinates of the obstructed view, ``(N, 2)`` float64."""
        return self.rectification.rectified_to_raw(self.obstructed, points).astype(np.float64)

    def rectified_to_raw_clean(self, points: np.ndarray) -> np.ndarray:
        """Rectified -> raw pixel coordinates of the clean view, ``(N, 2)`` float64."""
        return self.rectification.rectified_to_raw(self.clean, points).astype(np.float64)

    def with_maps(self, crop: Crop, target_grid: RemapGrid) -> "Context":
        """The context with the crop and both composed maps."""
        grid = input_map(self.rectified_to_raw_obstructed, crop)
        empty = np.zeros((0, 0), np.float32)
        return replace(  # the full-grid maps serve the samples only: workers need not get them
            self,
            rectified_maps=((empty, empty), (empty, empty)),
            valid_obstructed=empty.astype(bool),
            valid_clean=empty.astype(bool),
            crop=crop,
            input_grid=grid,
            target_grid=target_grid,
        )

    def bits_of(self, camera: CameraName) -> int:
        """The bits ``camera``'s 16-bit frames use (16: taken as they are)."""
        return self.bits.get(camera, 16)

    def raw_size(self, camera: CameraName) -> tuple[int, int]:
        """``(width, height)`` of ``camera``'s images according to the calibration."""
        return self.rectification.rig.camera(camera).resolution


_CONTEXT: Context | None = None


def set_context(context: Context) -> None:
    """Install the shared context in this process."""
    global _CONTEXT
    _CONTEXT = context


def init_worker(context: Context, parent_pid: int | None = None) -> None:
    """Pool initializer: end with the parent, ignore Ctrl-C, install the context, one OpenCV thread.

    A worker must not outlive the ingest that started it: after a ``kill -9``
    of the parent, orphaned workers would go on writing frames nobody
    records. :func:`end_with_parent` ties each worker's life to ``parent_pid``.
    The pool already uses every core it was given; OpenCV's own threads
    would only compete with it.
    """
    if parent_pid is not None:
        end_with_parent(parent_pid)
    # Ctrl-C reaches the whole process group: the parent stops the pool; a
    # worker interrupted inside the pool's queue could leave the parent waiting
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    set_context(context)
    cv2.setNumThreads(1)


def _context() -> Context:
    if _CONTEXT is None:
        raise RuntimeError("ingest worker used before set_context()")
    return _CONTEXT


def size_problem(image: np.ndarray, frame: FrameRef, expected: tuple[int, int]) -> str | None:
    """``size mismatch: ...`` when ``image`` is not ``expected`` ``(width, height)``, else None."""
    height, width = image.shape[:2]
    if (width, height) == tuple(expected):
        return None
    return (
        f"size mismatch: {frame.describe()} is {width}x{height} px, the calibration says "
        f"{expected[0]}x{expected[1]}"
    )


def _load_pair(
    obstructed: FrameRef, clean: FrameRef, context: Context
) -> tuple[np.ndarray, np.ndarray] | str:
    """Both raw images, or the reason they cannot be used."""
    images = []
    for frame, camera, role in (
        (obstructed, context.obstructed, "input"),
        (clean, context.clean, "clean"),
    ):
        try:
            image = load_frame(frame)
        except LenspairError as exc:
            return f"cannot read {role} frame: {exc}"
        bits = context.bits_of(camera)
        top = (1 << bits) - 1
        if bits < 16 and image.dtype == np.uint16 and int(image.max()) > top:
            # the frames sampled said otherwise: scaling this one would clip it
            return (
                f"values above {camera}'s {bits} bits ({int(image.max())} > {top} "
                f"in {frame.describe()})"
            )
        image = widen(image, bits)
        problem = size_problem(image, frame, context.raw_size(camera))
        if problem is not None:
            return problem
        images.append(image)
    first, second = images
    if first.dtype != second.dtype or first.ndim != second.ndim:
        return (
            f"format mismatch: {obstructed.describe()} is {first.dtype} {first.shape}, "
            f"{clean.describe()} is {second.dtype} {second.shape}"
        )
    return first, second


@dataclass(frozen=True)
class SampleTask:
    """A frame pair sampled for the homography."""

    obstructed: FrameRef
    clean: FrameRef
    estimation: EstimationParams


@dataclass(frozen=True)
class SampleResult:
    """Rectified grey views of a sampled pair and their feature matches.

    Attributes:
        t_ns: obstructed timestamp.
        problem: why the pair cannot be used (then everything else is empty).
        obstructed: rectified grey view, ``uint8 (H, W)``.
        clean: rectified grey view, ``uint8 (H, W)``.
        matches: ``(clean_points, obstructed_points)`` in rectified px.

    """

    t_ns: int
    problem: str | None = None
    obstructed: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), np.uint8))
    clean: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), np.uint8))
    matches: tuple[np.ndarray, np.ndarray] = (np.zeros((0, 2)), np.zeros((0, 2)))


def sample(task: SampleTask) -> SampleResult:
    """Load, rectify and match one sampled pair."""
    context = _context()
    loaded = _load_pair(task.obstructed, task.clean, context)
    if isinstance(loaded, str):
        return SampleResult(task.obstructed.t_ns, loaded)
    views = []
    for raw, (map_x, map_y) in zip(loaded, context.rectified_maps, strict=True):
        views.append(to_grey(np.asarray(cv2.remap(raw, map_x, map_y, cv2.INTER_LINEAR))))
    obstructed, clean = views
    matches = match_views(
        obstructed, clean, context.valid_obstructed, context.valid_clean, task.estimation
    )
    return SampleResult(task.obstructed.t_ns, None, to_u8(obstructed), to_u8(clean), matches)


def content_id(frame: FrameRef) -> str:
    """Checksum of an image file's bytes; for bag frames, the message's location and bag stat."""
    if frame.in_bag:
        return json.dumps(_identity(frame))
    try:
        return sha256_file(frame.source)
    except OSError as exc:
        return f"unreadable: {exc.strerror}"


def _identity(frame: FrameRef) -> list[object]:
    """The frame's place in its recording and its file's size and time, whatever the path.

    The file's folder is left out: the same recording given as ``rec`` from
    one folder and ``../rec`` from another (or moved with its times kept)
    resumes instead of doing every frame. Size and modification time, not
    the bytes: a rerun with nothing to do reads no frame (a recording can be
    tens of GB), and ``chmod`` or a move (which change the inode's change
    time) keep the work done. A frame replaced by one of the same size with
    its time set back is not noticed, unless the homography sampled it (those
    are hashed).

    A ROS 2 bag folder is stated file by file
    (:func:`lenspair.core.sourcefiles.source_fingerprint`): the folder's own
    time stays when a storage file in it is rewritten in place.
    """
    place = [frame.camera, frame.t_ns, frame.source.name, frame.topic, frame.log_time_ns]
    place.append(frame.occurrence)
    if frame.in_bag and frame.source.is_dir():
        return [*place, source_fingerprint(frame.source)]
    try:
        stat = frame.source.stat()
        return [*place, stat.st_size, stat.st_mtime_ns]
    except OSError:
        return [*place, None, None]


@dataclass(frozen=True)
class FrameTask:
    """One paired frame to ingest.

    Attributes:
        obstructed: the obstructed camera's frame (its timestamp names the outputs).
        clean: the clean camera's frame.
        state: fingerprint of everything shared that the outputs depend on.
        warning: a recording problem about this frame that does not stop it.

    """

    obstructed: FrameRef
    clean: FrameRef
    state: str
    warning: str | None = None

    @functools.cached_property
    def key(self) -> str:
        """Hash of everything this frame's outputs depend on (resume check; read once)."""
        content = [self.state, self.warning, _identity(self.obstructed), _identity(self.clean)]
        return sha256_bytes(json.dumps(content, default=str).encode("utf-8"))


def output_paths(out_dir: Path, t_ns: int) -> dict[str, Path]:
    """``input``/``target``/``mask`` file paths of a frame."""
    return {kind: out_dir / kind / f"{t_ns}.png" for kind in OUTPUT_KINDS}


def remove_outputs(out_dir: Path, t_ns: int, keep: tuple[str, ...] = ()) -> None:
    """Delete a frame's output files left by an earlier run (except ``keep``)."""
    for kind, path in output_paths(out_dir, t_ns).items():
        if kind not in keep:
            path.unlink(missing_ok=True)


def _figure(value: float | None) -> float | None:
    return None if value is None else round(float(value), 6)


def process(task: FrameTask) -> PairRecord:
    """Remap, verify, refine and write one frame pair; returns its record."""
    context = _context()
    assert context.input_grid is not None and context.target_grid is not None
    t_ns, t_clean = task.obstructed.t_ns, task.clean.t_ns
    base = PairRecord(t_ns=t_ns, status="rejected", t_clean_ns=t_clean)
    loaded = _load_pair(task.obstructed, task.clean, context)
    if isinstance(loaded, str):
        remove_outputs(context.out_dir, t_ns)
        return replace(base, reason=loaded)
    raw_obstructed, raw_clean = loaded
    params = context.verify
    image_in = apply(raw_obstructed, context.input_grid)
    image_target = apply(raw_clean, shifted(context.target_grid, 0.0, 0.0))
    gray_in, gray_target = to_grey(image_in), to_grey(image_target)
    shift = measure_shift(gray_in, gray_target, params)
    notes = [task.warning] if task.warning else []
    if shift.failure is None and shift.magnitude > params.refine_px:
        image_target = apply(raw_clean, shifted(context.target_grid, shift.dx, shift.dy))
        gray_target = to_grey(image_target)
        notes.append(f"refined: target shifted by ({shift.dx:.2f}, {shift.dy:.2f}) px")
    saturated, black = exposure_fractions(image_target)
    sharpness = laplacian_variance(gray_target)
    figures = replace(
        base,
        sharpness=_figure(sharpness),
        saturated=_figure(saturated),
        black=_figure(black),
    )
    if shift.failure is not None:
        remove_outputs(context.out_dir, t_ns)
        residual = shift.magnitude if shift.correlation > 0 else None
        return replace(figures, reason=shift.failure, residual_px=_figure(residual))
    verdict = verify_pair(gray_in, gray_target, shift.anomaly, params)
    figures = replace(
        figures,
        residual_px=_figure(verdict.residual_px),
        photometric_residual=_figure(verdict.photometric_residual),
        inliers=verdict.inliers,
        mask_fraction=_figure(verdict.mask_fraction),
        exposure_ratio=_figure(exposure_ratio(gray_in, gray_target, verdict.mask)),
    )
    if verdict.reason is not None:
        remove_outputs(context.out_dir, t_ns)
        return replace(figures, reason=verdict.reason)
    paths = output_paths(context.out_dir, t_ns)
    outputs = {"input": image_in, "target": image_target}
    if verdict.mask.any():
        outputs["mask"] = np.where(verdict.mask, 255, 0).astype(np.uint8)
    for kind, image in outputs.items():
        write_image(paths[kind], image)
    remove_outputs(context.out_dir, t_ns, keep=tuple(outputs))
    return replace(
        figures,
        status="kept",
        reason="; ".join(notes) or None,
        files={kind: f"{kind}/{t_ns}.png" for kind in outputs},
        sha256={kind: sha256_file(paths[kind]) for kind in outputs},
    )
