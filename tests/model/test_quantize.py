"""int8 calibration images (:mod:`lenspair.model.evaluation.quantize`)."""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from lenspair.model.evaluation.quantize import calibration_images


class _Pairs:
    """A pair source of the given inputs, listed from ``root``."""

    def __init__(self, root: Path, inputs: list[np.ndarray]) -> None:
        self.root = root
        self.inputs = inputs

    def __len__(self) -> int:
        return len(self.inputs)

    def __getitem__(self, index: int) -> SimpleNamespace:
        return SimpleNamespace(input=self.inputs[index], name=f"{index:03d}.png")


def _grey_warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [
        r.getMessage() for r in caplog.records if "calibration images are grey" in r.getMessage()
    ]


def test_grey_images_calibrating_a_colour_network_are_said_once_naming_the_folder(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # the grey channel was copied into all three without a word, and int8 checked on them
    rng = np.random.default_rng(0)
    grey = [(rng.random((20, 30)) * 255).astype(np.uint8) for _ in range(4)]
    colour = [(rng.random((20, 30, 3)) * 255).astype(np.uint8) for _ in range(4)]
    root = tmp_path / "calibration"
    with caplog.at_level("WARNING"):
        images = calibration_images(_Pairs(root, grey), 3, (16, 24))
    assert [image.shape for image in images] == [(1, 3, 16, 24)] * 4
    said = _grey_warnings(caplog)
    assert len(said) == 1, said
    assert said[0].startswith(f"{root}: int8 calibration: the calibration images are grey")
    assert "network takes colour" in said[0] and "\n" not in said[0]

    caplog.clear()
    with caplog.at_level("WARNING"):
        calibration_images(_Pairs(root, [grey[0], *colour[1:]]), 3, (16, 24))
    assert _grey_warnings(caplog) == [
        f"{root}: int8 calibration: 1 of the 4 calibration images are grey and the network "
        "takes colour (RGB): the ranges of colour frames were not seen, so colour frames may "
        "clip or lose precision; calibrate on colour images"
    ]

    caplog.clear()
    with caplog.at_level("WARNING"):
        calibration_images(_Pairs(root, colour), 3, (16, 24))  # colour for colour
        calibration_images(_Pairs(root, grey), 1, (16, 24))  # grey for grey
    assert _grey_warnings(caplog) == []
