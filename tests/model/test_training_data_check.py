"""Training data is checked from file headers before the first step."""

from pathlib import Path

import numpy as np
import pytest

from lenspair.core.imageio import image_header, write_image
from lenspair.dataset.errors import DatasetError
from lenspair.model.training.config import DataConfig
from lenspair.model.training.datasets import paired_training_data
from tests.model.train_fixtures import write_paired_folder


def test_header_matches_what_read_image_returns(tmp_path: Path) -> None:
    write_image(tmp_path / "rgb.png", np.zeros((5, 7, 3), np.uint16))
    write_image(tmp_path / "grey.png", np.zeros((5, 7), np.uint8))
    assert image_header(tmp_path / "rgb.png") == (5, 7, 3, "uint16")
    assert image_header(tmp_path / "grey.png") == (5, 7, 1, "uint8")


@pytest.mark.parametrize("bad", ["smaller", "not an image"])
def test_a_bad_pair_is_found_before_training(tmp_path: Path, bad: str) -> None:
    folder = write_paired_folder(tmp_path / "pairs", count=8)
    target = folder / "target" / "005.png"
    if bad == "smaller":
        write_image(target, np.zeros((16, 48), np.uint8))
    else:
        target.write_bytes(b"not an image at all")
    with pytest.raises(DatasetError, match=r"1 bad pair\(s\) of 8: .*005\.png"):
        paired_training_data(folder, DataConfig(crop_size=16), None, seed=0)
