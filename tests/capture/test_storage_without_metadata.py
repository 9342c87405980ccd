"""A ROS 2 bag folder without ``metadata.yaml``: what ``ros2 bag record`` killed hard leaves.

It is no bag folder (rosbags needs the metadata), and restore and detect said
"no images ... found and not a recording or a bag", as of any empty folder.
They now name its storage files and say what reads them.
"""

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch

from lenspair.capture.errors import CaptureError
from lenspair.capture.frames import iter_frames
from lenspair.capture.recording import open_recording
from lenspair.cli import main
from lenspair.model.inference.backends import TorchBackend, open_backend
from lenspair.model.inference.pipeline import restore_input
from tests.images import texture
from tests.model.restore_helpers import write_bag
from tests.model.train_fixtures import make_checkpoint

NO_IMAGES = (
    "no images (.bmp, .jfif, .jpe, .jpeg, .jpg, .pbm, .pgm, .png, .pnm, .ppm, .tif, .tiff) "
    "found and not a recording or a bag"
)


def _killed_recording(path: Path, kind: str) -> Path:
    """A ROS 2 bag folder of 3 stereo frames whose ``metadata.yaml`` was never written."""
    frames = [
        (10**18 + i * 50 * 10**6, (texture((32, 48), seed=i) * 255).astype(np.uint8))
        for i in range(3)
    ]
    folder = write_bag(path, kind, {"cam0": frames, "cam1": frames})
    (folder / "metadata.yaml").unlink()
    return folder


def _message(folder: Path, named: str, first: str) -> str:
    return (
        f"{folder}: no images, and not a bag folder: it holds ROS 2 bag storage ({named}) but "
        "no metadata.yaml (a recording killed before it closed?); pass the storage file itself "
        f"({folder / first}) or run `ros2 bag reindex {folder}` to write metadata.yaml"
    )


@pytest.mark.parametrize("kind", ["db3", "mcap"])
def test_the_error_names_the_storage_and_what_reads_it(
    tmp_path: Path, kind: str, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = _killed_recording(tmp_path / "rec", kind)
    (storage,) = folder.iterdir()
    message = _message(folder, storage.name, storage.name)
    with pytest.raises(CaptureError) as caught:
        iter_frames(folder)
    assert str(caught.value) == message
    out = tmp_path / "det"
    assert main(["detect", "detector.pt", str(folder), "--out", str(out)]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == f"lenspair detect: error: {message}"
    # what the message says to do works: the storage file itself is read as the bag
    assert main(["detect", "detector.pt", str(storage), "--out", str(out)]) == 0
    assert "6 frames judged" in capsys.readouterr().out


@pytest.fixture
def checkpoint(tmp_path: Path) -> Iterator[Path]:
    before = torch.get_num_threads()
    torch.set_num_threads(1)  # the machine is shared: more threads only contend
    yield make_checkpoint(tmp_path / "ck.pt")
    torch.set_num_threads(before)


def test_restore_says_so_and_restores_the_storage_file(
    tmp_path: Path, checkpoint: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = _killed_recording(tmp_path / "rec", "db3")
    out = tmp_path / "out"
    assert main(["restore", str(checkpoint), str(folder), "--out", str(out)]) == 2
    said = capsys.readouterr().err.strip().splitlines()[-1]
    assert said == f"lenspair restore: error: {_message(folder, 'rec.db3', 'rec.db3')}"
    backend = open_backend(checkpoint, torch.device("cpu"), "fp32")
    assert isinstance(backend, TorchBackend)
    report = restore_input(folder / "rec.db3", out, backend)
    assert (report.cameras, report.restored, report.failed) == (["cam0", "cam1"], 6, 0)
    assert len(list(iter_frames(Path(report.output)))) == 6


def test_many_storage_files_are_counted_and_only_those_directly_inside(tmp_path: Path) -> None:
    split = tmp_path / "split"
    split.mkdir()
    for index in range(5):
        (split / f"rec_{index}.db3").write_bytes(b"")
    named = "rec_0.db3, rec_1.db3, rec_2.db3 and 2 more"
    with pytest.raises(CaptureError) as caught:
        iter_frames(split)
    assert str(caught.value) == _message(split, named, "rec_0.db3")
    deeper = tmp_path / "deeper"
    (deeper / "rec").mkdir(parents=True)
    (deeper / "rec" / "rec.mcap").write_bytes(b"")
    with pytest.raises(CaptureError) as caught:
        iter_frames(deeper)
    assert str(caught.value) == f"{deeper}: {NO_IMAGES}"


def test_capture_ingest_names_the_storage_too(tmp_path: Path) -> None:
    # "unknown recording layout; expected ..." alone, as for any folder
    folder = _killed_recording(tmp_path / "rec", "mcap")
    with pytest.raises(CaptureError) as caught:
        open_recording(folder)
    hint = _message(folder, "rec.mcap", "rec.mcap").split("no images, and ", 1)[1]
    assert str(caught.value) == f"{folder}: unknown recording layout: {hint}"


def test_the_storage_file_passed_as_said_finds_the_rig_file_beside_its_folder(
    tmp_path: Path,
) -> None:
    # capture-ingest of the bare .db3 the message names then asked for a rig.yaml, though
    # it lay beside the bag folder, where the bag's own is found
    from lenspair.capture.recording import find_rig_file, resolve_obstructed
    from lenspair.capture.rigfile import RigFile, write_rig_file

    folder = _killed_recording(tmp_path / "rec", "db3")
    (storage,) = folder.iterdir()
    write_rig_file(tmp_path / "rig.yaml", RigFile("cam1", ("rain",)))
    assert find_rig_file(storage) == tmp_path / "rig.yaml"
    assert resolve_obstructed(storage).obstructed == "cam1"
    inside = folder / "rig.yaml"  # one inside the folder is nearer, as for a bag folder
    write_rig_file(inside, RigFile("cam0"))
    assert find_rig_file(storage) == inside
