"""The flat-frame guard in exported models: every size judged as the eager network judges it.

An export traces the generator at one size; what the guard computes from the
shape must stay symbolic, and its sums must not lose the deviation they
measure on large frames (ONNX Runtime sums in its own order).
"""

import numpy as np
import onnxruntime as ort
import pytest
import torch
from torch import Tensor, nn

from lenspair.model.networks.flat_frames import flat_keep


class _Keep(nn.Module):
    def forward(self, x: Tensor) -> Tensor:
        keep = flat_keep(x)
        assert keep is not None  # traced: always the mask
        return keep


def _speck(height: int, width: int, codes: float) -> np.ndarray:
    """Mid-grey ``(1, 1, H, W)`` with one pixel ``codes`` 8-bit codes brighter (a hot pixel)."""
    frame = np.full((1, 1, height, width), 128 / 255, np.float32)
    frame[..., height // 2, width // 2] += codes / 255
    return frame


def _eager(frame: np.ndarray) -> float:
    keep = flat_keep(torch.from_numpy(frame))
    return 1.0 if keep is None else float(keep.item())


@pytest.fixture(scope="module")
def onnx_keep(tmp_path_factory: pytest.TempPathFactory) -> ort.InferenceSession:
    """``flat_keep`` exported as ``lenspair export`` exports (dynamo, dynamic H and W) at 64x48."""
    path = tmp_path_factory.mktemp("flat") / "keep.onnx"
    height, width = torch.export.Dim("height", min=8), torch.export.Dim("width", min=8)
    torch.onnx.export(
        _Keep(),
        (torch.rand(1, 1, 48, 64),),
        str(path),
        dynamo=True,
        input_names=["x"],
        dynamic_shapes={"x": {2: height, 3: width}},
    )
    return ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])


@pytest.mark.parametrize(
    ("height", "width", "codes"),
    [(192, 256, 30.0), (1080, 1920, 4.0), (1080, 1920, 60.0), (16, 16, 8.0)],
)
def test_an_exported_guard_judges_every_size_as_the_eager_one(
    onnx_keep: ort.InferenceSession, height: int, width: int, codes: float
) -> None:
    # the pixel count was a Python float, frozen at the traced size: a 256x192 frame with
    # a 30-code hot pixel read 4x its RMS (keep 0.44 where eager says 0: blotched), and
    # ONNX Runtime's mean of a 1080p frame near 0.5 was off by 0.4 codes (keep 0.31)
    frame = _speck(height, width, codes)
    (exported,) = onnx_keep.run(None, {"x": frame})
    assert float(exported.ravel()[0]) == pytest.approx(_eager(frame), abs=0.02)


def test_an_exported_guard_leaves_low_texture_crops_alone(
    onnx_keep: ort.InferenceSession,
) -> None:
    # small crops of low texture read too little RMS through the frozen count (the traced
    # frame's), so the export called them flat and zeroed their norms: 4-54 codes off
    rng = np.random.default_rng(0)
    for side in (8, 16, 33):
        frame = (0.5 + rng.normal(0, 1.5 / 255, (1, 1, side, side))).astype(np.float32)
        (exported,) = onnx_keep.run(None, {"x": frame})
        assert float(exported.ravel()[0]) == pytest.approx(_eager(frame), abs=0.02)
