"""Training data is checked from file headers before the first step."""

import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from lenspair.cli import main
from lenspair.core.config import dump_yaml
from lenspair.core.errors import ConfigError
from lenspair.core.imageio import image_header
from lenspair.core.imagewrite import write_image
from lenspair.dataset.errors import DatasetError
from lenspair.model.training.config import DataConfig
from lenspair.model.training.config_loading import load_run_config, stored_run_config
from lenspair.model.training.data_checks import majority_channels
from lenspair.model.training.datasets import (
    paired_training_data,
    pairs_digest,
    synthetic_training_data,
)
from tests.model.train_fixtures import (
    clean_image,
    tiny_config,
    write_paired_folder,
    write_split_dataset,
)


def test_header_matches_what_read_image_returns(tmp_path: Path) -> None:
    write_image(tmp_path / "rgb.png", np.zeros((5, 7, 3), np.uint16))
    write_image(tmp_path / "grey.png", np.zeros((5, 7), np.uint8))
    assert image_header(tmp_path / "rgb.png") == (5, 7, 3, "uint16")
    assert image_header(tmp_path / "grey.png") == (5, 7, 1, "uint8")


@pytest.mark.parametrize("bad", ["smaller", "not an image"])
def test_a_bad_pair_is_found_before_training_and_left_out(tmp_path: Path, bad: str) -> None:
    # one bad pair of a Raindrop copy (a clean image a pixel short) refused the whole run,
    # where eval skips it; more than half bad is a folder given by mistake: refused
    folder = write_paired_folder(tmp_path / "pairs", count=8)

    def spoil(name: str) -> None:
        target = folder / "target" / f"{name}.png"
        if bad == "smaller":
            write_image(target, np.zeros((16, 48), np.uint8))
        else:
            target.write_bytes(b"not an image at all")

    spoil("005")
    notes: list[str] = []
    data = paired_training_data(folder, DataConfig(crop_size=24), None, seed=0, notes=notes)
    (said,) = [note for note in notes if "bad pair" in note]
    assert re.search(r"1 bad pair\(s\) of 8: .*005\.png.*; left out of training and val", said)
    assert len(data.train) + len(data.val) == 7 and "; 1 bad pairs left out;" in data.description
    names = [data.train.source[i].name for i in range(len(data.train))]
    names += [data.val.source[i].name for i in range(len(data.val))]
    assert "005" not in names and len(names) == 7
    for name in ("000", "001", "002", "003", "004"):
        spoil(name)  # 6 of 8
    with pytest.raises(DatasetError, match=r"6 bad pair\(s\) of 8: .*more than half"):
        paired_training_data(folder, DataConfig(crop_size=24), None, seed=0)


def test_a_bad_held_out_pair_moves_the_hold_out_to_good_pairs(tmp_path: Path) -> None:
    # the pairs held out by name hash were all bad: validation was left empty and the run
    # refused with "needs at least one validation pair", the warning naming them unsaid
    folder = write_paired_folder(tmp_path / "pairs", count=6)
    first = paired_training_data(folder, DataConfig(crop_size=24), None, seed=0)
    held = [first.val.source[i].name for i in range(len(first.val))]
    for name in held:
        (folder / "target" / f"{name}.png").write_bytes(b"not an image")
    notes: list[str] = []
    data = paired_training_data(folder, DataConfig(crop_size=24), None, seed=0, notes=notes)
    names = {data.val.source[i].name for i in range(len(data.val))}
    assert len(data.val) >= 1 and not names & set(held)
    assert len(data.train) + len(data.val) == 6 - len(held)
    assert any("every pair held out for validation is bad" in note for note in notes)
    assert "among the good ones" in data.description
    assert pairs_digest(folder, DataConfig(crop_size=24)) in data.description


def test_a_validation_pair_cut_off_after_its_header_is_found_before_training(
    tmp_path: Path,
) -> None:
    # found only at the first validation: the epoch was trained, then lost with no last.pt
    dataset = write_split_dataset(tmp_path / "ds", {"train": 3, "val": 2})
    target = dataset / "val" / "target" / "000.png"
    whole = target.read_bytes()
    target.write_bytes(whole[:300])  # the header reads, the pixels do not
    notes: list[str] = []
    paired_training_data(dataset, tiny_config().data, 1, 0, notes=notes)
    (said,) = [note for note in notes if "unreadable" in note]
    assert "validation leaves out 1 of its 2 pairs" in said and "000.png" in said
    other = dataset / "val" / "target" / "001.png"
    other.write_bytes(other.read_bytes()[:300])
    with pytest.raises(DatasetError, match=r"none of the 2 validation pair\(s\) can be scored"):
        paired_training_data(dataset, tiny_config().data, 1, 0)


