"""Restorer: the network in a user's own process gives what ``lenspair restore`` writes."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from lenspair.cli import main
from lenspair.core.bitdepth import narrow, widen
from lenspair.core.imageio import read_image
from lenspair.core.imagewrite import write_image
from lenspair.model.checkpoint import WEIGHTS_DIR, WEIGHTS_FILES
from lenspair.model.errors import ModelError
from lenspair.model.inference.restorer import Restorer
from lenspair.model.training.config import RunConfig
from tests.images import texture
from tests.model.train_fixtures import make_checkpoint, tiny_config


@pytest.fixture
def checkpoint(tmp_path: Path, one_thread: None) -> Path:
    return make_checkpoint(tmp_path / "ck.pt")


def _restored_by_command(
    tmp_path: Path, model: Path, frames: list[np.ndarray], *options: str
) -> list[np.ndarray]:
    folder, out = tmp_path / "frames", tmp_path / "out"
    for index, frame in enumerate(frames):
        write_image(folder / f"{index}.png", frame)
    argv = [str(model), str(folder), "--out", str(out), "--precision", "fp32", *options]
    assert main(["restore", *argv]) == 0
    return [read_image(out / f"{index}.png") for index in range(len(frames))]


def test_a_frame_restored_in_process_is_the_frame_restore_writes(
    tmp_path: Path, checkpoint: Path
) -> None:
    frames = [(texture((37, 53), seed=seed) * 255).astype(np.uint8) for seed in range(3)]
    restorer = Restorer(checkpoint, device="cpu", precision="fp32")
    assert restorer.channels == 1 and str(checkpoint) in restorer.description
    mine = [restorer(frame) for frame in frames]
    assert all(out.shape == (37, 53) and out.dtype == np.uint8 for out in mine)
    assert any(not np.array_equal(out, frame) for out, frame in zip(mine, frames, strict=True))
    for out, written in zip(mine, _restored_by_command(tmp_path, checkpoint, frames), strict=True):
        np.testing.assert_array_equal(out, written)
    assert all(
        np.array_equal(a, b) for a, b in zip(restorer.restore_batch(frames[:1]), mine, strict=False)
    )
    same = [f for f in frames if f.shape == frames[0].shape]  # a generator is a batch too
    batch = restorer.restore_batch(frame for frame in same)
    assert len(batch) == len(same) and np.array_equal(batch[0], mine[0])


def test_restore_s_default_on_the_cpu_writes_restorer_s_bytes_with_the_shipped_network(
    tmp_path: Path,
) -> None:
    """Frames of one size, the paper's GEA, torch's own thread count: at batch 4 (the old
    default) the CPU's kernels rounded a few hundred pixels a frame one code apart from
    Restorer's batch of one (not on one thread, so no ``one_thread`` fixture here)."""
    weights = WEIGHTS_DIR / WEIGHTS_FILES[1]
    frames = [(texture((120, 160), seed=seed) * 255).astype(np.uint8) for seed in range(5)]
    restorer = Restorer(weights, device="cpu", precision="fp32")
    written = _restored_by_command(tmp_path, weights, frames, "--device", "cpu")
    for frame, by_command in zip(frames, written, strict=True):
        np.testing.assert_array_equal(restorer(frame), by_command)


