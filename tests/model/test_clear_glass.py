"""Synthetic pretraining sees clear glass and textureless scenes (``clear_share``, plain scenes).

A network pretrained only on frames that all carry drops and a veil learnt to
change every frame: the weights shipped before these items darkened clear
frames by 11-13 codes. These tests pin what the data now holds.
"""

from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from lenspair.core.config import to_plain
from lenspair.core.imagewrite import write_image
from lenspair.model.checkpoint import checkpoint_config
from lenspair.model.training.config import DataConfig
from lenspair.model.training.config_loading import run_config_from_dict, stored_run_config
from lenspair.model.training.datasets import synthetic_training_data
from lenspair.model.training.loop import resume_config
from lenspair.model.training.pretrained import (
    FRAME,
    HELD_OUT_PLAIN,
    PLAIN_SCENES,
    VALIDATION_DRAWS,
    plain_scene,
    validation_drops,
    write_natural_images,
)
from lenspair.model.training.synthetic import OUR_DROPS, SyntheticDrops
from lenspair.simulate.natural_images import HELD_OUT
from tests.model.train_fixtures import make_checkpoint, tiny_config


def _clean_files(folder: Path, count: int, size: int = 96) -> list[Path]:
    rng = np.random.default_rng(1)
    files = []
    for index in range(count):
        image = cv2.GaussianBlur(rng.integers(0, 256, (size, size), dtype=np.uint8), (0, 0), 2)
        path = folder / f"clean_{index:02d}.png"
        write_image(path, image)
        files.append(path)
    return files


def _is_clear(item: dict[str, torch.Tensor]) -> bool:
    return bool(torch.equal(item["input"], item["target"]))


def test_training_share_of_clear_items_follows_clear_share(tmp_path: Path) -> None:
    files = _clean_files(tmp_path, 8)
    share, epochs = 0.3, 25
    data = SyntheticDrops(files, OUR_DROPS, 1, 48, seed=4, clear_share=share)
    clear = 0
    for epoch in range(epochs):
        data.set_epoch(epoch)
        clear += sum(_is_clear(data[index]) for index in range(len(data)))
    draws = epochs * len(files)
    spread = 4 * (draws * share * (1 - share)) ** 0.5  # 4 binomial standard deviations
    assert abs(clear - draws * share) < spread
    # and which items are clear changes with the epoch: every image is seen both ways
    data.set_epoch(0)
    first = [_is_clear(data[index]) for index in range(len(data))]
    data.set_epoch(1)
    assert first != [_is_clear(data[index]) for index in range(len(data))]


def test_without_clear_share_every_item_has_drops(tmp_path: Path) -> None:
    files = _clean_files(tmp_path, 6)
    data = SyntheticDrops(files, OUR_DROPS, 1, None, seed=2)
    assert not any(_is_clear(data[index]) for index in range(len(data)))


def test_validation_spreads_clear_items_evenly_and_says_which(tmp_path: Path) -> None:
    files = _clean_files(tmp_path, 3)
    val = validation_drops(files, 1, clear=True)
    assert len(val) == len(files) * (VALIDATION_DRAWS + 1)
    for index in range(len(val)):
        item = val[index]
        assert _is_clear(item) == val.clear(index)
    # each held-out image: its drop draws, then once through clear glass
    clear_names = [val[index]["name"] for index in range(len(val)) if val.clear(index)]
    assert sorted(clear_names) == sorted(p.name for p in files)
    again = validation_drops(files, 1, clear=True)  # fixed: the same items every time
    assert all(torch.equal(val[i]["input"], again[i]["input"]) for i in range(len(val)))
    training_validation = validation_drops(files, 1)  # what training selects on: drops only
    assert len(training_validation) == len(files) * VALIDATION_DRAWS
    assert not any(_is_clear(training_validation[i]) for i in range(len(training_validation)))
    training = SyntheticDrops(files, OUR_DROPS, 1, 48, clear_share=0.5)
    assert not training.clear(0)  # only validation items have a fixed answer


