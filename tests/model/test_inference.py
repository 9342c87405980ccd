"""Restore backends and tiling: whole vs tiled, torch vs ONNX Runtime, precision routing."""

from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from lenspair.core.imagewrite import write_image
from lenspair.model.errors import ModelError
from lenspair.model.inference.backends import (
    OnnxBackend,
    TorchBackend,
    open_backend,
    resolve_precision,
)
from lenspair.model.inference.pipeline import restore_input
from lenspair.model.inference.restore_options import RestoreOptions
from lenspair.model.inference.tiling import (
    from_batch,
    run_backend,
    run_tiled,
    tile_starts,
    to_batch,
)
from tests.images import texture
from tests.model.train_fixtures import make_checkpoint

CPU = torch.device("cpu")


class Pointwise:
    """A context-free backend (a fixed tone curve): tiling must not change its output."""

    channels = 1
    fixed_size: tuple[int, int] | None = None
    description = "pointwise"

    def __init__(self) -> None:
        self.calls: list[tuple[int, ...]] = []

    def __call__(self, batch: np.ndarray) -> np.ndarray:
        self.calls.append(batch.shape)
        return np.asarray(np.sqrt(batch), dtype=np.float32)


@pytest.fixture
def backend(tmp_path: Path, one_thread: None) -> TorchBackend:
    loaded = open_backend(make_checkpoint(tmp_path / "ck.pt"), CPU, "fp32")
    assert isinstance(loaded, TorchBackend)
    return loaded


@given(
    length=st.integers(8, 700),
    tile=st.integers(16, 300),
    overlap=st.integers(0, 64),
)
def test_tile_starts_cover_with_overlap(length: int, tile: int, overlap: int) -> None:
    overlap = min(overlap, tile - 1)
    starts = tile_starts(length, tile, overlap)
    # the last tile is flush with the border: it ran past it into a mirror image,
    # which the norms took for content
    assert starts[0] == 0 and starts[-1] + tile == max(length, tile)
    steps = np.diff(starts)
    assert np.all(steps > 0) and np.all(steps <= tile - overlap)
    # one step but the last (shorter, to end flush): the pooling grid stays aligned
    assert len(set(steps[:-1].tolist())) <= 1 and np.all(steps[-1:] <= steps[:1])


@settings(max_examples=25, deadline=None)
@given(
    height=st.integers(8, 90),
    width=st.integers(8, 90),
    tile=st.integers(16, 64),
    overlap=st.integers(0, 40),
)
def test_tiling_a_context_free_network_is_exact(
    height: int, width: int, tile: int, overlap: int
) -> None:
    """Blend weights are a partition of unity: no seam, no pixel left out, any size."""
    rng = np.random.default_rng(height * 1000 + width)
    batch = rng.random((2, 1, height, width), dtype=np.float32)
    tiled = run_tiled(Pointwise(), batch, (tile, tile), overlap)
    np.testing.assert_allclose(tiled, np.sqrt(batch), atol=1e-5)  # float32 blend


def test_tiled_and_whole_agree_within_tolerance(backend: TorchBackend) -> None:
    """The network normalises each tile by its own statistics (instance norm).

    Stated tolerance on this untrained test network: mean |tiled - whole| at
    most 0.6 x the network's own mean change to the image (measured ~0.5 x), and
    no seam: the step across tile boundaries is no larger than elsewhere.
    """
    image = texture((128, 160), seed=3)
    batch = image[None, None].astype(np.float32)
    whole = run_backend(backend, batch)
    tiled = run_backend(backend, batch, tile=64, overlap=32)
    change = float(np.abs(whole - batch).mean())
    assert change > 0.01  # the network does something
    assert float(np.abs(tiled - whole).mean()) <= 0.6 * change
    steps = np.abs(np.diff(tiled[0, 0], axis=1)).mean(axis=0)
    reference = np.abs(np.diff(whole[0, 0], axis=1)).mean(axis=0)
    boundaries = [63, 95, 127]  # last column of a tile, or first of the next's ramp
    assert np.all(steps[boundaries] <= reference[boundaries] + 0.05)


def test_odd_sizes_are_restored_at_their_size(backend: TorchBackend) -> None:
    """Not multiples of 4: padded and cropped back inside the network, as eval does."""
    image = texture((37, 53), seed=1)
    batch = image[None, None].astype(np.float32)
    output = run_backend(backend, batch)
    assert output.shape == batch.shape
    with torch.inference_mode():
        expected = backend.network(torch.from_numpy(batch))[1].clamp(0, 1).numpy()
    np.testing.assert_allclose(output, expected, atol=1e-5)  # channels-last vs NCHW


