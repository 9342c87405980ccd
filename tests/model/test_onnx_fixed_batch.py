"""ONNX models of a fixed batch size (other tools' exports) and ONNX Runtime's refusals.

The models are built node by node (``out = 0.5 * x + 0.25``, a context-free
restoring network): tiny and fast, and their output is known frame by frame.
"""

from pathlib import Path

import numpy as np
import pytest
import torch

from lenspair.core.imagewrite import write_image
from lenspair.model.errors import ModelError
from lenspair.model.inference.backends import OnnxBackend
from lenspair.model.inference.pipeline import restore_input
from lenspair.model.inference.restore_options import RestoreOptions
from lenspair.model.inference.restorer import Restorer

onnx = pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")
helper, TensorProto = onnx.helper, onnx.TensorProto

CPU = torch.device("cpu")


def _affine_model(
    path: Path, shape: list[int | str], out_shape: list[int | str] | None = None
) -> Path:
    """A restoring model ``0.5 * x + 0.25`` whose input is declared ``shape``.

    Its output is declared ``out_shape`` (default: ``shape``).
    """
    half = helper.make_tensor("half", TensorProto.FLOAT, [], [0.5])
    quarter = helper.make_tensor("quarter", TensorProto.FLOAT, [], [0.25])
    nodes = [
        helper.make_node("Mul", ["image", "half"], ["scaled"]),
        helper.make_node("Add", ["scaled", "quarter"], ["restored"]),
    ]
    graph = helper.make_graph(
        nodes,
        "affine",
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, shape)],
        [helper.make_tensor_value_info("restored", TensorProto.FLOAT, out_shape or shape)],
        initializer=[half, quarter],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8  # any onnxruntime of the last years reads it
    onnx.save(model, str(path))
    return path


class _Counting:
    """An ONNX Runtime session that records the batch size of every call."""

    def __init__(self, session: object) -> None:
        self.session = session
        self.sizes: list[int] = []

    def run(self, names: object, feed: dict[str, np.ndarray]) -> list[np.ndarray]:
        (batch,) = feed.values()
        self.sizes.append(len(batch))
        return self.session.run(names, feed)  # type: ignore[attr-defined,no-any-return]


def _frames(count: int, height: int, width: int, channels: int = 1) -> np.ndarray:
    generator = np.random.default_rng(count * 1000 + height)
    return generator.random((count, channels, height, width), dtype=np.float32)


def test_a_model_of_batch_one_runs_any_batch_one_frame_a_call(tmp_path: Path) -> None:
    """A batch of 4 to a model fixed at batch 1 raised onnxruntime's InvalidArgument."""
    backend = OnnxBackend(_affine_model(tmp_path / "b1.onnx", [1, 1, "h", "w"]), CPU)
    counting = _Counting(backend.session)
    backend.session = counting  # type: ignore[assignment]
    frames = _frames(4, 24, 40)
    restored = backend(frames)
    assert counting.sizes == [1, 1, 1, 1]
    np.testing.assert_allclose(restored, 0.5 * frames + 0.25, atol=1e-6)  # each in its place


def test_a_model_of_batch_two_fills_its_last_piece_and_drops_the_filling(tmp_path: Path) -> None:
    backend = OnnxBackend(_affine_model(tmp_path / "b2.onnx", [2, 3, "h", "w"]), CPU)
    counting = _Counting(backend.session)
    backend.session = counting  # type: ignore[assignment]
    frames = _frames(3, 16, 20, channels=3)
    restored = backend(frames)
    assert counting.sizes == [2, 2] and restored.shape == frames.shape
    np.testing.assert_allclose(restored, 0.5 * frames + 0.25, atol=1e-6)


def test_restore_with_batch_size_4_on_a_batch_one_model_restores_every_frame(
    tmp_path: Path,
) -> None:
    """``restore --batch-size 4`` ended with onnxruntime's traceback, OUT half written."""
    model = _affine_model(tmp_path / "b1.onnx", [1, 1, "h", "w"])
    source = tmp_path / "in"
    generator = np.random.default_rng(0)
    images = [generator.integers(0, 256, (24, 40), dtype=np.uint8) for _ in range(5)]
    for index, image in enumerate(images):
        write_image(source / f"f{index}.png", image)
    backend = OnnxBackend(model, CPU)
    report = restore_input(source, tmp_path / "out", backend, RestoreOptions(batch_size=4))
    assert (report.restored, report.failed) == (5, 0)