@pytest.mark.parametrize("share", [-0.1, 1.0, 1.5])
def test_a_clear_share_without_drops_is_refused(tmp_path: Path, share: float) -> None:
    with pytest.raises(ValueError, match="clear_share"):
        DataConfig(clear_share=share)
    with pytest.raises(ValueError, match="clear_share"):
        SyntheticDrops(_clean_files(tmp_path, 1), OUR_DROPS, 1, clear_share=share)


def test_synthetic_training_data_gives_the_share_to_training_not_validation(
    tmp_path: Path,
) -> None:
    _clean_files(tmp_path, 30)
    data = synthetic_training_data(tmp_path, DataConfig(crop_size=32, clear_share=0.25), 1, 0)
    assert isinstance(data.train, SyntheticDrops) and isinstance(data.val, SyntheticDrops)
    assert data.train.clear_share == 0.25
    assert data.val.clear_share == 0.0  # validation selects on drops: see clear_share
    assert DataConfig().clear_share > 0  # on by default: see its docstring


@pytest.mark.parametrize("channels", [1, 3])
def test_plain_scenes_are_textureless_with_their_declared_noise(channels: int) -> None:
    for name, (level, _, noise_codes) in PLAIN_SCENES.items():
        scene = plain_scene(name, channels)
        expected_shape = FRAME if channels == 1 else (*FRAME, 3)
        assert scene.shape == expected_shape and scene.dtype == np.uint8
        values = scene.astype(np.float64).reshape(*FRAME, channels)
        for channel in range(channels):
            plane = values[..., channel]
            smooth = cv2.GaussianBlur(plane, (0, 0), 6)
            # the noise is what is declared (rounding to codes adds 1/12 code^2)
            residual = (plane - smooth)[20:-20, 20:-20].std()
            assert residual == pytest.approx((noise_codes**2 + 1 / 12) ** 0.5, rel=0.1)
            # and there is no texture: the smooth part changes by well under a code per pixel
            gradient = np.abs(np.diff(smooth[20:-20, 20:-20], axis=1)).max()
            assert gradient < 0.25
            centre = (level[channel] if channels == 3 else np.mean(level)) * 255
            assert plane[200:280, 320:400].mean() == pytest.approx(centre, abs=6)
        assert np.array_equal(scene, plain_scene(name, channels))  # fixed seed


def test_pretraining_images_hold_plain_scenes_and_keep_the_held_out_apart(tmp_path: Path) -> None:
    train, validation = write_natural_images(tmp_path, 1)
    assert sorted(p.stem for p in validation) == sorted((*HELD_OUT, HELD_OUT_PLAIN))
    stems = {p.stem for p in train}
    assert set(PLAIN_SCENES) - {HELD_OUT_PLAIN} <= stems and HELD_OUT_PLAIN not in stems
    assert not any(p.stem.split("_zoom")[0].split("_whole")[0] in HELD_OUT for p in train)


def test_a_run_stored_before_clear_share_resumes_as_it_began(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Its stored config has no clear_share: it trained without clear items, and goes on so."""
    last = make_checkpoint(tmp_path / "run" / "checkpoints" / "last.pt")
    data = torch.load(last, weights_only=True)
    del data["config"]["data"]["clear_share"]  # as written before the key existed
    torch.save(data, last)
    assert checkpoint_config(data).data.clear_share == 0.0
    assert resume_config(tmp_path / "run", None).data.clear_share == 0.0
    with caplog.at_level("WARNING"):
        resumed = resume_config(tmp_path / "run", tiny_config())  # today's default, 0.2
    assert resumed.data.clear_share == DataConfig().clear_share
    assert any("data.clear_share: 0.0 -> 0.2" in m for m in caplog.messages)  # said
    # a user's own file without the key gets today's default
    plain = to_plain(tiny_config())
    del plain["data"]["clear_share"]
    assert run_config_from_dict(plain).data.clear_share == DataConfig().clear_share
    assert stored_run_config(plain).data.clear_share == 0.0
