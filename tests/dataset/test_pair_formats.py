"""Paired folders as train and dataset-build meet them: pixel formats, and the folder itself."""

import re
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from lenspair.capture.journal import LOCK_FILE
from lenspair.cli import main
from lenspair.core.config import dump_yaml
from lenspair.core.errors import ImageIOError
from lenspair.core.imagewrite import write_image
from lenspair.dataset.errors import DatasetError
from lenspair.dataset.readers import open_paired
from lenspair.model.training.datasets import paired_training_data
from tests.dataset.dataset_synth import RecordingFactory
from tests.model.train_fixtures import tiny_config, write_paired_folder


def _write_tiff(path: Path, kind: str, height: int = 32, width: int = 48) -> None:
    """A one-channel TIFF of ``kind`` ``float`` or ``uint32``, which lenspair cannot read."""
    pixels = np.full((height, width, 1), 7, np.float32 if kind == "float" else np.uint32)
    out = oiio.ImageOutput.create(str(path))
    assert out is not None
    spec = oiio.ImageSpec(width, height, 1, oiio.FLOAT if kind == "float" else oiio.UINT32)
    assert out.open(str(path), spec)
    assert out.write_image(pixels) and out.close()


def _replace(png: Path, kind: str) -> Path:
    """``png`` replaced by a TIFF of the same stem (the pair it belongs to) in format ``kind``."""
    png.unlink()
    tiff = png.with_suffix(".tif")
    _write_tiff(tiff, kind)
    return tiff


def test_an_input_target_or_mask_of_an_unreadable_pixel_format_is_a_header_problem(
    tmp_path: Path,
) -> None:
    """header_problems compared input and target only: a pair of float TIFFs passed it, and
    the run it was meant to protect ended in epoch 1 with no pair readable."""
    folder = write_paired_folder(tmp_path / "pairs", count=5)
    for index in range(5):
        write_image(folder / "mask" / f"{index:03d}.png", np.zeros((32, 48), np.uint8))
    float_input = _replace(folder / "input" / "001.png", "float")
    _replace(folder / "target" / "001.png", "float")  # both float: their headers agree
    wide_input = _replace(folder / "input" / "002.png", "uint32")
    _replace(folder / "target" / "002.png", "uint32")
    float_mask = _replace(folder / "mask" / "003.png", "float")
    float_target = _replace(folder / "target" / "004.png", "float")  # the input is 8-bit
    data = open_paired(folder)
    headers, problems = data.header_problems()
    assert set(headers) == {0} and set(problems) == {1, 2, 3, 4}
    need = r": unsupported pixel format {} \(need 8/16-bit\)"
    for index, path, kind in [
        (1, float_input, "float"),
        (2, wide_input, "uint"),  # 32-bit
        (3, float_mask, "float"),
        (4, float_target, "float"),
    ]:
        assert re.fullmatch(re.escape(str(path)) + need.format(kind), problems[index])
    for index in (1, 2, 3, 4):  # reading refuses them as their headers said
        with pytest.raises(ImageIOError, match="unsupported pixel format"):
            data[index]


def test_float_pairs_are_left_out_before_the_first_step_and_counted(tmp_path: Path) -> None:
    """Two float pairs of twelve were swapped for others every epoch, unsaid in config.yaml;
    all of them float started a run that ended in epoch 1 ("no training pair can be read")."""
    folder = write_paired_folder(tmp_path / "mixed", count=12)
    for name in ("003", "007"):
        _replace(folder / "input" / f"{name}.png", "float")
        _replace(folder / "target" / f"{name}.png", "float")
    config = tiny_config()
    notes: list[str] = []
    data = paired_training_data(folder, config.data, 1, 0, notes=notes)
    assert len(data.train) + len(data.val) == 10  # type: ignore[arg-type]
    assert "2 bad pairs left out" in data.description
    assert any("2 bad pair(s) of 12" in note and "float" in note for note in notes)

    every = write_paired_folder(tmp_path / "floats", count=4)
    for index in range(4):
        _replace(every / "input" / f"{index:03d}.png", "float")
        _replace(every / "target" / f"{index:03d}.png", "float")
    with pytest.raises(DatasetError, match=r"4 bad pair\(s\) of 4: .*float.*more than half"):
        paired_training_data(every, config.data, 1, 0, notes=[])


def test_all_float_pairs_refuse_train_before_the_run_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = write_paired_folder(tmp_path / "floats", count=4)
    for index in range(4):
        _replace(folder / "input" / f"{index:03d}.png", "float")
        _replace(folder / "target" / f"{index:03d}.png", "float")
    config = tmp_path / "tiny.yaml"
    config.write_text(dump_yaml(tiny_config(max_steps=2)))  # 32 px crops: the pairs hold one
    run = tmp_path / "run"
    argv = ["train", str(folder), "--out", str(run), "--config", str(config), "--device", "cpu"]
    assert main(argv) == 2  # it made the run folder and ended in epoch 1
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "unsupported pixel format float" in line and "more than half" in line
    assert not run.exists()


def _raindrop(folder: Path) -> Path:
    for index in range(2):
        write_image(folder / "data" / f"{index}_rain.png", np.full((8, 8), index, np.uint8))
        write_image(folder / "gt" / f"{index}_clean.png", np.full((8, 8), 9, np.uint8))
    return folder


def _renamed(folder: Path, names: tuple[str, str]) -> Path:
    write_paired_folder(folder, count=2)
    (folder / "input").rename(folder / names[0])
    (folder / "target").rename(folder / names[1])
    return folder


@pytest.mark.parametrize(
    ("make", "said"),
    [
        (lambda p: write_paired_folder(p, count=2), "input/ + target/"),
        (lambda p: _renamed(p, ("lq", "gt")), "lq/ + gt/"),
        (_raindrop, "Raindrop data/ + gt/"),
    ],
    ids=["input-target", "lq-gt", "raindrop"],
)
def test_dataset_build_of_a_paired_folder_says_train_reads_it_as_it_is(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], make: object, said: str
) -> None:
    """It said "missing pairs.jsonl (not an ingested recording, or capture-ingest was stopped
    before it finished: run it again)": advice to ingest a folder that needs nothing."""
    folder = make(tmp_path / "pairs")  # type: ignore[operator]
    out = tmp_path / "DS"
    assert main(["dataset-build", str(folder), "--out", str(out)]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f"lenspair dataset-build: error: {folder}: already a")
    assert said in line
    assert "train, eval and tradeoff read it as it is" in line
    assert "dataset-build takes recordings ingested by capture-ingest" in line
    assert "run it again" not in line
    assert not out.exists()


def test_a_stopped_ingest_or_another_folder_still_names_the_missing_file(
    recording: RecordingFactory, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An ingested recording holds input/ + target/ too: stopped early, it is told to rerun."""
    stopped = recording("rec_a", n=2)
    for name in ("pairs.jsonl", "report.json"):
        (stopped / name).unlink()
    (stopped / LOCK_FILE).touch()  # what capture-ingest makes first
    other = tmp_path / "half"
    (other / "input").mkdir(parents=True)  # no target/: no paired folder either
    for folder in (stopped, other):
        assert main(["dataset-build", str(folder), "--out", str(tmp_path / "DS")]) == 2
        (line,) = capsys.readouterr().err.strip().splitlines()
        assert "missing pairs.jsonl (not an ingested recording" in line, folder
        assert "run it again" in line
