"""``detect`` accounts for every image of its input, and fails when it judged none."""

import csv
from pathlib import Path

import pytest

from lenspair.cli import main
from lenspair.model.detection.unjudged import unjudged_images
from tests.model.folder_recordings import TIMES, euroc_recording, textured_image

SHAPE = (36, 54)


def _image(path: Path, seed: int) -> None:
    textured_image(path, seed, SHAPE)


def _rows(out: Path) -> list[dict[str, str]]:
    with (out / "detections.csv").open() as handle:
        return list(csv.DictReader(handle))


def _broken_png(path: Path) -> None:
    """A PNG cut short after its header: read fails, named as truncated."""
    _image(path, 9)
    path.write_bytes(path.read_bytes()[:60])


def test_no_frame_judged_is_exit_2_naming_the_first_after_writing_the_rows(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "bad"
    _broken_png(folder / "a.png")
    (folder / "b.png").write_bytes(b"\x89PNG not really")
    out = tmp_path / "out"
    assert main(["detect", "detector.pt", str(folder), "--out", str(out)]) == 2
    said = capsys.readouterr()
    [error] = [line for line in said.err.splitlines() if " error: " in line]
    assert error.startswith("lenspair detect: error: none of the 2 frames could be judged")
    assert f"(the first: {folder / 'a.png'}: " in error
    assert error.endswith(f"each is listed in {out / 'detections.csv'}")
    assert "0 frames judged" in said.out  # the summary still said, as restore's is
    rows = _rows(out)
    assert [row["name"] for row in rows] == ["a.png", "b.png"] and all(r["error"] for r in rows)


def test_a_single_unreadable_image_is_exit_2(tmp_path: Path) -> None:
    _broken_png(tmp_path / "cut.png")
    out = tmp_path / "out"
    assert main(["detect", "detector.pt", str(tmp_path / "cut.png"), "--out", str(out)]) == 2
    assert [row["name"] for row in _rows(out)] == ["cut.png"]


def test_one_frame_judged_among_unreadable_ones_is_done(tmp_path: Path) -> None:
    folder = tmp_path / "mixed"
    _broken_png(folder / "a.png")
    _image(folder / "b.png", 1)
    assert main(["detect", "detector.pt", str(folder), "--out", str(tmp_path / "out")]) == 0


def test_cam0_and_cam1_folders_of_images_alone_are_judged_as_a_folder(tmp_path: Path) -> None:
    folder = tmp_path / "cc"
    _image(folder / "cam0" / "a.png", 1)
    _image(folder / "cam1" / "b.png", 2)
    out = tmp_path / "out"
    assert main(["detect", "detector.pt", str(folder), "--out", str(out)]) == 0
    rows = _rows(out)
    assert [row["name"] for row in rows] == ["cam0/a.png", "cam1/b.png"]
    assert not any(row["error"] for row in rows)


def test_a_third_cameras_images_are_named_not_judged(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recording = euroc_recording(tmp_path / "eu", shape=SHAPE)
    _image(recording / "overview.png", 5)
    out = tmp_path / "out"
    assert main(["detect", "detector.pt", str(recording), "--out", str(out)]) == 0
    said = capsys.readouterr()
    warnings = [line for line in said.err.splitlines() if "warning" in line]
    assert warnings == [
        f"lenspair detect: warning: {recording / 'mav0/cam2'}: 2 images outside the "
        "recording's cameras (cam0, cam1), not judged: detect the folder as an INPUT of its own",
        f"lenspair detect: warning: {recording / 'overview.png'}: an image outside the "
        "recording's cameras (cam0, cam1), not judged: detect it as an INPUT of its own",
    ]
    assert "4 frames judged" in said.out
    assert "3 images outside the recording's cameras not judged (warnings above)" in said.out
    assert len(_rows(out)) == 4


def test_unjudged_images_looks_through_recordings_only(tmp_path: Path) -> None:
    for side in ("left", "right", "center"):
        for index, t_ns in enumerate(TIMES):
            _image(tmp_path / "lr" / side / f"{t_ns}.png", index)
    judged = [tmp_path / "lr" / side / f"{t}.png" for side in ("left", "right") for t in TIMES]
    [group] = unjudged_images(tmp_path / "lr", "folders", ("cam0", "cam1"), judged)
    assert (group.where, group.images, group.folder) == (tmp_path / "lr" / "center", 2, True)
    assert unjudged_images(tmp_path / "lr", "folder", ("cam0", "cam1"), []) == []
