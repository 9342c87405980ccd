"""What restore refuses about its input and OUT before it runs, and frames the network cannot take.

:func:`check_input` is everything that can be refused without the model
(``restore`` calls it before it loads one): an input lenspair does not read,
a topic the bag lacks, a folder without images, an OUT inside the input
(:func:`check_apart`) or not empty. :func:`frame_problem` says why a frame
cannot go through the network (its channels, its size).
"""

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from lenspair.capture.bag_frames import BagOverview, bag_overview, bag_topics
from lenspair.capture.bagwrite import output_bag_path
from lenspair.capture.frames import InputKind, detect_input, frame_files
from lenspair.capture.rigfile import CameraName
from lenspair.core.fsutil import inside_refusal
from lenspair.model.errors import ModelError
from lenspair.model.inference.report import RESTORE_LOCK
from lenspair.model.inference.restore_options import RestoreOptions, resolve_cameras
from lenspair.model.networks.padding import MIN_SIDE


def image_channels(image: np.ndarray) -> int:
    """Channels of an HxW (one) or HxWxC image."""
    return 1 if image.ndim == 2 else int(image.shape[2])


def frame_problem(name: str, image: np.ndarray, channels: int) -> str | None:
    """Why the network cannot take ``image`` (``name`` leads the line), or None.

    Channels other than the network's ``channels`` (no silent conversion), or
    a side under the network's minimum.
    """
    if image_channels(image) != channels:
        return (
            f"{name}: {image_channels(image)} channel(s) but the network takes {channels}; "
            "convert the images or use a network trained on them"
        )
    if min(image.shape[:2]) < MIN_SIDE:
        return (
            f"{name}: {image.shape[1]}x{image.shape[0]} pixels, smaller than the network's "
            f"{MIN_SIDE}x{MIN_SIDE} minimum"
        )
    return None


def check_out_dir(out_dir: Path, resume: bool) -> None:
    """Refuse a non-empty OUT unless resuming.

    Raises:
        ModelError: OUT is a file, or holds files and ``resume`` is False.
    """
    if out_dir.exists() and not out_dir.is_dir():
        raise ModelError(f"--out {out_dir}: exists and is not a folder")
    if not resume and holds_output(out_dir):
        raise ModelError(
            f"--out {out_dir}: not empty; pass --resume to continue a run or choose a new folder"
        )


def holds_output(out_dir: Path) -> bool:
    """Whether the folder OUT holds anything but a restore's lock file.

    The lock a run killed before its first report left (or that the running
    run holds) is no output.
    """
    return out_dir.is_dir() and any(p.name != RESTORE_LOCK for p in out_dir.iterdir())


def check_apart(input_path: Path, kind: InputKind, out_dir: Path) -> None:
    """Refuse an OUT that would overwrite the input or be read back as input.

    Outputs keep the input's names, so OUT may not be an input folder (a
    folder of images, a recording, a ROS 2 bag folder) or lie inside it (a
    rerun would restore its own outputs, or write into the bag), and the
    output of a single image or bag may not land on the input itself (OUT =
    the folder that holds it: a bag is written afresh, which would delete the
    input).

    Raises:
        ModelError: naming OUT and the input.
    """
    # a folder, a recording, a ROS 2 bag
    why = "outputs keep the input's names"
    if (problem := inside_refusal(out_dir, input_path, "the input", why)) is not None:
        raise ModelError(problem)
    if kind in ("folder", "euroc", "folders"):
        return
    bag = kind in ("rosbag1", "rosbag2")
    written = output_bag_path(input_path, out_dir) if bag else out_dir / input_path.name
    if written.resolve() == input_path.resolve():
        raise ModelError(
            f"--out {out_dir}: the folder that holds {input_path}; the output keeps its name "
            "and would replace it, so choose another folder"
        )
    if input_path.resolve().is_relative_to(written.resolve()):  # a bare .db3/.mcap
        raise ModelError(
            f"--out {out_dir}: the restored bag is written as the folder {written}, which "
            f"holds the input {input_path} and would replace it, so choose another folder"
        )


@dataclass(frozen=True)
class CheckedInput:
    """What :func:`check_input` found: the kind, the options that apply, the frames.

    Attributes:
        kind: image, folder, EuRoC/ASL recording or bag.
        options: the options, with those meaning nothing for images reset.
        cameras: the cameras to restore (none for images).
        files: the image files (none for bags, read as they stream).
        overview: a bag's :class:`~lenspair.capture.bag_frames.BagOverview`,
            read once here (a bag cut short is scanned whole by each opening);
            None for other inputs.
    """

    kind: InputKind
    options: RestoreOptions
    cameras: tuple[CameraName, ...]
    files: list[Path]
    overview: BagOverview | None = None


def check_input(input_path: Path, out_dir: Path, options: RestoreOptions) -> CheckedInput:
    """Everything about the input and OUT that can be refused without the model.

    ``restore`` calls it before it loads the model, so that a mistyped path,
    a topic the bag lacks, a folder without images or a non-empty OUT is the
    only line said.

    Raises:
        CaptureError: no such input, not one lenspair reads, a topic or camera it lacks.
        ModelError: no images, ``out_dir`` inside the input (:func:`check_apart`) or
            not empty without ``options.resume``.
    """
    kind = detect_input(input_path)
    check_apart(input_path, kind, out_dir)
    cameras = resolve_cameras(input_path, kind, options.camera, options.topics)
    if kind in ("image", "folder"):
        # an image or a folder of them has no cameras nor topics: none decides its bytes
        options = replace(options, camera="auto", suffix="", topics=None)
        cameras = ()
    bag = kind in ("rosbag1", "rosbag2")
    if bag and options.suffix:
        check_suffix_free(input_path, cameras, options)
    overview = bag_overview(input_path, cameras, options.topics) if bag else None
    if overview is not None and (empty := overview.nothing_to_read(input_path)):
        raise ModelError(f"{empty}: nothing to restore")
    files = [] if bag else frame_files(input_path, kind, cameras)
    if not bag and not files:
        # Refused before OUT is made: an empty run is a mistyped path, not a result.
        raise ModelError(f"{input_path}: no images to restore")
    check_out_dir(out_dir, options.resume)
    return CheckedInput(kind, options, cameras, files, overview)


def check_suffix_free(bag: Path, cameras: tuple[CameraName, ...], options: RestoreOptions) -> None:
    """Refuse ``--suffix`` where ``<topic><suffix>`` is already one of the bag's topics.

    A bag restored before with the same suffix (or recorded from a robot that
    publishes restored frames) holds that topic already; writing the restored
    frames into it would mix two runs' frames on one topic.

    Raises:
        ModelError: names the bag, the topic and what to do.
    """
    existing, named = bag_topics(bag, options.topics)
    taken = sorted(
        topic + options.suffix
        for topic, camera in named.items()
        if camera in cameras and topic + options.suffix in existing
    )
    if taken:
        raise ModelError(
            f"{bag}: topic {taken[0]} is in the bag already; --suffix {options.suffix} would "
            "write restored frames into it: choose another --suffix, or restore without one "
            "to replace the camera's frames"
        )
