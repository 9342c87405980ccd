"""Listing the frames of images, folders and recordings for detect/restore."""

from pathlib import Path

import numpy as np
import pytest

from lenspair.capture.errors import CaptureError
from lenspair.capture.frame_source import input_frames
from lenspair.core.imageio import write_image
from tests.capture.ingest_helpers import make_recording


def _image(path: Path, value: int) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_image(path, np.full((6, 8), value, np.uint8))


def test_one_image(tmp_path: Path) -> None:
    _image(tmp_path / "a.png", 7)
    (frame,) = list(input_frames(tmp_path / "a.png"))
    assert frame.name == "a.png" and frame.camera is None
    assert int(frame.load()[0, 0]) == 7


def test_folder_is_searched_recursively_in_a_stable_order(tmp_path: Path) -> None:
    _image(tmp_path / "b.png", 1)
    _image(tmp_path / "sub" / "a.png", 2)
    _image(tmp_path / "a.png", 3)
    (tmp_path / "notes.txt").write_text("not an image")
    names = [frame.name for frame in input_frames(tmp_path)]
    assert names == ["a.png", "b.png", "sub/a.png"]


def test_recording_gives_both_cameras_in_time_order(tmp_path: Path) -> None:
    root = tmp_path / "rec"
    make_recording(root, frames=3)
    frames = list(input_frames(root))
    cameras = [frame.camera for frame in frames]
    assert cameras == ["cam0"] * 3 + ["cam1"] * 3
    stamps = [frame.t_ns for frame in frames[:3]]
    assert stamps == sorted(stamps)
    assert frames[0].name == f"cam0/{frames[0].t_ns}"
    assert frames[0].load().ndim in (2, 3)


def test_bad_inputs_are_one_line_errors(tmp_path: Path) -> None:
    with pytest.raises(CaptureError, match="no such file"):
        list(input_frames(tmp_path / "missing"))
    (tmp_path / "empty").mkdir()
    with pytest.raises(CaptureError, match="no images"):
        list(input_frames(tmp_path / "empty"))
    (tmp_path / "x.txt").write_text("x")
    with pytest.raises(CaptureError, match="not an image"):
        list(input_frames(tmp_path / "x.txt"))