def test_onnx_matches_torch(tmp_path: Path, backend: TorchBackend) -> None:
    """ONNX Runtime and torch agree to 1e-4 (max abs, [0, 1] range) at every size."""
    from lenspair.model.evaluation.export import export_onnx

    export_onnx(backend.network, 1, tmp_path / "m.onnx", size=(32, 48), runs=1)
    onnx = open_backend(tmp_path / "m.onnx", CPU, "fp32")
    assert isinstance(onnx, OnnxBackend) and onnx.fixed_size is None
    rng = np.random.default_rng(0)
    batch = rng.random((3, 1, 32, 48), dtype=np.float32)
    np.testing.assert_allclose(onnx(batch), backend(batch), atol=1e-4)
    # another size runs whole, as the checkpoint does: it ran on tiles of the exported
    # size (up to 109 8-bit codes from the checkpoint at 752x480)
    large = texture((64, 96), seed=2)[None, None].astype(np.float32)
    np.testing.assert_allclose(run_backend(onnx, large), run_backend(backend, large), atol=1e-4)
    # and --tile tiles it as it tiles the checkpoint
    image = tmp_path / "in.png"
    write_image(image, (large[0, 0] * 255).astype(np.uint8))
    report = restore_input(image, tmp_path / "out", onnx, RestoreOptions(tile=48))
    assert report.restored == 1 and report.forced_tile is None
    np.testing.assert_allclose(
        run_backend(onnx, large, tile=48), run_backend(backend, large, tile=48), atol=1e-4
    )
    with pytest.raises(ModelError, match="at least 16 pixels"):
        run_backend(backend, large[..., :12, :12], tile=8)  # its docstring's promise


def test_integer_round_trip_keeps_dtype_and_channels() -> None:
    rng = np.random.default_rng(0)
    for dtype in (np.uint8, np.uint16):
        top = np.iinfo(dtype).max
        mono = rng.integers(0, top, (9, 11), dtype=dtype, endpoint=True)
        rgb = rng.integers(0, top, (9, 11, 3), dtype=dtype, endpoint=True)
        for image in (mono, rgb):
            (back,) = from_batch(to_batch([image]), image.dtype, image.ndim == 2)
            assert back.dtype == image.dtype and back.shape == image.shape
            np.testing.assert_array_equal(back, image)
    # a uint8 frame batched with uint16 ones was scaled by their 65535: refused
    eight = np.full((4, 5), 255, np.uint8)
    sixteen = np.full((4, 5), 65535, np.uint16)
    with pytest.raises(ModelError, match=r"different bit depths \(uint16, uint8\)"):
        to_batch([sixteen, eight])
    with pytest.raises(ModelError, match="different shapes"):
        to_batch([eight, eight[:3]])


def test_channel_mismatch_is_refused() -> None:
    rgb = np.zeros((1, 3, 16, 16), dtype=np.float32)
    with pytest.raises(ModelError, match="takes 1 channel"):
        run_backend(Pointwise(), rgb)


def test_bf16_stays_close_to_fp32(backend: TorchBackend) -> None:
    """bf16 autocast (8 mantissa bits): within 0.05 max abs of fp32 on [0, 1] images."""
    bf16 = TorchBackend(backend.network, 1, CPU, "bf16")
    batch = texture((32, 48), seed=5)[None, None].astype(np.float32)
    assert float(np.abs(bf16(batch) - backend(batch)).max()) < 0.05


def test_precision_auto_follows_the_hardware(monkeypatch: pytest.MonkeyPatch) -> None:
    import lenspair.model.precision as precision

    def probe(flags: frozenset[str]) -> precision.Probe:
        return lambda device: precision.Hardware("cpu", "test CPU", flags, "mock")

    native = probe(frozenset({"avx512_bf16", "avx512_vnni"}))
    emulated = probe(frozenset({"avx512f", "avx512_vnni"}))
    for speed, expected in ((1.8, "bf16"), (0.6, "fp32")):  # native, measured faster / slower
        monkeypatch.setattr(
            "lenspair.model.inference.backends.choose_precision",
            lambda r, d, t, s=speed: precision.choose_precision(
                r, d, t, probe=native, bf16_speed=lambda task: s
            ),
        )
        assert resolve_precision("auto", CPU) == expected
    monkeypatch.setattr(
        "lenspair.model.inference.backends.choose_precision",
        lambda r, d, t: precision.choose_precision(r, d, t, probe=emulated),
    )
    assert resolve_precision("auto", CPU) == "fp32"  # emulated bf16 is never auto
    assert resolve_precision("bf16", CPU) == "bf16"  # asked for explicitly: honoured
    with pytest.raises(ModelError, match="--precision"):
        resolve_precision("int4", CPU)


def test_open_backend_takes_a_device_name(tmp_path: Path) -> None:
    # load_model and load_detector take "cpu"; open_backend raised AttributeError
    assert open_backend(make_checkpoint(tmp_path / "ck.pt"), "cpu", "fp32").channels == 1


def test_a_backend_refuses_batches_it_would_misread(backend: TorchBackend) -> None:
    frames = np.full((1, 1, 16, 16), 128, np.uint8)  # 0..255 ran unscaled: white output
    with pytest.raises(ModelError, match="a batch of uint8: expected float32"):
        backend(frames)
    with pytest.raises(ModelError, match=r"shape \(1, 16, 16\): expected \(N, 1, H, W\)"):
        backend(np.zeros((1, 16, 16), np.float32))  # a traceback about memory formats
    assert backend(np.zeros((1, 1, 16, 16), np.float32)).shape == (1, 1, 16, 16)