def test_a_model_of_one_size_and_batch_one_runs_the_tiles_of_a_larger_frame(
    tmp_path: Path,
) -> None:
    """Tiles go to the network several a call: Restorer raised onnxruntime's InvalidArgument
    for a model fixed at 1x1x32x48, whatever the frame's batch."""
    restorer = Restorer(_affine_model(tmp_path / "fixed.onnx", [1, 1, 32, 48]), device="cpu")
    frame = np.random.default_rng(1).integers(0, 256, (100, 150), dtype=np.uint8)
    restored = restorer(frame)
    expected = np.rint(frame.astype(np.float64) * 0.5 + 63.75)  # 0.5 * x + 0.25, in codes
    assert restored.shape == frame.shape and restored.dtype == np.uint8
    assert np.abs(restored.astype(np.float64) - expected).max() <= 1


def test_a_batch_onnx_runtime_refuses_is_a_one_line_model_error_and_fails_its_frames(
    tmp_path: Path,
) -> None:
    """A model that fixes its height (not both sides: not tiled) refused a frame of another
    height with onnxruntime's own exception: Restorer raised it, restore ended with it."""
    model = _affine_model(tmp_path / "h32.onnx", ["N", 1, 32, "w"])
    restorer = Restorer(model, device="cpu")
    assert restorer(np.zeros((32, 48), np.uint8)).shape == (32, 48)
    with pytest.raises(ModelError) as refused:
        restorer(np.zeros((40, 48), np.uint8))
    message = str(refused.value)
    assert "\n" not in message and message.startswith(f"{model}: ")
    assert "(1, 1, 40, 48)" in message and "['N', 1, 32, 'w']" in message
    source = tmp_path / "in"
    write_image(source / "a.png", np.full((32, 48), 10, np.uint8))
    write_image(source / "b.png", np.full((40, 48), 20, np.uint8))
    write_image(source / "c.png", np.full((32, 48), 30, np.uint8))
    report = restore_input(source, tmp_path / "out", OnnxBackend(model, CPU), RestoreOptions())
    assert (report.restored, report.failed) == (2, 1)
    (problem,) = [p for p in report.problems if p["frame"] == "b.png"]
    assert str(model) in problem["reason"] and "(1, 1, 40, 48)" in problem["reason"]


def test_a_model_whose_output_channels_are_named_not_numbered_runs(tmp_path: Path) -> None:
    """torch's classic exporter with dynamic axes names the output's channel axis
    (``Addrestored_dim_1``): the model was refused as "not a restoring model"."""
    import warnings  # the classic exporter's deprecation warning is not this test's

    from lenspair.model.checkpoint import load_model
    from tests.model.train_fixtures import make_checkpoint

    network = load_model(make_checkpoint(tmp_path / "tiny.pt"), CPU).network.eval()

    class _Restored(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.network = network  # a submodule: its weights are the export's parameters

        def forward(self, image: torch.Tensor) -> torch.Tensor:
            return self.network(image)[1]  # type: ignore[no-any-return]

    axes = {0: "n", 2: "h", 3: "w"}
    model = tmp_path / "classic.onnx"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            _Restored(), (torch.rand(1, 1, 32, 40),), str(model), input_names=["image"],
            output_names=["restored"], dynamo=False, opset_version=17,
            dynamic_axes={"image": axes, "restored": axes},
        )  # fmt: skip
    restorer = Restorer(model, device="cpu")
    frame = np.random.default_rng(2).integers(0, 256, (24, 40), dtype=np.uint8)
    with torch.no_grad():
        expected = _Restored()(torch.from_numpy(frame / 255.0).float()[None, None])
    restored = restorer(frame)
    assert restored.shape == frame.shape
    assert np.abs(restored - np.rint(expected[0, 0].numpy() * 255)).max() <= 1
    # a number that differs is still refused: a mono input whose output is three channels
    node = helper.make_node("Concat", ["image"] * 3, ["restored"], axis=1)
    graph = helper.make_graph(
        [node],
        "three",
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, ["n", 1, "h", "w"])],
        [helper.make_tensor_value_info("restored", TensorProto.FLOAT, ["n", 3, "h", "w"])],
    )
    three = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    three.ir_version = 8
    onnx.save(three, str(tmp_path / "three.onnx"))
    with pytest.raises(ModelError, match=r"not \(N, 1, H, W\) like its input"):
        Restorer(tmp_path / "three.onnx", device="cpu")
