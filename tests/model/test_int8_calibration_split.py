"""int8 calibration where a split is empty, as dataset-build leaves one of small inputs."""

import json
import shutil
from pathlib import Path

import pytest

from lenspair.cli import main
from lenspair.model.errors import ModelError
from lenspair.model.evaluation.quantize import calibration_images
from tests.model.train_fixtures import make_checkpoint, write_split_dataset

pytestmark = pytest.mark.usefixtures("one_thread")


def _dataset(root: Path, empty: tuple[str, ...]) -> Path:
    """A lenspair dataset (its card says so) whose ``empty`` splits hold no pairs."""
    counts = {name: 2 for name in ("train", "val", "test") if name not in empty}
    write_split_dataset(root, counts)
    for split in empty:
        for side in ("input", "target"):
            (root / split / side).mkdir(parents=True)
    (root / "dataset.json").write_text('{"format": "lenspair-dataset/1"}\n')
    return root


class _NoPairs:
    """A pair source listed from ``root`` that holds no pairs."""

    def __init__(self, root: Path) -> None:
        self.root = root

    def __len__(self) -> int:
        return 0


def test_calibration_images_of_no_pairs_name_the_folder(tmp_path: Path) -> None:
    with pytest.raises(ModelError) as raised:
        calibration_images(_NoPairs(tmp_path / "DS" / "val"), 1, (32, 48))
    (line,) = str(raised.value).splitlines()
    assert line.startswith(f"{tmp_path / 'DS' / 'val'}: int8 calibration: no pairs")


def test_eval_of_train_at_int8_passes_over_an_empty_split(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """It calibrated on the empty val split and failed: "no images to calibrate on"."""
    pytest.importorskip("onnxruntime")
    data = _dataset(tmp_path / "DS", empty=("val",))
    checkpoint = make_checkpoint(tmp_path / "c.pt")
    out = tmp_path / "eval"
    argv = ["eval", str(checkpoint), "--data", str(data), "--split", "train", "--out", str(out)]
    argv += ["--device", "cpu", "--precision", "int8", "--latency-runs", "0"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert f"int8: not calibrated on {data} split val: it holds no pairs" in printed
    assert f"int8: calibrated on {data} split test" in printed
    said = json.loads((out / "metrics.json").read_text())["calibration"]
    assert said.startswith(str(data / "test"))

    # not a lenspair dataset (no card): its empty split cannot be opened; passed over too
    (data / "dataset.json").unlink()
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert f"int8: not calibrated on {data} split val: {data / 'val'}: no images" in printed
    assert f"int8: calibrated on {data} split test" in printed
    (data / "dataset.json").write_text('{"format": "lenspair-dataset/1"}\n')

    # no other split holds pairs: the scored images, said so (as for a paired folder)
    shutil.rmtree(data / "test")
    (data / "test" / "input").mkdir(parents=True)
    (data / "test" / "target").mkdir()
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "calibrated on the evaluated images themselves (no other split with pairs)" in printed
    said = json.loads((out / "metrics.json").read_text())["calibration"]
    assert said.startswith("the evaluated pairs themselves")


def test_eval_refuses_a_calibration_of_no_pairs_naming_the_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = _dataset(tmp_path / "DS", empty=("train",))
    checkpoint = make_checkpoint(tmp_path / "c.pt")
    argv = ["eval", str(checkpoint), "--data", str(data), "--split", "test"]
    argv += ["--out", str(tmp_path / "eval"), "--precision", "int8", "--calibration", str(data)]
    assert main(argv) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert f"--calibration {data}: {data / 'train'} holds no pairs to calibrate on" in line
    assert not (tmp_path / "eval" / "metrics.json").exists()


@pytest.mark.parametrize("split", ["val", None])
def test_export_refuses_a_calibration_split_of_no_pairs_before_writing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], split: str | None
) -> None:
    """The fp32 file was written (over an earlier one), then the int8 calibration failed."""
    empty = split or "train"  # without --split: the train split
    data = _dataset(tmp_path / "DS", empty=(empty,))
    checkpoint = make_checkpoint(tmp_path / "c.pt")
    onnx_file = tmp_path / "m.onnx"
    onnx_file.write_bytes(b"an earlier export")
    argv = ["export", str(checkpoint), "--onnx", str(onnx_file), "--size", "48x32"]
    argv += ["--int8", "--calibration", str(data)] + (["--split", split] if split else [])
    assert main(argv) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    option = f"--calibration {data}" + (f" --split {split}" if split else "")
    assert f"{option}: {data / empty} holds no pairs to calibrate on" in line
    assert onnx_file.read_bytes() == b"an earlier export"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["DS", "c.pt", "m.onnx"]