def test_a_training_image_smaller_than_the_crop_is_found_before_the_first_step(
    tmp_path: Path,
) -> None:
    dataset = write_split_dataset(tmp_path / "ds", {"train": 3, "val": 1})
    small = clean_image(np.random.default_rng(1), 20, 20)
    write_image(dataset / "train" / "input" / "001.png", small)
    write_image(dataset / "train" / "target" / "001.png", small)
    config = tiny_config()  # 32 px crops
    with pytest.raises(
        DatasetError, match=r"1 training image\(s\) smaller than the 32 px crop.*001"
    ):
        paired_training_data(dataset, config.data, 1, 0)
    # validation images are whole: a small one there is fine
    write_image(dataset / "train" / "input" / "001.png", clean_image(np.random.default_rng(1)))
    write_image(dataset / "train" / "target" / "001.png", clean_image(np.random.default_rng(1)))
    write_image(dataset / "val" / "input" / "000.png", small)
    write_image(dataset / "val" / "target" / "000.png", small)
    paired_training_data(dataset, config.data, 1, 0)


def test_mixed_grey_and_colour_pairs_are_said(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    dataset = write_split_dataset(tmp_path / "ds", {"train": 3, "val": 1})
    grey = clean_image(np.random.default_rng(2))
    colour = np.ascontiguousarray(np.stack([grey, grey[::-1], grey], axis=2))
    write_image(dataset / "train" / "input" / "002.png", colour)
    write_image(dataset / "train" / "target" / "002.png", colour)
    caplog.set_level("WARNING")
    data = paired_training_data(dataset, tiny_config().data, None, 0)
    assert data.channels == 1
    assert any("mix 2 grey and 1 colour" in r.getMessage() for r in caplog.records)
    # the first pair no longer decides: a colour 000 among grey pairs leaves them grey
    for name, image in (("000", colour), ("002", grey)):
        write_image(dataset / "train" / "input" / f"{name}.png", image)
        write_image(dataset / "train" / "target" / f"{name}.png", image)
    assert paired_training_data(dataset, tiny_config().data, None, 0).channels == 1


@pytest.mark.parametrize(
    ("grey", "colour", "channels"), [(0, 5, 3), (5, 0, 1), (3, 2, 1), (2, 3, 3), (2, 2, 3)]
)
def test_the_network_takes_the_channels_of_most_images_and_colour_on_a_tie(
    grey: int, colour: int, channels: int
) -> None:
    assert majority_channels({1: grey, 3: colour}) == channels


def _clean_folder(folder: Path, count: int) -> Path:
    for index in range(count):
        write_image(folder / f"{index}.png", clean_image(np.random.default_rng(index)))
    return folder


def test_unusable_clean_images_are_found_before_synthetic_pretraining(tmp_path: Path) -> None:
    folder = _clean_folder(tmp_path / "clean", 6)
    (folder / "3.png").write_bytes(b"\\x89PNG\\r\\n\\x1a\\n garbage")
    with pytest.raises(DatasetError, match=r"1 unusable clean image\(s\).*3\.png"):
        synthetic_training_data(folder, tiny_config().data, 1, 0)


def test_mixed_grey_and_colour_clean_images_are_said(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    folder = tmp_path / "photos"
    grey = clean_image(np.random.default_rng(3))
    # first by name: it set the network's channels, so one stray grey file made a colour
    # set train a network of luma
    write_image(folder / "0_grey.png", grey)
    for index in range(1, 5):
        write_image(folder / f"{index}.png", np.ascontiguousarray(np.stack([grey] * 3, axis=2)))
    caplog.set_level("WARNING")
    data = synthetic_training_data(folder, tiny_config().data, None, 0)
    assert data.channels == 3
    (said,) = [r.getMessage() for r in caplog.records if "mix" in r.getMessage()]
    assert "clean images mix 1 grey and 4 colour" in said and "model.channels" in said
    assert "the network takes those of most of them (3)" in said
    caplog.clear()
    synthetic_training_data(folder, tiny_config().data, 3, 0)  # chosen: still said, as 3
    assert any("the network takes 3 channel(s)" in r.getMessage() for r in caplog.records)
    for index in range(1, 4):  # 4 grey, 4 colour: "those of most of them (3)" on a tie
        write_image(folder / f"{index}_grey.png", grey)
    caplog.clear()
    assert synthetic_training_data(folder, tiny_config().data, None, 0).channels == 3
    (said,) = [r.getMessage() for r in caplog.records if "mix" in r.getMessage()]
    assert "mix 4 grey and 4 colour" in said and "takes colour (3) on a tie" in said


def test_a_training_image_damaged_behind_its_header_costs_only_its_pair(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # the check before the first step reads headers; the damage shows mid-epoch
    dataset = write_split_dataset(tmp_path / "ds", {"train": 6, "val": 2})
    damaged = sorted((dataset / "train" / "input").glob("*.png"))[2]
    data = damaged.read_bytes()
    damaged.write_bytes(data[: data.index(b"IDAT") + 20])  # the header chunks whole, pixels cut
    config = tmp_path / "tiny.yaml"
    config.write_text(dump_yaml(tiny_config(max_steps=7)))  # 3 steps an epoch: 2 epochs and more
    run = tmp_path / "run"
    argv = ["train", str(dataset), "--out", str(run), "--config", str(config), "--device", "cpu"]
    with caplog.at_level("WARNING"):
        assert main(argv) == 0  # the run ended mid-epoch with an error, all its work lost
    said = [r.getMessage() for r in caplog.records if "training goes on without" in r.getMessage()]
    assert len(said) == 1 and damaged.name in said[0]  # once, naming the file
    assert (run / "checkpoints" / "last.pt").is_file()


def test_a_float_clean_image_is_found_before_synthetic_pretraining(tmp_path: Path) -> None:
    import OpenImageIO as oiio

    folder = _clean_folder(tmp_path / "clean", 6)
    pixels = np.random.default_rng(9).random((64, 64, 1)).astype(np.float32)
    out = oiio.ImageOutput.create(str(folder / "float.tif"))
    assert out.open(str(folder / "float.tif"), oiio.ImageSpec(64, 64, 1, oiio.FLOAT))
    assert out.write_image(pixels) and out.close()
    # read_image refuses it: the run would end at the step that first drew it
    with pytest.raises(DatasetError, match=r"1 unusable clean image\(s\).*float\.tif.*float"):
        synthetic_training_data(folder, tiny_config().data, 1, 0)


def test_a_clean_image_damaged_behind_its_header_costs_only_itself(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    folder = _clean_folder(tmp_path / "clean", 8)
    data = synthetic_training_data(folder, tiny_config().data, 1, 0)
    damaged = data.train.images[1]  # type: ignore[attr-defined]
    whole = damaged.read_bytes()
    damaged.write_bytes(whole[: whole.index(b"IDAT") + 20])  # header whole, pixels cut
    data = synthetic_training_data(folder, tiny_config().data, 1, 0)  # headers still pass
    with caplog.at_level("WARNING"):
        items = [data.train[index] for index in range(len(data.train))]  # type: ignore[arg-type]
        again = data.train[1]  # type: ignore[index]
    said = [r.getMessage() for r in caplog.records if "training goes on without" in r.getMessage()]
    assert len(said) == 1 and damaged.name in said[0]  # once, naming the file
    assert items[1]["name"] == items[2]["name"] == again["name"] != damaged.name
    assert not torch.equal(items[1]["input"], items[2]["input"])  # its own crop and drops


def test_held_out_clean_images_too_small_to_score_are_said_before_the_first_step(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Validation leaves out images under SSIM's 11x11 window: said up front, not after an
    epoch; when every held-out image is that small, nothing could be validated."""
    folder = _clean_folder(tmp_path / "clean", 12)
    data = synthetic_training_data(folder, tiny_config().data, 1, 0)
    held_out = data.val.images  # type: ignore[attr-defined]
    write_image(held_out[0], np.zeros((10, 40), np.uint8))
    with caplog.at_level("WARNING"):
        synthetic_training_data(folder, tiny_config().data, 1, 0)
    said = [r.getMessage() for r in caplog.records if "validation leaves out" in r.getMessage()]
    assert len(said) == 1 and held_out[0].name in said[0] and "40x10" in said[0]
    for path in held_out:
        write_image(path, np.zeros((10, 40), np.uint8))
    with pytest.raises(DatasetError, match=r"every one of the \d+ held-out clean image"):
        synthetic_training_data(folder, tiny_config().data, 1, 0)


def test_a_validation_split_with_an_unpaired_file_is_refused_not_replaced(
    tmp_path: Path,
) -> None:
    """Held-out train pairs took its place: fewer training pairs and no real validation."""
    dataset = write_split_dataset(tmp_path / "ds", {"train": 4, "val": 3, "test": 1})
    next((dataset / "val" / "target").glob("*.png")).unlink()
    with pytest.raises(DatasetError, match=r"val: 1 unpaired file\(s\)"):
        paired_training_data(dataset, DataConfig(crop_size=24), 1, 0)
    shutil.rmtree(dataset / "val")  # no val split at all: train pairs held out, and said
    data = paired_training_data(dataset, DataConfig(crop_size=24), 1, 0)
    assert "no 'val' split" in data.description and len(data.train) < 4
    # an empty val/, or empty val/input and val/target: the same (it was "holds several
    # splits; choose one of train", or "no images in input/")
    (dataset / "val").mkdir()
    for made in ([], ["input", "target"]):
        for name in made:
            (dataset / "val" / name).mkdir()
        data = paired_training_data(dataset, DataConfig(crop_size=24), 1, 0)
        assert "the split is empty" in data.description and len(data.train) < 4


def test_data_warnings_reach_train_log(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    # said while loading, before the run log existed (test_ddp: by rank 0 alone)
    dataset = write_split_dataset(tmp_path / "ds", {"train": 6})  # no val split: held out
    config = tmp_path / "tiny.yaml"
    config.write_text(dump_yaml(tiny_config(max_steps=1)))
    run = tmp_path / "run"
    argv = ["train", str(dataset), "--config", str(config), "--device", "cpu", "--out", str(run)]
    with caplog.at_level("WARNING"):
        assert main(argv) == 0
    warning = "no 'val' split"
    assert sum(warning in r.getMessage() for r in caplog.records) == 1
    assert (run / "train.log").read_text().count(warning) == 1


def test_validation_pairs_are_spread_over_the_split_not_a_name_prefix(tmp_path: Path) -> None:
    """data.max_val_images kept the first pairs by name: with ``<recording>_<t_ns>`` names,
    one recording chose best.pt and stopped the run early."""
    dataset = write_split_dataset(tmp_path / "ds", {"train": 2})
    rng = np.random.default_rng(5)
    for recording in ("a", "b", "c"):
        for t_ns in range(1000, 1004):
            image = clean_image(rng)
            for side in ("input", "target"):
                write_image(dataset / "val" / side / f"{recording}_{t_ns}.png", image)
    notes: list[str] = []
    data = paired_training_data(dataset, DataConfig(crop_size=24, max_val_images=3), 1, 0, notes)
    names = [data.val[i]["name"] for i in range(len(data.val))]
    assert sorted(name.split("_")[0] for name in names) == ["a", "b", "c"]
    assert "validation 3 of 12 pairs" in data.description and not notes


def test_a_validation_split_equal_to_the_training_split_is_refused(tmp_path: Path) -> None:
    """The run validated on its own training pairs: best.pt and early stopping judged fit."""
    with pytest.raises(ValueError, match=r"^val_split: must differ from train_split \('train'\)"):
        DataConfig(val_split="train")
    config = tmp_path / "leak.yaml"
    config.write_text("data: {val_split: train}\n")
    with pytest.raises(ConfigError, match=rf"^{re.escape(str(config))}: data\.val_split: must"):
        load_run_config(config)
    # a run stored before the check still loads (its network restores), validating apart
    assert stored_run_config({"data": {"val_split": "train"}}).data.val_split == "val"


def test_a_generic_folders_notes_reach_the_run(tmp_path: Path) -> None:
    """Said by the reader: kept for the run's log, as the other data warnings are."""
    folder = write_paired_folder(tmp_path / "pairs", count=6)
    for index in range(6):
        write_image(folder / "mask" / f"{index:03d}.png", np.zeros((32, 48), np.uint8))
    notes: list[str] = []
    paired_training_data(folder, DataConfig(crop_size=24), 1, 0, notes)
    assert sum("6 masks mark pixels left out of the loss" in note for note in notes) == 1


def test_validation_pairs_too_small_to_score_are_found_before_the_first_step(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """They were found at the first validation, after an epoch of training, with no last.pt
    to resume; some of them are said up front, as validation leaves them out."""
    dataset = tmp_path / "ds"
    write_paired_folder(dataset / "train", count=4, height=64, width=64)
    write_paired_folder(dataset / "val", count=2, height=8, width=8)
    config = tmp_path / "tiny.yaml"
    config.write_text(dump_yaml(tiny_config(max_steps=1)))
    run = tmp_path / "run"
    argv = ["train", str(dataset), "--config", str(config), "--device", "cpu", "--out", str(run)]
    assert main(argv) == 2
    error = capsys.readouterr().err.strip()
    assert "\n" not in error and f"{dataset / 'val'}: every one of the 2 validation pair" in error
    assert "11x11 SSIM window" in error and "(8x8)" in error
    assert not run.exists()  # refused before the run folder was made
    write_paired_folder(dataset / "val", count=3, height=16, width=16)  # 002 is large enough
    write_paired_folder(tmp_path / "small", count=2, height=8, width=8)
    for side in ("input", "target"):
        shutil.copy(tmp_path / "small" / side / "001.png", dataset / "val" / side / "001.png")
    assert main(argv) == 0
    said = "validation leaves out 1 of its 3 pairs, smaller than validation's 11x11 SSIM window"
    log = (run / "train.log").read_text()
    assert said in log and "val/input/001.png (8x8)" in log
    assert log.index(said) < log.index("training GEA")  # before the first step
