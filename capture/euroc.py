"""EuRoC/ASL folders: ``mav0/cam{0,1}/data.csv`` + ``data/<t_ns>.png`` + ``sensor.yaml``.

``data.csv`` (the ASL dataset format)::

    #timestamp [ns],filename
    1403636579763555584,1403636579763555584.png

The header line may lack its ``#``. Rows are read in file order (that order
is the recording order used to spot timestamps going back). A row that cannot
be parsed, or that names a file missing from ``data/``, is recorded as a
problem; so is an image in ``data/`` that no row lists. Without ``data.csv``
the file names give the timestamps.
"""

import os
from collections.abc import Sequence
from pathlib import Path

from lenspair.capture.errors import CaptureError
from lenspair.capture.folders import image_files, list_image_folder, timestamp_from_name
from lenspair.capture.recording_types import (
    CAMERAS,
    FrameProblem,
    FrameRef,
    Recording,
    order_frames,
    recording_id_for,
)
from lenspair.capture.rigfile import CameraName

DATA_CSV = "data.csv"
SENSOR_YAML = "sensor.yaml"


def find_euroc_root(path: Path) -> Path | None:
    """The folder holding ``cam0/``/``cam1/``: ``path/mav0``, ``path`` itself, or None."""
    path = Path(path)
    for root in (path / "mav0", path):
        if any((root / camera).is_dir() for camera in CAMERAS):
            return root
    return None


def read_euroc(path: Path, root: Path, cameras: Sequence[CameraName] = CAMERAS) -> Recording:
    """List an EuRoC/ASL recording.

    Args:
        path: the path the user gave (recording id and messages use it).
        root: the folder holding ``cam0/`` and ``cam1/`` (see
            :func:`find_euroc_root`).
        cameras: the cameras to list (a command restoring or judging one
            camera reads a recording that holds only that one).

    Raises:
        CaptureError: a camera folder is missing, has neither ``data.csv``
            nor ``data/``, or has no usable frame.
    """
    problems: list[FrameProblem] = []
    frames: dict[CameraName, list[FrameRef]] = {}
    sensor_files: dict[CameraName, Path] = {}
    for camera in cameras:
        camera_dir = root / camera
        if not camera_dir.is_dir():
            raise CaptureError(f"{camera_dir}: missing camera folder ({camera})")
        frames[camera] = _list_camera(camera, camera_dir, problems)
        if (camera_dir / SENSOR_YAML).is_file():
            sensor_files[camera] = camera_dir / SENSOR_YAML
    return Recording(
        Path(path), recording_id_for(path), "euroc", frames, problems, sensor_files=sensor_files
    )


def _list_camera(
    camera: CameraName, camera_dir: Path, problems: list[FrameProblem]
) -> list[FrameRef]:
    data_dir = camera_dir / "data"
    csv_path = camera_dir / DATA_CSV
    if not csv_path.is_file():
        if not data_dir.is_dir():
            raise CaptureError(f"{camera_dir}: neither {DATA_CSV} nor data/ found ({camera})")
        return list_image_folder(camera, data_dir, problems)
    frames, named = read_data_csv(camera, csv_path, data_dir, problems)
    if data_dir.is_dir():
        listed = {frame.t_ns for frame in frames}
        for file in image_files(data_dir):
            t_ns = timestamp_from_name(file.name)
            # a listed frame's companion (<t>_depth.png beside <t>.png) is no frame lost
            if file.name not in named and t_ns not in listed:
                # its name is its timestamp: pairs.jsonl names it
                problems.append(
                    FrameProblem(
                        camera, t_ns, str(file), f"image not listed in data.csv ({csv_path})"
                    )
                )
    return order_frames(camera, frames, problems)


def name_in_folder(folder: Path, name: str) -> str | None:
    """``name`` (relative to ``folder``, or absolute) as a path inside ``folder``, or None.

    Lexical, as a recording is copied: ``a/../b.png`` is ``b.png``, an absolute
    path under ``folder`` becomes relative to it, and one that leaves ``folder``
    (``../x.png``, another folder's absolute path) is None. Symbolic links are
    not followed: a ``data/`` folder of links to elsewhere is still the folder.
    An absolute name outside ``folder`` as written is tried once more with
    links resolved on both sides: the recording opened through a linked
    parent (``/mnt/link/rec``) while ``data.csv`` names the real path
    (``/data/rec/...``), or the other way round.
    """
    root = os.path.abspath(folder)
    inside = _relative_inside(root, os.path.abspath(os.path.join(root, name)))
    if inside is None and os.path.isabs(name):
        inside = _relative_inside(os.path.realpath(root), os.path.realpath(name))
    return inside


def _relative_inside(root: str, target: str) -> str | None:
    """``target`` relative to ``root`` when it lies strictly inside it, else None."""
    if os.path.commonpath([root, target]) != root or target == root:
        return None
    return Path(os.path.relpath(target, root)).as_posix()


def read_data_csv(
    camera: CameraName, csv_path: Path, data_dir: Path, problems: list[FrameProblem]
) -> tuple[list[FrameRef], set[str]]:
    """Frames listed in one ``data.csv``, in row order (not yet sorted or deduplicated).

    Args:
        camera: the camera of this ``data.csv``.
        csv_path: the ``data.csv`` file.
        data_dir: folder the file names are relative to.
        problems: appended to: unparsable rows and rows naming a missing file.

    Returns:
        One frame per valid row, in file order; and the file names that any
        row names (valid or not).

    Raises:
        CaptureError: the file cannot be read as text.
    """
    try:
        text = csv_path.read_text(encoding="utf-8-sig")  # a spreadsheet's BOM is not a row
    except (OSError, UnicodeDecodeError) as exc:
        raise CaptureError(f"{csv_path}: cannot read ({exc})") from None
    frames = []
    named: set[str] = set()
    for number, line in enumerate(text.splitlines(), start=1):
        row = line.strip()
        if not row or row.startswith("#"):
            continue
        if number == 1 and row.lower().startswith("timestamp"):
            continue  # a header written without the leading '#'
        where = f"{csv_path}:{number}"
        fields = [f.strip() for f in row.split(",")]
        if len(fields) != 2 or not fields[1]:
            problems.append(
                FrameProblem(camera, None, where, f"expected '<t_ns>,<file>', got {row[:60]!r}")
            )
            continue
        inside = name_in_folder(data_dir, fields[1])
        named.add(fields[1] if inside is None else inside)
        try:
            t_ns = int(fields[0])
        except ValueError:
            t_ns = -1
        if t_ns < 0:
            reason = (
                f"timestamp is not a non-negative integer (ns): {fields[0][:30]!r}; "
                f"the row lists {fields[1][:80]!r}"
            )
            problems.append(FrameProblem(camera, None, where, reason))
            continue
        if inside is None:  # restore writes OUT/<name>: a name leaving data/ must not be one
            reason = f"listed file lies outside {data_dir}: {fields[1][:80]!r}"
            problems.append(FrameProblem(camera, t_ns, where, reason))
            continue
        file = data_dir / inside
        if not file.is_file():
            problems.append(FrameProblem(camera, t_ns, where, f"listed file missing: {file}"))
            continue
        frames.append(FrameRef(camera, t_ns, file))
    return frames, named
