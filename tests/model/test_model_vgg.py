"""VGG19 features: torchvision-compatible keys, offline loading, clear errors."""

from pathlib import Path

import pytest
import torch

from lenspair.model.errors import ModelError
from lenspair.model.networks.vgg import SLICE_ENDS, VGG19_WEIGHTS_ENV, VGG19Features, load_vgg19

# torchvision's vgg19().features: conv layer index -> (out, in) channels.
TORCHVISION_CONVS = {
    0: (64, 3), 2: (64, 64), 5: (128, 64), 7: (128, 128), 10: (256, 128), 12: (256, 256),
    14: (256, 256), 16: (256, 256), 19: (512, 256), 21: (512, 512), 23: (512, 512),
    25: (512, 512), 28: (512, 512), 30: (512, 512), 32: (512, 512), 34: (512, 512),
}  # fmt: skip


def _torchvision_style_state(seed: int = 0) -> dict[str, torch.Tensor]:
    """What torch.save(torchvision.models.vgg19().state_dict()) holds (small classifier)."""
    generator = torch.Generator().manual_seed(seed)
    state = {}
    for index, (out_channels, in_channels) in TORCHVISION_CONVS.items():
        state[f"features.{index}.weight"] = (
            torch.randn(out_channels, in_channels, 3, 3, generator=generator) * 0.01
        )
        state[f"features.{index}.bias"] = torch.randn(out_channels, generator=generator) * 0.01
    state["classifier.0.weight"] = torch.zeros(4, 8)
    state["classifier.0.bias"] = torch.zeros(4)
    return state


def test_keys_match_torchvision_layout() -> None:
    keys = set(VGG19Features().state_dict())
    expected = {
        f"features.{i}.{p}" for i in TORCHVISION_CONVS if i < 30 for p in ("weight", "bias")
    }
    assert keys == expected
    assert SLICE_ENDS["relu5_1"] == 30


def test_load_from_file_and_from_environment(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    state = _torchvision_style_state()
    path = tmp_path / "vgg19-test.pth"
    torch.save(state, path)
    loaded = load_vgg19(path)
    assert loaded is not None
    assert torch.equal(loaded.features[28].weight, state["features.28.weight"])
    assert not any(p.requires_grad for p in loaded.parameters())
    loaded.train()
    assert not loaded.training
    outputs = loaded(torch.rand(1, 1, 32, 32))
    assert [o.shape[1] for o in outputs] == [64, 128, 256, 512, 512]
    assert [o.shape[-1] for o in outputs] == [32, 16, 8, 4, 2]

    monkeypatch.setenv(VGG19_WEIGHTS_ENV, str(path))
    from_env = load_vgg19(None)
    assert from_env is not None
    assert torch.equal(from_env.features[0].bias, state["features.0.bias"])


def test_no_file_means_none(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(VGG19_WEIGHTS_ENV, raising=False)
    assert load_vgg19(None) is None
    monkeypatch.setenv(VGG19_WEIGHTS_ENV, "  ")
    assert load_vgg19(None) is None


def test_bare_features_state_dict_loads(tmp_path: Path) -> None:
    state = {
        k.removeprefix("features."): v
        for k, v in _torchvision_style_state().items()
        if k.startswith("features.")
    }
    path = tmp_path / "features.pth"
    torch.save(state, path)
    assert load_vgg19(path) is not None


def test_clear_errors(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(ModelError, match="no such file"):
        load_vgg19(tmp_path / "missing.pth")
    monkeypatch.setenv(VGG19_WEIGHTS_ENV, str(tmp_path / "missing.pth"))
    with pytest.raises(ModelError, match=VGG19_WEIGHTS_ENV):
        load_vgg19(None)

    state = _torchvision_style_state()
    del state["features.10.weight"]
    state["features.0.weight"] = torch.zeros(64, 1, 3, 3)
    path = tmp_path / "wrong.pth"
    torch.save(state, path)
    with pytest.raises(ModelError, match=r"missing keys features\.10\.weight") as info:
        load_vgg19(path)
    assert "features.0.weight: expected (64, 3, 3, 3), got (64, 1, 3, 3)" in str(info.value)

    other = tmp_path / "resnet.pth"
    torch.save({"conv1.weight": torch.zeros(1), "fc.bias": torch.zeros(1)}, other)
    with pytest.raises(ModelError, match="not a torchvision VGG19 state dict"):
        load_vgg19(other)

    garbage = tmp_path / "garbage.pth"
    garbage.write_bytes(b"not a torch file")
    with pytest.raises(ModelError, match="not a VGG19 state dict"):
        load_vgg19(garbage)

    listed = tmp_path / "list.pth"
    torch.save([torch.zeros(1)], listed)
    with pytest.raises(ModelError, match="not a dict"):
        load_vgg19(listed)


def test_wrong_input_channels() -> None:
    with pytest.raises(ModelError, match="1 or 3"):
        VGG19Features()(torch.rand(1, 2, 16, 16))


def test_training_names_where_a_bad_weights_file_came_from(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # train resolved the variable itself, so the error named /nonexist without saying why
    from dataclasses import replace

    from lenspair.model.training.step import Trainer
    from tests.model.train_fixtures import tiny_config

    config = tiny_config()
    config = replace(config, loss=replace(config.loss, perceptual=0.1))
    monkeypatch.setenv(VGG19_WEIGHTS_ENV, str(tmp_path / "missing.pth"))
    with pytest.raises(ModelError, match=rf"missing\.pth \(from \${VGG19_WEIGHTS_ENV}\)"):
        Trainer(config, torch.device("cpu"))
    junk = tmp_path / "junk.pth"
    junk.write_text("junk\n")  # it said "...weights_only=True: 174812789"
    monkeypatch.setenv(VGG19_WEIGHTS_ENV, str(junk))
    with pytest.raises(ModelError) as caught:
        Trainer(config, torch.device("cpu"))
    assert str(caught.value) == (
        f"VGG19 weights (from ${VGG19_WEIGHTS_ENV}): {junk}: not a VGG19 state dict (not a "
        "readable torch file: neither a torch zip archive nor a torch pickle)"
    )
    with pytest.raises(ModelError, match=rf"^VGG19 weights: {junk}: not a VGG19 state dict"):
        load_vgg19(junk)
