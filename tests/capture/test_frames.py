"""Frames of every input kind (:mod:`lenspair.capture.frames`), for restore and detect."""

from pathlib import Path

import numpy as np
import pytest

from lenspair.capture.bag_frames import bag_overview
from lenspair.capture.errors import CaptureError
from lenspair.capture.frames import detect_input, frame_files, iter_frames
from lenspair.core.imageio import read_image
from lenspair.core.imagewrite import write_image
from tests.capture.ingest_helpers import make_recording
from tests.model.restore_helpers import bag_from_recording, write_bag


def _image(path: Path, value: int) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_image(path, np.full((6, 8), value, np.uint8))


def test_one_image(tmp_path: Path) -> None:
    _image(tmp_path / "a.png", 7)
    (frame,) = list(iter_frames(tmp_path / "a.png"))
    assert (frame.index, frame.name, frame.camera, frame.t_ns) == (0, "a.png", None, None)
    assert frame.image is not None and int(frame.image[0, 0]) == 7


def test_folder_is_searched_recursively_in_a_stable_order(tmp_path: Path) -> None:
    _image(tmp_path / "b.png", 1)
    _image(tmp_path / "sub" / "a.png", 2)
    _image(tmp_path / "sub" / "deep" / "c.tif", 4)
    _image(tmp_path / "a.png", 3)
    _image(tmp_path / ".cache" / "z.png", 5)
    (tmp_path / "notes.txt").write_text("not an image")
    names = [frame.name for frame in iter_frames(tmp_path)]
    assert names == ["a.png", "b.png", "sub/a.png", "sub/deep/c.tif"]
    assert len(frame_files(tmp_path, detect_input(tmp_path), ("cam0", "cam1"))) == len(names)


def test_recording_gives_the_chosen_cameras_in_time_order(tmp_path: Path) -> None:
    root = make_recording(tmp_path / "rec", frames=3)
    assert detect_input(root) == "euroc"
    frames = list(iter_frames(root))
    assert [frame.camera for frame in frames] == ["cam0"] * 3 + ["cam1"] * 3
    stamps = [frame.t_ns for frame in frames[:3]]
    assert None not in stamps and stamps == sorted(stamps)  # type: ignore[type-var]
    assert frames[0].name == f"mav0/cam0/data/{frames[0].t_ns}.png"
    cam1 = list(iter_frames(root, cameras=("cam1",)))
    files = sorted((root / "mav0/cam1/data").glob("*.png"))
    for frame, file in zip(cam1, files, strict=True):
        assert frame.camera == "cam1" and frame.image is not None
        np.testing.assert_array_equal(frame.image, read_image(file))


def test_bag_frames_in_log_time_order(tmp_path: Path) -> None:
    bag = bag_from_recording(tmp_path / "b", "ros1", frames=2)
    frames = list(iter_frames(bag))
    assert [frame.camera for frame in frames] == ["cam0", "cam1", "cam0", "cam1"]
    assert [frame.index for frame in frames] == [0, 1, 2, 3]
    assert frames[0].name.startswith("/cam0/image_raw@") and frames[0].image is not None


def test_bag_topics_can_be_named(tmp_path: Path) -> None:
    image = np.zeros((4, 6), np.uint8)
    stream = [(10**18, image), (10**18 + 50, image)]
    bag = write_bag(tmp_path / "three", "mcap", {"cam0": stream, "cam1": stream, "cam2": stream})
    chosen = list(iter_frames(bag, topics=("/cam2/image_raw", "/cam0/image_raw")))
    assert [(f.camera, f.name.split("@")[0]) for f in chosen[:2]] == [
        ("cam1", "/cam0/image_raw"),
        ("cam0", "/cam2/image_raw"),
    ]
    with pytest.raises(CaptureError, match="/status is a std_msgs/msg/String, not an image"):
        iter_frames(bag, topics=("/status", "/cam0/image_raw"))
    # the progress bar's total, from the bag's index: the chosen cameras' messages only
    assert bag_overview(bag, ("cam0", "cam1")).frames == 4
    assert bag_overview(bag, ("cam1",), ("/cam2/image_raw", "/cam0/image_raw")).frames == 2
    assert bag_overview(bag).others == (
        f"{bag}: image topic /cam2/image_raw left as recorded (camera topics: cam0 "
        "/cam0/image_raw, cam1 /cam1/image_raw; --topics CAM0 CAM1 chooses others)",
    )


def test_bad_inputs_are_one_line_errors_raised_before_any_frame(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    (tmp_path / "x.txt").write_text("x")
    _image(tmp_path / "a.png", 1)
    cases = [
        (tmp_path / "missing", None, "no such file"),
        (tmp_path / "empty", None, "no images"),
        (tmp_path / "x.txt", None, "not an image"),
        (tmp_path / "a.png", ("/a", "/b"), "topics can only be chosen for bags"),
    ]
    for path, topics, message in cases:
        with pytest.raises(CaptureError, match=message) as caught:
            iter_frames(path, topics=topics)  # not iterated: the call itself checks
        assert "\n" not in str(caught.value)


@pytest.mark.parametrize("say_pages", [True, False])
def test_a_tiff_of_several_pages_is_said_by_detect_not_by_restore(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
    say_pages: bool,
) -> None:
    # detect judged the first page of a stack and said nothing of the others; restore,
    # which copies such a file whole and lists it, must not say "only the first is read"
    import OpenImageIO as oiio  # the test writes a file of pages, which lenspair does not

    from lenspair.core import imageio

    monkeypatch.setattr(imageio, "_SAID", set())
    page = np.full((16, 24, 1), 9, np.uint8)
    spec = oiio.ImageSpec(24, 16, 1, "uint8")
    output = oiio.ImageOutput.create(str(tmp_path / "stack.tif"))
    assert output.open(str(tmp_path / "stack.tif"), [spec, spec])
    assert output.write_image(page)
    assert output.open(str(tmp_path / "stack.tif"), spec, "AppendSubimage")
    assert output.write_image(page)
    output.close()
    with caplog.at_level("WARNING", logger="lenspair.core.imageio"):
        (frame,) = iter_frames(tmp_path, say_pages=say_pages)
    assert frame.image is not None and frame.image.shape == (16, 24)
    said = [m for m in caplog.messages if "several images (pages)" in m]
    assert len(said) == (1 if say_pages else 0)