def test_a_12_bit_camera_s_words_come_back_in_its_words(
    checkpoint: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """As restore does: on the full scale through the network, then narrowed back."""
    full = (texture((32, 48), seed=4) * 65535).astype(np.uint16)
    frame = narrow(full, 12)
    restorer = Restorer(checkpoint, device="cpu", precision="fp32")
    with caplog.at_level("WARNING"):
        out = restorer(frame)
    said = [r.getMessage() for r in caplog.records if "12-bit values" in r.getMessage()]
    # of the frames, not of the model file (it said "RUN/best.pt: its 16-bit frames ...")
    assert len(said) == 1 and said[0].startswith("the frames given to Restorer(")
    assert out.dtype == np.uint16 and int(out.max()) < 1 << 12
    reference = Restorer(checkpoint, device="cpu", precision="fp32")(widen(frame, 12))
    assert np.abs(out.astype(np.int64) - narrow(reference, 12).astype(np.int64)).max() <= 1


def test_a_black_warm_up_frame_tells_no_depth(
    checkpoint: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The README has a node restore one blank frame at start-up: a black 16-bit frame set
    the depth to 10 bits with a warning, and the camera's first real frame raised it."""
    restorer = Restorer(checkpoint, device="cpu", precision="fp32")

    def depth_lines() -> list[str]:
        return [r.getMessage() for r in caplog.records if r.name == "lenspair.core.bitdepth"]

    with caplog.at_level("WARNING"):
        assert not restorer(np.zeros((32, 48), np.uint16)).any()
        assert restorer.depth.bits == 16 and not depth_lines()
        restorer(narrow((texture((32, 48), seed=4) * 65535).astype(np.uint16), 12))
    assert restorer.depth.bits == 12
    (said,) = depth_lines()
    assert "12-bit values" in said


def test_a_batch_whose_depth_rises_scales_each_frame_as_one_by_one(
    tmp_path: Path, checkpoint: Path
) -> None:
    """Two 10-bit frames, then a 12-bit one: the first two are taken as 10-bit words
    whatever the batch (they were, one by one, before the third came).

    Batched and one by one agree to one code: oneDNN may sum a batch of three in
    another order than a batch of one (it did on an AMD EPYC: one pixel of 1536 a
    code apart), while a frame rescaled to the later depth is four times off.
    """
    frames = [narrow((texture((32, 48), seed=s) * 65535).astype(np.uint16), 10) for s in (7, 8)]
    frames.append(narrow((texture((32, 48), seed=9) * 65535).astype(np.uint16), 12))
    one_by_one = Restorer(checkpoint, device="cpu", precision="fp32")
    mine = [one_by_one(frame) for frame in frames]
    assert int(mine[0].max()) < 1 << 10 and int(mine[2].max()) >= 1 << 10
    batched = Restorer(checkpoint, device="cpu", precision="fp32").restore_batch(frames)
    written = _restored_by_command(tmp_path, checkpoint, frames, "--batch-size", "4")
    for index, (out, together, by_command) in enumerate(zip(mine, batched, written, strict=True)):
        for other in (together, by_command):
            assert other.dtype == out.dtype and other.shape == out.shape
            assert int(np.abs(other.astype(np.int64) - out).max()) <= 1
            if index < 2:  # still 10-bit words, not rescaled to the third frame's 12 bits
                assert int(other.max()) < 1 << 10


def test_one_restorer_with_bits_serves_a_12_bit_and_a_16_bit_camera(checkpoint: Path) -> None:
    """Two cameras on one Restorer: after a 16-bit frame, the running depth took the 12-bit
    camera's frames as 16-bit words (mean output five times too dark)."""
    mono12 = narrow((texture((32, 48), seed=10) * 65535).astype(np.uint16), 12)
    mono16 = (texture((32, 48), seed=11) * 65535).astype(np.uint16)
    alone = Restorer(checkpoint, device="cpu", precision="fp32")(mono12)  # its own Restorer
    for bits in (12, None):
        shared = Restorer(checkpoint, device="cpu", precision="fp32", bits=bits)
        first = shared(mono12)
        shared(mono16)
        after = shared(mono12)
        np.testing.assert_array_equal(first, alone)
        if bits is None:  # the running depth, raised by the 16-bit camera (module docstring)
            assert np.abs(after.astype(np.int64) - alone).mean() > 100
        else:
            np.testing.assert_array_equal(after, alone)
    # 12.0 == 12 was taken, then failed at the first 16-bit frame's shift with a TypeError
    for wrong in (8, 12.0, np.float64(12), True, "12"):
        with pytest.raises(ModelError, match="bits must be one of"):
            Restorer(checkpoint, device="cpu", bits=wrong)  # type: ignore[arg-type]
    assert Restorer(checkpoint, device="cpu", bits=np.int64(12)).bits == 12


def test_the_allocator_is_left_alone_when_asked(
    checkpoint: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Tuning glibc is the whole host process's: a node sharing it may say no."""
    from lenspair.model.inference import backends  # the module whose tune_allocator deploy calls

    calls: list[int] = []
    monkeypatch.setattr(backends, "tune_allocator", lambda: calls.append(1) or True)
    Restorer(checkpoint, device="cpu", tune_allocator=False)
    assert calls == []
    Restorer(checkpoint, device="cpu")
    assert calls == [1]


def test_a_non_integer_tile_is_a_one_line_error(checkpoint: Path) -> None:
    for tile, overlap in ((64.5, 16), ("64", 16), (64, 1.5), (True, 16)):
        with pytest.raises(ModelError, match="whole number of pixels"):
            Restorer(checkpoint, device="cpu", tile=tile, overlap=overlap)  # type: ignore[arg-type]
    assert Restorer(checkpoint, device="cpu", tile=np.int64(64)).tile == 64


def test_tiles_are_those_of_restore_tile(tmp_path: Path, checkpoint: Path) -> None:
    frame = (texture((64, 96), seed=5) * 255).astype(np.uint8)
    whole = Restorer(checkpoint, device="cpu", precision="fp32")(frame)
    tiled = Restorer(checkpoint, device="cpu", precision="fp32", tile=48, overlap=16)(frame)
    assert tiled.shape == whole.shape and not np.array_equal(tiled, whole)
    (written,) = _restored_by_command(
        tmp_path, checkpoint, [frame], "--tile", "48", "--overlap", "16"
    )
    np.testing.assert_array_equal(tiled, written)


def test_frames_it_cannot_restore_are_one_line_errors(tmp_path: Path, checkpoint: Path) -> None:
    restorer = Restorer(checkpoint, device="cpu", precision="fp32")
    grey = (texture((32, 48), seed=6) * 255).astype(np.uint8)
    cases = [
        (np.repeat(grey[..., None], 3, axis=2), r"frame 0: 3 channel\(s\) but the network takes 1"),
        (grey.astype(np.float32) / 255, "expected dtype uint8 or uint16, got float32"),
        (grey[:4, :4], "4x4 pixels, smaller than the network's 8x8 minimum"),
    ]
    for frame, message in cases:
        with pytest.raises(ModelError, match=message):
            restorer(frame)
    with pytest.raises(ModelError, match="different shapes"):
        restorer.restore_batch([grey, grey[:, :40]])
    dim16 = np.zeros_like(grey, dtype=np.uint16)  # would read as 10-bit words
    with pytest.raises(ModelError, match="different shapes or bit depths"):
        restorer.restore_batch([grey, dim16])
    assert restorer.depth.bits == 16  # a refused call leaves the camera's depth as it was
    assert restorer.restore_batch([]) == []
    with pytest.raises(ModelError, match=r"takes a list of frames, got one \(32, 48\) array"):
        restorer.restore_batch(grey)  # iterated, its rows were taken for frames
    with pytest.raises(ModelError, match="uint16 in the other byte order"):
        restorer(grey.astype(">u2"))  # a mono16 message with is_bigendian, decoded by hand
    with pytest.raises(ModelError, match="--tile"):
        Restorer(checkpoint, device="cpu", tile=8)
    with pytest.raises(ModelError, match="overlap"):
        Restorer(checkpoint, device="cpu", tile=32, overlap=32)
    with pytest.raises(ModelError, match="not found"):
        Restorer(tmp_path / "missing.pt", device="cpu")
    rgb = make_checkpoint(tmp_path / "rgb.pt", tiny_config_rgb())
    with pytest.raises(ModelError, match=r"frame 0: 1 channel\(s\) but the network takes 3"):
        Restorer(rgb, device="cpu")(grey)


def tiny_config_rgb() -> RunConfig:
    config = tiny_config()
    return replace(config, model=replace(config.model, channels=3))
