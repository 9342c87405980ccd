"""Paths written in YAML files: ``~`` is the home folder, relative is beside the file.

rig.yaml's ``calibration``, a scene spec's texture files and the training
config's ``train.vgg19_weights`` (and ``LENSPAIR_VGG19_WEIGHTS``) all go
through :func:`lenspair.core.config.config_path`.
"""

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from lenspair.capture.calibration_source import calibration_files
from lenspair.capture.rigfile import RigFile
from lenspair.cli import build_parser
from lenspair.commands.train import with_options
from lenspair.core.config import config_path, load_yaml
from lenspair.model.networks.vgg import VGG19_WEIGHTS_ENV, VGG19Features, load_vgg19
from lenspair.model.training.config_loading import load_run_config, with_file
from lenspair.model.training.step import Trainer, vgg19_weights_path
from lenspair.simulate.textures import check_texture, load_texture_image
from tests.model.train_fixtures import tiny_config


@pytest.fixture
def home(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A home folder of the test's own, holding ``x/``."""
    folder = tmp_path / "home"
    (folder / "x").mkdir(parents=True)
    monkeypatch.setenv("HOME", str(folder))
    return folder


def test_config_path_expands_home_and_reads_relative_beside_the_file(home: Path) -> None:
    base = Path("/configs")
    assert config_path("~/x/a.pth", base) == home / "x" / "a.pth"
    assert config_path("a.pth", base) == base / "a.pth"
    assert config_path("/abs/a.pth", base) == Path("/abs/a.pth")
    assert config_path("a.pth") == Path("a.pth")  # no folder: as written


def test_rig_yaml_calibration_under_home_is_found(home: Path, tmp_path: Path) -> None:
    (home / "x" / "camchain.yaml").write_text("cam0: {}\n")
    recording = tmp_path / "rec"
    recording.mkdir()
    (recording / "rig.yaml").write_text("obstructed: cam1\ncalibration: ~/x/camchain.yaml\n")
    rig = RigFile(obstructed="cam1", calibration="~/x/camchain.yaml")
    assert calibration_files(recording, rig, ()) == [home / "x" / "camchain.yaml"]


def test_texture_file_under_home_is_read(home: Path, tmp_path: Path) -> None:
    cv2.imwrite(str(home / "x" / "tex.png"), np.full((8, 8, 3), 128, np.uint8))
    spec_dir = tmp_path / "specs"
    spec_dir.mkdir()
    assert check_texture("~/x/tex.png", spec_dir) is None
    assert load_texture_image("~/x/tex.png", spec_dir).shape == (8, 8, 3)


def test_vgg19_weights_under_home_from_the_config_and_the_environment(
    home: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    weights = home / "x" / "vgg.pth"
    config = tmp_path / "train.yaml"
    config.write_text("train:\n  vgg19_weights: ~/x/vgg.pth\n")
    assert load_run_config(config).train.vgg19_weights == weights
    assert vgg19_weights_path(Path("~/x/vgg.pth")) == weights
    monkeypatch.setenv(VGG19_WEIGHTS_ENV, "~/x/vgg.pth")
    assert vgg19_weights_path(None) == weights


@dataclass(frozen=True)
class _WithPath:
    weights: Path


@pytest.fixture
def configs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A folder for config files; the test runs from a sibling folder, ``../configs``."""
    folder = tmp_path / "configs"
    folder.mkdir()
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    return folder


def test_a_relative_path_field_is_read_beside_its_yaml_file_from_any_folder(
    configs: Path,
) -> None:
    (configs / "c.yaml").write_text("weights: vgg.pth\n")
    assert load_yaml(_WithPath, Path("../configs/c.yaml")).weights == Path("../configs/vgg.pth")


def test_the_train_config_s_relative_weights_are_beside_it_from_any_folder(
    configs: Path,
) -> None:
    # `vgg19_weights: vgg.pth` beside train.yaml, run from another folder: "no such file
    # vgg.pth", where rig.yaml and scene specs read their paths beside themselves
    (configs / "train.yaml").write_text("train:\n  vgg19_weights: vgg.pth\n")
    config = load_run_config(Path("../configs/train.yaml"))
    assert config.train.vgg19_weights == configs / "vgg.pth"  # absolute: a resume finds it
    assert with_file(load_run_config(None), Path("../configs/train.yaml")) == config


def test_the_environment_s_vgg19_weights_under_home_are_loaded(
    home: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # LENSPAIR_VGG19_WEIGHTS=~/x/vgg.pth: "VGG19 weights: no such file ~/x/vgg.pth"
    torch.save(VGG19Features().state_dict(), home / "x" / "vgg.pth")
    monkeypatch.setenv(VGG19_WEIGHTS_ENV, "~/x/vgg.pth")
    assert load_vgg19(None) is not None


def test_train_s_vgg19_weights_option_under_home_is_loaded(home: Path) -> None:
    # --vgg19-weights=~/x/vgg.pth reaches the config as typed (a shell expands ~ only at a
    # word's start): the run printed the expanded path, then loaded the raw one, "no such file"
    torch.save(VGG19Features().state_dict(), home / "x" / "vgg.pth")
    trainer = Trainer(tiny_config(vgg19_weights=Path("~/x/vgg.pth")), torch.device("cpu"))
    assert trainer.vgg is not None and trainer.perceptual_status.endswith(f"({home}/x/vgg.pth)")


def test_a_config_over_a_stored_one_keeps_the_stored_paths(configs: Path) -> None:
    # train --resume RUN --config patience.yaml re-read the run's own relative
    # vgg19_weights beside patience.yaml: "no such file cfgs/weights/vgg19.pth"
    stored = tiny_config(vgg19_weights=Path("weights/vgg19.pth"))
    (configs / "patience.yaml").write_text("train:\n  patience: 3\n")
    merged = with_file(stored, Path("../configs/patience.yaml"))
    assert merged.train.patience == 3
    assert merged.train.vgg19_weights == Path("weights/vgg19.pth")
    (configs / "weights.yaml").write_text("train:\n  vgg19_weights: mine.pth\n")
    named = with_file(stored, Path("../configs/weights.yaml"))
    assert named.train.vgg19_weights == configs.resolve() / "mine.pth"  # the file's own: beside it


def test_a_home_folder_that_cannot_be_told_leaves_the_path_as_written() -> None:
    # ~nosuchuser ended in "RuntimeError: Could not determine home directory" (a traceback)
    assert config_path("~nosuchuser_lenspair/vgg.pth") == Path("~nosuchuser_lenspair/vgg.pth")


def test_train_s_vgg19_weights_option_is_kept_absolute(configs: Path) -> None:
    # kept as typed (relative to where train ran), a resume from another folder missed it
    args = build_parser("train").parse_args(
        ["train", "--synthetic", "imgs", "--out", "run", "--vgg19-weights", "w.pth"]
    )
    config = with_options(tiny_config(), args)
    assert config.train.vgg19_weights == Path.cwd() / "w.pth"
