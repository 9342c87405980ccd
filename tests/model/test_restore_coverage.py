"""``restore`` accounts for every image of its input: cam0/cam1 folders of images, third cameras."""

from pathlib import Path

import pytest
import torch

from lenspair.capture.frames import detect_input, images_outside_cameras
from lenspair.capture.rigfile import RigFile, write_rig_file
from lenspair.model.inference.backends import TorchBackend, open_backend
from lenspair.model.inference.out_layout import files_under
from lenspair.model.inference.pipeline import restore_input
from lenspair.model.inference.restore_options import RestoreOptions
from tests.model.folder_recordings import TIMES, euroc_recording, textured_image
from tests.model.restore_helpers import file_tree
from tests.model.train_fixtures import make_checkpoint


@pytest.fixture
def backend(tmp_path: Path, one_thread: None) -> TorchBackend:
    loaded = open_backend(make_checkpoint(tmp_path / "ck.pt"), torch.device("cpu"), "fp32")
    assert isinstance(loaded, TorchBackend)
    return loaded


def test_cam0_and_cam1_folders_of_images_alone_are_a_folder(
    tmp_path: Path, backend: TorchBackend
) -> None:
    """No data.csv, no data/: a folder of images, every one restored (was refused as EuRoC)."""
    folder = tmp_path / "cc"
    textured_image(folder / "cam0" / "a.png", 1)
    textured_image(folder / "cam1" / "b.png", 2)
    textured_image(folder / "top.png", 3)
    assert detect_input(folder) == "folder"
    report = restore_input(folder, tmp_path / "out", backend)
    assert (report.kind, report.restored, report.failed, report.problems) == ("folder", 3, 0, [])
    assert sorted(file_tree(tmp_path / "out")) == [
        ".lenspair-restore.lock",  # one restore writes OUT at a time (empty, hidden)
        "cam0/a.png",
        "cam1/b.png",
        "restore_report.json",
        "top.png",
    ]


def test_a_recording_is_told_by_each_camera_folders_listing(tmp_path: Path) -> None:
    assert detect_input(euroc_recording(tmp_path / "eu", ("cam0", "cam1"))) == "euroc"
    bare = tmp_path / "bare"  # cam0/ and cam1/ beside each other, data/ without data.csv
    for camera in ("cam0", "cam1"):
        textured_image(bare / camera / "data" / f"{TIMES[0]}.png", 1)
    assert detect_input(bare) == "euroc"
    half = tmp_path / "half"  # one camera a recording's, the other images alone
    textured_image(half / "cam0" / "data" / f"{TIMES[0]}.png", 1)
    textured_image(half / "cam1" / "b.png", 2)
    assert detect_input(half) == "folder"


def test_a_third_cameras_images_are_copied_and_named(tmp_path: Path, backend: TorchBackend) -> None:
    """mav0/cam2 is copied as it is, as before, and now named: one line for its folder."""
    recording = euroc_recording(tmp_path / "eu")
    textured_image(recording / "mav0" / "overview.png", 7)
    textured_image(recording / "mav0" / "cam0" / "preview.png", 8)  # beside data/: no frame either
    write_rig_file(recording / "rig.yaml", RigFile(obstructed="cam1", anomaly=("rain",)))
    out = tmp_path / "out"
    report = restore_input(recording, out, backend)
    assert report.cameras == ["cam1"] and report.restored == 2 and report.failed == 0
    # cam0 is left out by rig.yaml's choice, not named; cam2 and the loose images are
    reasons = [problem["reason"] for problem in report.problems]
    assert reasons == [
        f"{recording / 'mav0/cam2'}: 2 images outside the recording's cameras (cam0, cam1), "
        "copied unrestored: restore the folder as an INPUT of its own",
        f"{recording / 'mav0/overview.png'}: an image outside the recording's cameras "
        "(cam0, cam1), copied unrestored: restore it as an INPUT of its own",
    ]
    assert file_tree(out / "mav0" / "cam2") == file_tree(recording / "mav0" / "cam2")
    both = restore_input(recording, tmp_path / "both", backend, RestoreOptions(camera="both"))
    assert [p["reason"].split(":")[0] for p in both.problems] == [
        str(recording / "mav0/cam0/preview.png"),
        str(recording / "mav0/cam2"),
        str(recording / "mav0/overview.png"),
    ]


def test_images_beside_left_and_right_are_named(tmp_path: Path, backend: TorchBackend) -> None:
    recording = tmp_path / "lr"
    for seed, side in enumerate(("left", "right", "center")):
        for index, t_ns in enumerate(TIMES):
            textured_image(recording / side / f"{t_ns}.png", 10 * seed + index)
    textured_image(recording / "overview.png", 5)
    textured_image(recording / ".thumbs" / "x.png", 6)  # hidden, as a folder's hidden files: quiet
    assert detect_input(recording) == "folders"
    report = restore_input(recording, tmp_path / "out", backend)
    assert report.restored == 4
    reasons = [problem["reason"] for problem in report.problems]
    assert reasons == [
        f"{recording / 'center'}: 2 images outside the recording's cameras (left/, right/), "
        "copied unrestored: restore the folder as an INPUT of its own",
        f"{recording / 'overview.png'}: an image outside the recording's cameras (left/, "
        "right/), copied unrestored: restore it as an INPUT of its own",
    ]
    assert file_tree(tmp_path / "out" / "center") == file_tree(recording / "center")


def test_images_outside_cameras_groups_by_the_topmost_folder(tmp_path: Path) -> None:
    recording = euroc_recording(tmp_path / "eu", ("cam0", "cam1"))
    for name in ("mav0/cam2/data/1.png", "mav0/cam2/data/2.png", "mav0/cam2/x.png"):
        textured_image(recording / name, 1)
    textured_image(recording / "mav0/cam0/data/sub/3.png", 2)  # below a camera's images: its folder
    (recording / "mav0/cam2/notes.txt").write_text("not an image")
    read = [recording / "mav0" / c / "data" / f"{t}.png" for c in ("cam0", "cam1") for t in TIMES]
    groups = images_outside_cameras(
        recording, "euroc", ("cam0", "cam1"), read, files_under(recording)
    )
    assert [(g.where.relative_to(recording).as_posix(), g.images, g.folder) for g in groups] == [
        ("mav0/cam0/data/sub", 1, True),
        ("mav0/cam2", 3, True),
    ]
    assert images_outside_cameras(recording, "folder", (), [], files_under(recording)) == []


@pytest.mark.parametrize("simulated", [True, False])
def test_a_simulated_recordings_ground_truth_is_not_named_outside_its_cameras(
    tmp_path: Path, simulated: bool
) -> None:
    # the demo restored a simulated recording and listed its truth/ as a problem
    root = euroc_recording(tmp_path / "rec", ("cam0", "cam1"))
    textured_image(root / "truth" / "clear" / f"{TIMES[0]}.png", 5)
    if simulated:
        (root / "truth" / "geometry.json").write_text("{}")
    outside = images_outside_cameras(root, "euroc", ("cam1",), [], files_under(root))
    named = [group.where.relative_to(root).as_posix() for group in outside]
    assert named == ([] if simulated else ["truth"])
