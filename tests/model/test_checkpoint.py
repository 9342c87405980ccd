import math
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from lenspair.core.config import to_plain
from lenspair.model.checkpoint import (
    CHECKPOINT_FORMAT,
    build_network,
    checkpoint_config,
    load_checkpoint,
    load_model,
    load_weights,
    save_checkpoint,
    to_cpu,
)
from lenspair.model.detection.train import load_detector
from lenspair.model.errors import ModelError
from lenspair.model.training.step import Trainer
from tests.model.train_fixtures import make_checkpoint, tiny_config

pytestmark = pytest.mark.usefixtures("one_thread")


def test_round_trip_restores_every_state(tmp_path: Path) -> None:
    config = tiny_config()
    trainer = Trainer(config, torch.device("cpu"))
    batch = {
        "input": torch.rand(2, 1, 32, 32, generator=torch.Generator().manual_seed(0)),
        "target": torch.rand(2, 1, 32, 32, generator=torch.Generator().manual_seed(1)),
        "valid": torch.ones(2, 1, 32, 32),
    }
    trainer.train_step(batch)  # non-trivial optimiser state
    path = tmp_path / "ckpt" / "last.pt"
    save_checkpoint(path, {**trainer.state_dict(), "epoch": 3, "step": 7}, config)

    data = load_checkpoint(path)
    assert data["format"] == CHECKPOINT_FORMAT
    assert data["epoch"] == 3 and data["step"] == 7
    assert checkpoint_config(data) == config
    for key, value in trainer.model.state_dict().items():
        assert torch.equal(data["model"][key], value)
        assert data["model"][key].device.type == "cpu"

    other = Trainer(config, torch.device("cpu"))
    other.load_state_dict(data)
    for mine, theirs in zip(trainer.opt_g.state_dict()["state"].values(),
                            other.opt_g.state_dict()["state"].values(), strict=True):  # fmt: skip
        assert torch.equal(mine["exp_avg"], theirs["exp_avg"])
    for key, value in trainer.discriminator.state_dict().items():
        assert torch.equal(other.discriminator.state_dict()[key], value)


def test_load_model_rebuilds_the_network(tmp_path: Path) -> None:
    path = make_checkpoint(tmp_path / "a.pt")
    loaded = load_model(path)
    assert not loaded.network.training
    assert loaded.config.model == tiny_config().model
    x = torch.rand(1, 1, 33, 47)
    with torch.no_grad():
        first = loaded.network(x)[1]
        second = load_model(path).network(x)[1]
    assert first.shape == x.shape
    assert torch.equal(first, second)


def test_checkpoint_is_plain_data_for_weights_only(tmp_path: Path) -> None:
    path = make_checkpoint(tmp_path / "a.pt")
    data = torch.load(path, weights_only=True, map_location="cpu")
    assert data["config"] == to_plain(tiny_config())


def test_to_cpu_copies_nested_tensors() -> None:
    tensor = torch.ones(2, requires_grad=True)
    nested = to_cpu({"a": [tensor, (tensor, 3)], "b": "x"})
    assert nested["b"] == "x"
    assert not nested["a"][0].requires_grad
    assert nested["a"][1][1] == 3


