"""Pretraining on a paired folder's targets holds out what fine-tuning on it validates on."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from lenspair.core.imagewrite import write_image
from lenspair.model.training.datasets import _split_sources, synthetic_training_data
from lenspair.model.training.holdout import pair_name, split_holdout
from tests.model.train_fixtures import tiny_config

T0 = 1_700_000_000_000_000_000


def _write_pairs(folder: Path, layout: str, count: int) -> None:
    """``count`` pairs: Raindrop ``data/N_rain.png`` + ``gt/N_clean.png``, or dataset-build
    ``input/<rec>_<t_ns>.png`` + ``target/...`` frames 2 s apart (held out in windows)."""
    rng = np.random.default_rng(0)
    for i in range(count):
        image = rng.integers(0, 256, (40, 40), dtype=np.uint8)
        if layout == "raindrop":
            write_image(folder / "data" / f"{i}_rain.png", image)
            write_image(folder / "gt" / f"{i}_clean.png", image)
        else:
            name = f"rec_{T0 + i * 2 * 10**9}"
            write_image(folder / "input" / f"{name}.png", image)
            write_image(folder / "target" / f"{name}.png", image)


@pytest.mark.parametrize("layout", ["raindrop", "recording"])
def test_pretraining_never_trains_on_the_fine_tunes_validation_targets(
    tmp_path: Path, layout: str
) -> None:
    folder = tmp_path / "train"
    _write_pairs(folder, layout, 60)
    data = replace(tiny_config().data, max_val_images=100)
    train_pairs, val_pairs, _ = _split_sources(folder, data, [])
    pretraining = synthetic_training_data(folder, data, None, seed=0, notes=[])
    assert len(val_pairs) >= 3
    layout_of = "raindrop" if layout == "raindrop" else "paired"
    held_out = {pair_name(image, layout_of) for image in pretraining.val.images}
    pretrained_on = {pair_name(image, layout_of) for image in pretraining.train.images}
    assert held_out == set(val_pairs.names or [])
    assert pretrained_on == set(train_pairs.names or [])


def test_pair_names_follow_the_layout() -> None:
    assert pair_name(Path("raindrop/train/gt/12_clean.png"), "raindrop") == "12"
    assert pair_name(Path("pairs/target/beach_clean.jpg"), "paired") == "beach_clean"
    assert pair_name(Path("ds/train/target/rec_1.png"), "lenspair") == "rec_1"


def test_photographs_that_share_a_name_in_scene_folders_are_held_out_one_by_one(
    tmp_path: Path,
) -> None:
    # named by stem, the twenty 000.png were one group, too big to hold out: no validation
    images = [tmp_path / f"scene_{k:02d}" / f"{i:03d}.png" for k in range(20) for i in range(3)]
    train, val = split_holdout(images, 0.1, tmp_path)
    assert len(val) == 6 and sorted(train + val) == sorted(images)  # the tenth asked for
