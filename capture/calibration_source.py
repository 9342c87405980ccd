"""Where a recording's rig calibration comes from, for ``capture-ingest``.

In order: the files given with ``--calib``, else the file named by
``rig.yaml``'s ``calibration`` key (``~`` expanded; relative to ``rig.yaml``), else a Kalibr
``camchain.yaml`` in or beside the recording, else a EuRoC recording's own
``mav0/cam{0,1}/sensor.yaml`` when both hold intrinsics and ``T_BS``, else a
bag's own ``camera_info`` topics (:mod:`lenspair.capture.bag_calibration`).
"""

from pathlib import Path

from lenspair.capture.bag_calibration import bag_calibration
from lenspair.capture.errors import CaptureError
from lenspair.capture.recording import Recording, find_rig_file, recording_places
from lenspair.capture.rigfile import CameraName, RigFile
from lenspair.core.config import config_path
from lenspair.core.errors import LenspairError
from lenspair.rectify.calib_euroc import is_euroc_sensor_file
from lenspair.rectify.calib_io import load_calibration
from lenspair.rectify.rig import StereoRig

CAMCHAIN_FILE = "camchain.yaml"


def find_calibration(
    recording: Recording, rig_file: RigFile, calibration: tuple[Path, ...]
) -> tuple[StereoRig, str]:
    """The rig calibration: ``--calib``, rig.yaml's key, camchain, sensor.yaml, camera_info.

    Args:
        recording: the recording (its folder is searched).
        rig_file: the recording's ``rig.yaml`` contents.
        calibration: files given with ``--calib`` (any format of
            :func:`lenspair.rectify.calib_io.load_calibration`).

    Returns:
        ``(rig, description of the source)``.

    Raises:
        CaptureError: none of the three exists; the message says where it looked.
        RectifyError: the file is malformed (NaN, missing keys; names the file).

    """
    paths = calibration_files(recording.path, rig_file, calibration)
    if not calibration and rig_file.calibration is None:
        sensors = [recording.sensor_files.get(camera) for camera in ("cam0", "cam1")]
        if not paths and all(p is not None and is_euroc_sensor_file(p) for p in sensors):
            paths = [p for p in sensors if p is not None]  # a EuRoC recording's own
        topics = recording.topics if recording.layout in ("rosbag1", "rosbag2") else None
        if not paths and topics is not None:
            from_bag = bag_calibration(recording.path, topics)
            if from_bag is not None:
                return from_bag
        if not paths:
            found = [p for p in sensors if p is not None]
            note = f" ({len(found)} sensor.yaml without intrinsics and T_BS)" if found else ""
            note += " (no camera_info topic beside its cameras' images)" if topics else ""
            raise CaptureError(
                f"{recording.path}: no calibration{note}: pass --calib FILE, set 'calibration:' "
                f"in rig.yaml, or put {CAMCHAIN_FILE} (Kalibr) beside the recording"
            )
    return load_calibration(paths, resolutions=_frame_sizes(recording))


def calibration_files(
    recording_path: Path, rig_file: RigFile, calibration: tuple[Path, ...]
) -> list[Path]:
    """The calibration files a recording names: ``--calib``'s, rig.yaml's, or a camchain.

    Empty when none is named or found (:func:`find_calibration` then looks at
    the recording's own ``sensor.yaml`` files and a bag's ``camera_info``).

    Raises:
        CaptureError: rig.yaml names a file that does not exist.
    """
    if calibration:
        return list(calibration)
    if rig_file.calibration is not None:
        rig_path = find_rig_file(recording_path)
        base = rig_path.parent if rig_path is not None else recording_path
        path = config_path(rig_file.calibration, base)
        if not path.is_file():
            raise CaptureError(f"{rig_path}: calibration {rig_file.calibration!r} not found")
        return [path]
    places = recording_places(recording_path)
    return [p / CAMCHAIN_FILE for p in places if (p / CAMCHAIN_FILE).is_file()][:1]


def stated_topics(
    recording_path: Path, rig_file: RigFile, calibration: tuple[Path, ...]
) -> tuple[str, str] | None:
    """The ``(cam0, cam1)`` topics the recording's calibration states, or None.

    The calibration :func:`find_calibration` will use (:func:`calibration_files`;
    a Kalibr camchain states each camera's ``rostopic``). For a bag whose topic
    names tell neither camera: the calibration then chooses the two cameras,
    as it already decides their order. A calibration that cannot be read
    states nothing here; :func:`find_calibration` says why.
    """
    try:
        paths = calibration_files(recording_path, rig_file, calibration)
        rig, _ = load_calibration(paths) if paths else (None, "")
    except LenspairError:
        return None
    return rig.topics if rig is not None and rig.topics_stated else None


def _frame_sizes(recording: Recording) -> tuple[tuple[int, int] | None, ...]:
    """``(width, height)`` of each camera's first readable frame (or None), cam0's first.

    For an OpenCV FileStorage calibration without an image size (the
    stereo_calib sample writes none): each camera's frames are the size it
    was calibrated at, or the frame-size check refuses them later. Each
    camera its own: a rig's two cameras need not have one size.
    """
    return tuple(_first_frame_size(recording, camera) for camera in ("cam0", "cam1"))


def _first_frame_size(recording: Recording, camera: CameraName) -> tuple[int, int] | None:
    """``(width, height)`` of the first of ``camera``'s first five frames that reads, or None."""
    for frame in recording.frames[camera][:5]:
        try:
            image = recording.load(frame)
        except LenspairError:
            continue
        return int(image.shape[1]), int(image.shape[0])
    return None