def test_unreadable_and_foreign_files_raise(tmp_path: Path) -> None:
    with pytest.raises(ModelError, match="not found"):
        load_checkpoint(tmp_path / "missing.pt")
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(ModelError, match="not a lenspair checkpoint"):
        load_checkpoint(junk)
    junk.write_text("hello world\n")  # torch says only "101" (a KeyError) of a text file
    with pytest.raises(ModelError, match=r"neither a torch zip archive nor a torch pickle\)$"):
        load_checkpoint(junk)
    foreign = tmp_path / "foreign.pt"
    torch.save({"weights": torch.zeros(1)}, foreign)
    cut = tmp_path / "cut.pt"  # torch said "[Errno 22] Invalid argument" of it
    cut.write_bytes(foreign.read_bytes()[: foreign.stat().st_size // 2])
    with pytest.raises(ModelError, match=r"\(not a readable torch file: a torch zip archive cut"):
        load_checkpoint(cut)
    with pytest.raises(ModelError, match="not a lenspair checkpoint"):
        load_checkpoint(foreign)
    # the bundled detector is a lenspair checkpoint, of the other kind: said so
    detector = Path(__file__).parents[2] / "calib_samples" / "detector.pt"
    with pytest.raises(ModelError, match=r"an anomaly detector \(from train-detector"):
        load_checkpoint(detector)


def test_weights_that_do_not_fit_are_reported(tmp_path: Path) -> None:
    path = make_checkpoint(tmp_path / "a.pt")
    data = load_checkpoint(path)
    data["model"] = {k: v for k, v in list(data["model"].items())[1:]}
    torch.save(data, path)
    with pytest.raises(ModelError, match="do not fit"):
        load_model(path)


def test_weights_holding_nan_or_inf_are_refused_naming_the_first_tensor(tmp_path: Path) -> None:
    # a diverged run's checkpoint: restore and eval turned every frame into NaN, blaming frames
    path = make_checkpoint(tmp_path / "a.pt")
    data = load_checkpoint(path)
    name = next(k for k, v in data["model"].items() if v.is_floating_point() and v.numel() > 1)
    data["model"][name].view(-1)[:2] = torch.tensor([math.nan, math.inf])
    torch.save(data, path)
    with pytest.raises(ModelError) as info:
        load_model(path)
    message = str(info.value)
    assert message.startswith(f"{path}: its weights hold NaN or Inf: {name} (2 of ")
    assert "\n" not in message


class _Pickled:
    """A Python object that a weights-only load must refuse."""


@pytest.mark.parametrize("loader", ["checkpoint", "detector"])
@pytest.mark.parametrize("content", ["empty", "pickled-object", "garbage", "truncated"])
def test_non_checkpoint_is_one_line_without_unsafe_advice(
    tmp_path: Path, content: str, loader: str
) -> None:
    path = tmp_path / "other.pt"
    if content == "empty":
        path.write_bytes(b"")
    elif content == "pickled-object":
        torch.save({"thing": _Pickled()}, path)
    elif content == "truncated":
        torch.save({"weights": torch.zeros(64, 64)}, path)
        path.write_bytes(path.read_bytes()[:-200])
    else:
        path.write_bytes(b"PK\x03\x04 not really a zip")
    with pytest.raises(ModelError) as info:
        load_checkpoint(path) if loader == "checkpoint" else load_detector(path)
    message = str(info.value)
    kind = "lenspair checkpoint" if loader == "checkpoint" else "detector checkpoint"
    assert message.startswith(f"{path}: ") and f"not a {kind}" in message
    assert "\n" not in message and "\x1b" not in message
    assert "weights_only" not in message
    if content == "empty":
        assert "empty" in message


def test_other_width_names_the_first_differing_tensor_and_both_shapes(tmp_path: Path) -> None:
    narrow = tiny_config()
    wide = replace(narrow, model=replace(narrow.model, width=0.5))
    path = make_checkpoint(tmp_path / "narrow.pt", narrow)
    data = load_checkpoint(path)
    network = build_network(wide.model)
    expected = network.state_dict()
    first = next(k for k, v in expected.items() if v.shape != data["model"][k].shape)
    with pytest.raises(ModelError) as info:
        load_weights(network, data, path)
    message = str(info.value)
    assert first in message
    assert str(tuple(data["model"][first].shape)) in message
    assert str(tuple(expected[first].shape)) in message


def test_exported_models_are_named_for_what_they_are(tmp_path: Path) -> None:
    from lenspair.model.checkpoint import load_model
    from lenspair.model.evaluation.export import export_torchscript

    network = load_model(make_checkpoint(tmp_path / "c.pt")).network
    export_torchscript(network, 1, tmp_path / "m.ts.pt", size=(32, 48), runs=1)
    with pytest.raises(
        ModelError, match=r"m\.ts\.pt: a TorchScript model written by lenspair"
    ) as ts:
        load_checkpoint(tmp_path / "m.ts.pt")
    assert "weights_only" not in str(ts.value)
    (tmp_path / "m.onnx").write_bytes(b"\x08\x07")  # any bytes: the suffix says what it is
    with pytest.raises(ModelError, match=r"an ONNX model .*restore also runs the \.onnx"):
        load_checkpoint(tmp_path / "m.onnx")
    with pytest.raises(ModelError, match=r"shipped weights for train --init only") as shipped:
        load_checkpoint(Path("pretrained"))
    named = str(shipped.value).split("give the file: ")[1].rstrip(")").split(" and ")
    assert len(named) == 2 and all(load_checkpoint(Path(name)) for name in named)


def test_a_runtime_key_of_a_newer_version_is_passed_over_but_a_section_typo_is_not(
    tmp_path: Path,
) -> None:
    # runs trained by a newer lenspair (runtime.data_path) failed to load in the
    # process that scored them: "runtime.data_path: unknown key"
    from lenspair.core.config import dump_yaml, to_plain
    from lenspair.core.errors import ConfigError
    from lenspair.model.training.config_loading import load_run_config, run_config_from_dict

    plain = to_plain(tiny_config())
    plain["runtime"] = {"precision": "fp32", "added_by_a_later_version": [1, 2]}
    loaded = run_config_from_dict(plain)
    assert loaded.runtime is not None and loaded.runtime.precision == "fp32"
    assert loaded.train == tiny_config().train
    file = tmp_path / "config.yaml"
    file.write_text(dump_yaml(plain))
    assert load_run_config(file) == loaded
    plain["train"]["learning_rate"] = 1e-3  # a typo where it steers training: refused
    file.write_text(dump_yaml(plain))
    with pytest.raises(ConfigError, match=r"config\.yaml: train\.learning_rate: unknown key"):
        load_run_config(file)


def test_a_run_folder_given_for_a_checkpoint_names_its_best_network(tmp_path: Path) -> None:
    """It said "checkpoint not found" of a folder that is there."""
    run = tmp_path / "run"
    with pytest.raises(ModelError, match=r"run: a folder, not a checkpoint file$"):
        run.mkdir() or load_checkpoint(run)
    make_checkpoint(run / "checkpoints" / "best.pt")
    with pytest.raises(
        ModelError, match=r"a folder, not a checkpoint file; the run's best network"
    ):
        load_checkpoint(run)


def test_a_missing_recording_folder_is_named_as_missing(tmp_path: Path) -> None:
    from lenspair.model.detection.data import recording_samples
    from lenspair.model.networks.detector import DetectorSpec

    with pytest.raises(ModelError, match=r"nosuch: no such recording folder"):
        recording_samples(tmp_path / "nosuch", DetectorSpec(), 2)
