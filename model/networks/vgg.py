"""VGG19 features for the perceptual loss, loading torchvision-format weights offline.

Nothing is ever downloaded. :class:`VGG19Features` reproduces torchvision's
``vgg19().features`` layer indices up to ``relu5_1`` (index 29), so its state
dict keys are torchvision's (``features.0.weight``, ``features.0.bias``, ...,
``features.28.bias``). A user who has torchvision's ImageNet file (e.g.
``vgg19-dcbb9e9d.pth``) points :func:`load_vgg19` at it, or sets the
environment variable :data:`VGG19_WEIGHTS_ENV`; the classifier keys and the
features past ``relu5_1`` are ignored. The file is read with
``torch.load(weights_only=True)``: a state dict of tensors, never pickled code.

Without a file the caller trains without the perceptual term (and says so).
"""

import os
from pathlib import Path

import torch
from torch import Tensor, nn

from lenspair.core.config import config_path
from lenspair.model.checkpoint import read_torch_file
from lenspair.model.errors import ModelError

VGG19_WEIGHTS_ENV = "LENSPAIR_VGG19_WEIGHTS"
"""Environment variable naming a torchvision-format VGG19 state-dict file."""

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)

_CONFIG: tuple[int | str, ...] = (
    64, 64, "M", 128, 128, "M", 256, 256, 256, 256, "M", 512, 512, 512, 512, "M", 512,
)  # fmt: skip
"""torchvision's VGG19 ("E") configuration, cut after the first conv of block 5."""

SLICE_ENDS: dict[str, int] = {
    "relu1_1": 2,
    "relu2_1": 7,
    "relu3_1": 12,
    "relu4_1": 21,
    "relu5_1": 30,
}
"""Exclusive end index in ``features`` of each tapped ReLU (pix2pixHD's slices)."""


class VGG19Features(nn.Module):
    """Frozen VGG19 ``features`` up to ``relu5_1``, tapping the five ``relu*_1`` outputs.

    Input: ``(N, 1 or 3, H, W)`` float in [0, 1]; mono is repeated to RGB and
    the batch is ImageNet-normalised inside. Output: the five feature maps
    ``relu1_1`` (64 ch, full size) ... ``relu5_1`` (512 ch, 1/16 size).
    Parameters never require gradients; the module stays in eval mode.
    """

    mean: Tensor
    std: Tensor

    def __init__(self) -> None:
        """Create the layers with random weights (load real ones with :func:`load_vgg19`)."""
        super().__init__()
        layers: list[nn.Module] = []
        in_channels = 3
        for item in _CONFIG:
            if item == "M":
                layers.append(nn.MaxPool2d(kernel_size=2, stride=2))
            else:
                assert isinstance(item, int)
                layers += [nn.Conv2d(in_channels, item, 3, padding=1), nn.ReLU(inplace=True)]
                in_channels = item
        self.features = nn.Sequential(*layers)
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)
        self.requires_grad_(False)
        self.eval()

    def train(self, mode: bool = True) -> "VGG19Features":
        """Stay in eval mode whatever is asked (the network is a fixed feature extractor)."""
        del mode
        return super().train(False)

    def forward(self, x: Tensor) -> list[Tensor]:
        """Extract the five ``relu*_1`` feature maps.

        Args:
            x: ``(N, 1 or 3, H, W)`` float in [0, 1].

        Returns:
            ``[relu1_1, relu2_1, relu3_1, relu4_1, relu5_1]``.

        Raises:
            ModelError: if ``x`` has neither 1 nor 3 channels.
        """
        if x.ndim != 4 or x.shape[1] not in (1, 3):
            raise ModelError(f"VGG19 input: expected (N, 1 or 3, H, W), got {tuple(x.shape)}")
        if x.shape[1] == 1:
            x = x.expand(-1, 3, -1, -1)
        x = (x - self.mean.to(x.dtype)) / self.std.to(x.dtype)
        outputs = []
        start = 0
        for end in SLICE_ENDS.values():
            for index in range(start, end):
                x = self.features[index](x)
            outputs.append(x)
            start = end
        return outputs


def load_vgg19(path: Path | None = None) -> VGG19Features | None:
    """Load VGG19 features from a torchvision-format state-dict file, if one is given.

    Args:
        path: the ``.pth`` file; when ``None``, the environment variable
            :data:`VGG19_WEIGHTS_ENV` is read instead.

    Returns:
        The frozen network on the CPU, or ``None`` when neither ``path`` nor
        the environment variable names a file (train without the perceptual term).

    Raises:
        ModelError: if the named file is missing, is not a ``weights_only``
            state dict, or lacks a key or has a wrong shape (all listed).
    """
    if path is None:
        value = os.environ.get(VGG19_WEIGHTS_ENV, "").strip()
        if not value:
            return None
        path = config_path(value)
        origin = f"{path} (from ${VGG19_WEIGHTS_ENV})"
    else:
        origin = str(path)
    if not path.is_file():
        raise ModelError(f"VGG19 weights: no such file {origin}")
    try:
        state = read_torch_file(path, "VGG19 state dict")
    except ModelError as exc:  # names the file; and where its name came from
        source = f" (from ${VGG19_WEIGHTS_ENV})" if origin != str(path) else ""
        raise ModelError(f"VGG19 weights{source}: {exc}") from None
    network = VGG19Features()
    network.load_state_dict(_select_features(state, network, origin))
    return network


def _select_features(state: object, network: VGG19Features, origin: str) -> dict[str, Tensor]:
    """Pick and check the ``features.*`` entries ``network`` needs from a loaded file."""
    if not isinstance(state, dict):
        raise ModelError(f"VGG19 weights: {origin} holds a {type(state).__name__}, not a dict")
    if state and not any(str(key).startswith("features.") for key in state):
        # A bare ``vgg.features.state_dict()`` has keys "0.weight", ...
        state = {f"features.{key}": value for key, value in state.items()}
    expected = network.state_dict()
    missing = [key for key in expected if key not in state]
    wrong = [
        f"{key}: expected {tuple(expected[key].shape)}, got {_describe(state[key])}"
        for key in expected
        if key in state
        and not (isinstance(state[key], Tensor) and state[key].shape == expected[key].shape)
    ]
    if missing or wrong:
        problems = []
        if missing:
            problems.append(f"missing keys {', '.join(missing)}")
        if wrong:
            problems.append(f"wrong shapes {'; '.join(wrong)}")
        raise ModelError(
            f"VGG19 weights: {origin} is not a torchvision VGG19 state dict: " + "; ".join(problems)
        )
    return {key: state[key].float() for key in expected}


def _describe(value: object) -> str:
    """Shape of a tensor, or the type name of anything else."""
    return str(tuple(value.shape)) if isinstance(value, Tensor) else type(value).__name__
