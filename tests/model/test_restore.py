"""``lenspair restore`` end to end: folders, recordings, bags, failures, resume, the CLI."""

import json
import os
import shutil
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from lenspair.capture.bag_frames import iter_bag_messages
from lenspair.capture.frame_types import BagMessage
from lenspair.capture.frames import iter_frames
from lenspair.cli import main
from lenspair.core.imageio import alpha_is_associated, read_image
from lenspair.core.imagewrite import write_image
from lenspair.model.detection.judge import judge
from lenspair.model.detection.train import save_detector
from lenspair.model.errors import ModelError
from lenspair.model.inference.backends import TorchBackend, open_backend
from lenspair.model.inference.judge import ThresholdJudge, default_judge
from lenspair.model.inference.pipeline import restore_input
from lenspair.model.inference.report import REPORT_NAME
from lenspair.model.inference.restore_options import RestoreOptions
from lenspair.model.inference.tiling import from_batch, run_backend, to_batch
from lenspair.model.networks.detector import AnomalyDetector, DetectorSpec
from tests.capture.ingest_helpers import frame_files, make_recording, simulate
from tests.capture.test_rosbag import IMAGE, T0
from tests.capture.test_rosbag import _raw_fields as raw_fields
from tests.capture.test_rosbag import _write_bag as write_messages
from tests.file_limits import run_with_file_limit
from tests.images import texture
from tests.model.restore_helpers import (
    HEALTH,
    bag_from_recording,
    humble_bag,
    restored_files,
    write_bag,
)
from tests.model.train_fixtures import make_checkpoint, tiny_config

CPU = torch.device("cpu")


@pytest.fixture
def checkpoint(tmp_path: Path, one_thread: None) -> Path:
    return make_checkpoint(tmp_path / "ck.pt")


@pytest.fixture
def backend(checkpoint: Path) -> TorchBackend:
    loaded = open_backend(checkpoint, CPU, "fp32")
    assert isinstance(loaded, TorchBackend)
    return loaded


def expected(backend: TorchBackend, image: np.ndarray) -> np.ndarray:
    """What restoring ``image`` alone gives (batch 1, whole image)."""
    (out,) = from_batch(run_backend(backend, to_batch([image])), image.dtype, image.ndim == 2)
    return out


def _folder(root: Path, dtype: type = np.uint8) -> Path:
    """Images in a tree, odd sizes among them, 8- or 16-bit."""
    top = np.iinfo(dtype).max
    for index, (name, shape) in enumerate(
        [("a.png", (32, 48)), ("sub/b.png", (37, 53)), ("sub/deep/c.tif", (32, 48))]
    ):
        write_image(root / name, (texture(shape, seed=index) * top).astype(dtype))
    return root


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_folder_keeps_tree_names_depth(tmp_path: Path, backend: TorchBackend, dtype: type) -> None:
    source = _folder(tmp_path / "in", dtype)
    report = restore_input(source, tmp_path / "out", backend, RestoreOptions(batch_size=2))
    assert (report.frames_read, report.restored, report.failed) == (3, 3, 0)
    for name in ("a.png", "sub/b.png", "sub/deep/c.tif"):
        original, restored = read_image(source / name), read_image(tmp_path / "out" / name)
        assert restored.dtype == original.dtype and restored.shape == original.shape
        np.testing.assert_array_equal(restored, expected(backend, original))
    saved = json.loads((tmp_path / "out" / REPORT_NAME).read_text())
    assert saved["restored"] == 3 and saved["input"] == str(source)


def test_a_resume_sets_aside_the_outputs_whose_input_is_gone(
    tmp_path: Path, backend: TorchBackend, caplog: pytest.LogCaptureFixture
) -> None:
    source = tmp_path / "in"
    for name in ("a.png", "b.png"):
        write_image(source / name, (texture((32, 48), seed=len(name)) * 255).astype(np.uint8))
    options = RestoreOptions(batch_size=1)
    restore_input(source, tmp_path / "out", backend, options)
    out = tmp_path / "out"
    (source / "b.png").unlink()
    (out / "notes.txt").write_text("the user's own")
    report = restore_input(source, out, backend, replace(options, resume=True))
    # b's output stayed beside the others, unsaid: an image the input no longer has
    assert not (out / "b.png").exists() and (out / ".restore-stale" / "b.png").is_file()
    assert (out / "a.png").is_file()
    assert (out / "notes.txt").read_text() == "the user's own"  # not restore's: left there
    reasons = [p["reason"] for p in report.problems]
    assert "b.png: its input is gone; moved to .restore-stale/b.png" in reasons
    assert "notes.txt: in OUT, not in the input; left in place" in reasons
    assert any("1 image(s) whose input is gone" in m for m in caplog.messages)
    again = restore_input(source, out, backend, replace(options, resume=True))
    assert (again.resumed, again.restored) == (1, 0)
    assert not any("input is gone" in p["reason"] for p in again.problems)


def test_a_resume_keeps_the_frames_of_a_camera_folder_behind_a_link(
    tmp_path: Path, backend: TorchBackend
) -> None:
    # rglob does not enter a linked folder: every frame behind it counted as gone, and
    # each resume moved them away and restored them again
    recording = make_recording(tmp_path / "rec", frames=3)
    data = recording / "mav0" / "cam1" / "data"
    data.rename(tmp_path / "other_disk")
    data.symlink_to(tmp_path / "other_disk", target_is_directory=True)
    options = RestoreOptions(batch_size=1, camera="cam1")
    first = restore_input(recording, tmp_path / "out", backend, options)
    restored = sorted((tmp_path / "out" / "mav0" / "cam1" / "data").iterdir())
    assert first.restored == 3 and len(restored) == 3
    # the camera not restored, behind its own link: copied (it was left out)
    cam0 = recording / "mav0" / "cam0" / "data"
    cam0.rename(tmp_path / "cam0_disk")
    cam0.symlink_to(tmp_path / "cam0_disk", target_is_directory=True)
    again = restore_input(recording, tmp_path / "out", backend, replace(options, resume=True))
    assert (again.resumed, again.restored) == (3, 0)
    assert not (tmp_path / "out" / ".restore-stale").exists()
    assert sorted((tmp_path / "out" / "mav0" / "cam1" / "data").iterdir()) == restored
    assert len(list((tmp_path / "out" / "mav0" / "cam0" / "data").iterdir())) == 3


def test_a_resume_restores_again_the_frames_whose_depth_an_added_frame_changed(
    tmp_path: Path, backend: TorchBackend, caplog: pytest.LogCaptureFixture
) -> None:
    from lenspair.core.bitdepth import narrow

    full = (texture((32, 48), seed=3) * 65535).astype(np.uint16)
    for name in ("b0.png", "b1.png"):  # a 10-bit camera's words
        write_image(tmp_path / "in" / name, narrow(full, 10))
    options = RestoreOptions(batch_size=1)
    restore_input(tmp_path / "in", tmp_path / "out", backend, options)
    assert int(read_image(tmp_path / "out" / "b0.png").max()) < 1 << 10
    write_image(tmp_path / "in" / "a.png", full)  # before them: the depth is 16 from here on
    report = restore_input(
        tmp_path / "in", tmp_path / "out", backend, replace(options, resume=True)
    )
    restore_input(tmp_path / "in", tmp_path / "fresh", backend, options)
    # they were kept in 10-bit words: "1 restored, 2 resumed"
    assert (report.restored, report.resumed) == (3, 0)
    for name in ("a.png", "b0.png", "b1.png"):
        fresh = read_image(tmp_path / "fresh" / name)
        np.testing.assert_array_equal(read_image(tmp_path / "out" / name), fresh)
    assert any("2 finished 16-bit frame(s) restored again" in m for m in caplog.messages)
    again = restore_input(tmp_path / "in", tmp_path / "out", backend, replace(options, resume=True))
    assert (again.restored, again.resumed) == (0, 3)  # and a plain resume keeps all


@pytest.mark.parametrize("bits", [10, 12])
def test_16_bit_frames_of_fewer_bits_are_restored_on_the_full_scale_and_written_back(
    tmp_path: Path, backend: TorchBackend, bits: int, caplog: pytest.LogCaptureFixture
) -> None:
    # mono16 words of a Mono10/Mono12 camera: the network saw an all but black
    # frame; now it sees the full-range one, and the output is in the camera's words
    from lenspair.core.bitdepth import narrow, widen

    full = (texture((32, 48), seed=3) * 65535).astype(np.uint16)
    low = narrow(full, bits)
    dim = low // 8  # then a dim frame: its own values fit 2 bits fewer
    write_image(tmp_path / "in" / "0.png", (full >> 8).astype(np.uint8))  # an 8-bit one first
    write_image(tmp_path / "in" / "a.png", low)
    write_image(tmp_path / "in" / "b.png", dim)
    restore_input(tmp_path / "in", tmp_path / "out", backend, RestoreOptions(batch_size=1))
    assert any(f"16-bit frames hold {bits}-bit values" in m for m in caplog.messages)
    for name, image in (("a.png", low), ("b.png", dim)):
        restored = read_image(tmp_path / "out" / name)
        assert restored.dtype == np.uint16 and int(restored.max()) < 1 << bits
        # the dim frame too at the input's depth: the same gain, not one of its own
        reference = narrow(expected(backend, widen(image, bits)), bits).astype(np.int64)
        assert np.abs(restored.astype(np.int64) - reference).max() <= 1, name
    # a full-range frame first: the input is 16-bit, and a later dim frame stays as it is
    write_image(tmp_path / "mixed" / "a.png", full)
    write_image(tmp_path / "mixed" / "b.png", low)
    restore_input(tmp_path / "mixed", tmp_path / "out2", backend, RestoreOptions(batch_size=1))
    np.testing.assert_array_equal(read_image(tmp_path / "out2" / "b.png"), expected(backend, low))


def test_a_folders_other_files_are_copied_with_it(tmp_path: Path, backend: TorchBackend) -> None:
    source = _folder(tmp_path / "in")
    (source / "sub" / "notes.txt").write_text("exposure 4 ms")  # not an image
    hidden = texture((32, 48), seed=7)
    write_image(source / ".thumb.png", (hidden * 255).astype(np.uint8))  # hidden: not a frame
    report = restore_input(source, tmp_path / "out", backend)
    assert report.restored == 3  # the hidden image is not one of the frames
    # "the same tree": they were left out without a word
    assert (tmp_path / "out" / "sub" / "notes.txt").read_text() == "exposure 4 ms"
    assert (tmp_path / "out" / ".thumb.png").read_bytes() == (source / ".thumb.png").read_bytes()
    assert report.problems == []  # notes are no frames left dirty


def test_frames_a_folder_holds_but_restore_does_not_read_are_named(
    tmp_path: Path, backend: TorchBackend
) -> None:
    # a bag, a video or a WebP in a folder were copied unchanged without a word: dirty frames
    source = _folder(tmp_path / "in")
    for name in ("day1/run.bag", "clip.mp4", "frame.webp", "calib/camchain.yaml"):
        (source / name).parent.mkdir(parents=True, exist_ok=True)
        (source / name).write_bytes(b"data")
    report = restore_input(source, tmp_path / "out", backend)
    said = sorted(p["reason"].split(":")[0] for p in report.problems)
    assert said == sorted(str(source / name) for name in ("day1/run.bag", "clip.mp4", "frame.webp"))
    assert all((tmp_path / "out" / name).read_bytes() == b"data" for name in ("clip.mp4",))


def test_a_bgra8_camera_is_restored_in_colour_and_keeps_its_alpha(
    tmp_path: Path, one_thread: None
) -> None:
    # a ZED publishes bgra8: every frame failed, copied as recorded ("cannot write restored
    # pixels as encoding 'bgra8'")
    config = tiny_config()
    rgb_config = replace(config, model=replace(config.model, channels=3))
    backend = open_backend(make_checkpoint(tmp_path / "rgb.pt", rgb_config), CPU, "fp32")
    assert isinstance(backend, TorchBackend)
    colour = (texture((32, 48, 3), seed=5) * 255).astype(np.uint8)
    alpha = np.full((32, 48), 255, np.uint8)
    alpha[:, :10] = 7
    bgra = np.ascontiguousarray(np.dstack([colour[:, :, ::-1], alpha]))
    fields = {"height": 32, "width": 48, "encoding": "bgra8", "is_bigendian": 0}
    fields |= {"step": 48 * 4, "data": bgra.reshape(-1)}
    bag = write_messages(tmp_path / "zed", "db3", [("/zed/left/image", IMAGE, T0, fields)])
    report = restore_input(bag, tmp_path / "out", backend)
    assert (report.restored, report.failed) == (1, 0)
    (item,) = [m for m in iter_bag_messages(Path(report.output)) if m.frame is not None]
    assert (item.message.encoding, item.message.step) == ("bgra8", 48 * 4)
    written = np.asarray(item.message.data).reshape(32, 48, 4)
    np.testing.assert_array_equal(written[:, :, 3], alpha)
    np.testing.assert_array_equal(written[:, :, 2::-1], expected(backend, colour))


DRIVER_IMAGE = """std_msgs/Header header
uint32 height
uint32 width
string encoding
uint8 is_bigendian
uint32 step
uint8[] data
uint32 exposure_us
"""
"""A driver's own ``sensor_msgs/Image``: a field after ``data``."""


@pytest.mark.parametrize("kind", ["ros1", "db3", "mcap"])
def test_an_image_type_with_a_drivers_own_field_is_written_back_with_it(
    tmp_path: Path, backend: TorchBackend, kind: str
) -> None:
    # the copy was serialised by the stock definition: each restored message lacked the
    # field its connection's definition names, and no reader could decode the copy
    stock = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
    store = get_typestore(Stores.EMPTY)
    dependencies = ("builtin_interfaces/msg/Time", "std_msgs/msg/Header")
    store.register({name: stock.fielddefs[name] for name in dependencies})
    store.register(get_types_from_msg(DRIVER_IMAGE, IMAGE))
    images = [(texture((32, 48), seed=k) * 255).astype(np.uint8) for k in range(2)]
    fields = [raw_fields(im, "mono8", pad=0) for im in images]
    for k, field in enumerate(fields):
        field["exposure_us"] = 700 + k
    messages = [("/cam0/image_raw", IMAGE, T0 + k * 50_000_000, f) for k, f in enumerate(fields)]
    bag = write_messages(tmp_path / "drv", kind, messages, store=store)
    report = restore_input(bag, tmp_path / "out", backend)
    assert (report.restored, report.failed) == (2, 0)
    with AnyReader([Path(report.output)], default_typestore=stock) as reader:
        copied = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()]
    assert [m.exposure_us for m in copied] == [700, 701]
    for message, image in zip(copied, images, strict=True):
        pixels = np.asarray(message.data).reshape(32, 48)
        np.testing.assert_array_equal(pixels, expected(backend, image))


def test_rgb_network_on_rgb_images_and_mismatch_refused(tmp_path: Path, one_thread: None) -> None:
    config = tiny_config()
    rgb_config = replace(config, model=replace(config.model, channels=3))
    rgb = open_backend(make_checkpoint(tmp_path / "rgb.pt", rgb_config), CPU, "fp32")
    image = (texture((32, 48, 3), seed=4) * 255).astype(np.uint8)
    write_image(tmp_path / "in" / "x.png", image)
    restore_input(tmp_path / "in", tmp_path / "out", rgb)
    restored = read_image(tmp_path / "out" / "x.png")
    assert restored.shape == (32, 48, 3)
    mono = open_backend(make_checkpoint(tmp_path / "mono.pt"), CPU, "fp32")
    with pytest.raises(ModelError, match=r"3 channel.*network takes 1"):
        restore_input(tmp_path / "in", tmp_path / "out2", mono)
    assert not (tmp_path / "out2").exists()  # refused before writing anything: not even OUT
    rgb_bag = bag_from_recording(tmp_path / "b", "db3", frames=2, colour=True)
    with pytest.raises(ModelError, match=r"3 channel.*network takes 1"):
        restore_input(rgb_bag, tmp_path / "out3", mono)
    assert not (tmp_path / "out3").exists()
    with pytest.raises(ModelError, match=r"3 channel.*network takes 1"):
        restore_input(tmp_path / "in", tmp_path / "new" / "deeper" / "out", mono)
    assert not (tmp_path / "new").exists()  # the parents it made go too
    (tmp_path / "out4").mkdir()  # a folder the user made stays
    with pytest.raises(ModelError, match=r"3 channel.*network takes 1"):
        restore_input(tmp_path / "in", tmp_path / "out4", mono)
    assert (tmp_path / "out4").is_dir() and not any((tmp_path / "out4").iterdir())


def _raw(path: Path) -> np.ndarray:
    """Every channel of an image file as stored, alpha included (not premultiplied)."""
    import OpenImageIO as oiio

    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    handle = oiio.ImageInput.open(str(path), config)
    pixels = np.asarray(handle.read_image(handle.spec().format))
    handle.close()
    return pixels


@pytest.mark.parametrize(("colour", "dtype"), [(True, np.uint8), (False, np.uint16)])
def test_alpha_is_carried_to_the_restored_image(
    tmp_path: Path, one_thread: None, colour: bool, dtype: type
) -> None:
    config = tiny_config()
    config = replace(config, model=replace(config.model, channels=3 if colour else 1))
    backend = open_backend(make_checkpoint(tmp_path / "m.pt", config), CPU, "fp32")
    top = np.iinfo(dtype).max
    image = (texture((32, 48, 3) if colour else (32, 48), seed=6) * top).astype(dtype)
    alpha = (texture((32, 48), seed=7) * top).astype(dtype)
    write_image(tmp_path / "in" / "x.png", image, alpha=alpha)
    assert _raw(tmp_path / "in" / "x.png").shape == (32, 48, 4 if colour else 2)
    report = restore_input(tmp_path / "in", tmp_path / "out", backend)
    assert (report.restored, report.failed) == (1, 0)
    written = _raw(tmp_path / "out" / "x.png")
    assert written.dtype == dtype and written.shape == (32, 48, 4 if colour else 2)
    np.testing.assert_array_equal(written[:, :, -1], alpha)  # transparency unchanged
    restored = written[:, :, :3] if colour else written[:, :, 0]
    np.testing.assert_array_equal(restored, expected(backend, image))  # colour restored


@pytest.mark.parametrize("associated", [True, False], ids=["premultiplied", "straight"])
def test_a_tiffs_alpha_keeps_its_association(
    tmp_path: Path, backend: TorchBackend, associated: bool
) -> None:
    # A premultiplied TIFF came out marked straight: the same colour values, another meaning.
    image = (texture((32, 48), seed=8) * 255).astype(np.uint8)
    alpha = (texture((32, 48), seed=9) * 255).astype(np.uint8)
    write_image(tmp_path / "in" / "x.tif", image, alpha=alpha, associated=associated)
    assert alpha_is_associated(tmp_path / "in" / "x.tif") is associated
    assert restore_input(tmp_path / "in", tmp_path / "out", backend).restored == 1
    assert alpha_is_associated(tmp_path / "out" / "x.tif") is associated
    np.testing.assert_array_equal(_raw(tmp_path / "out" / "x.tif")[:, :, -1], alpha)


def test_recording_restores_the_obstructed_camera(tmp_path: Path, backend: TorchBackend) -> None:
    recording = simulate("rain", tmp_path / "rec", frames=2)  # rig.yaml: cam1 obstructed
    report = restore_input(recording, tmp_path / "out", backend)
    assert report.cameras == ["cam1"] and report.restored == 2
    before, after = restored_files(recording), restored_files(tmp_path / "out")
    assert before.keys() == after.keys()
    for name, data in before.items():
        if name.startswith("mav0/cam1/data/"):
            np.testing.assert_array_equal(
                read_image(tmp_path / "out" / name), expected(backend, read_image(recording / name))
            )
        else:  # data.csv, sensor.yaml, rig.yaml, the clean camera: unchanged
            assert after[name] == data, name


@pytest.mark.parametrize("kind", ["ros1", "db3", "mcap"])
def test_bag_copies_every_message(tmp_path: Path, backend: TorchBackend, kind: str) -> None:
    bag = bag_from_recording(tmp_path, kind)
    suffix = "/restored" if kind == "mcap" else ""
    report = restore_input(bag, tmp_path / "out", backend, RestoreOptions(suffix=suffix))
    assert report.cameras == ["cam1"] and report.restored == 3
    source = list(iter_bag_messages(bag, cameras=("cam0", "cam1")))
    copy = list(iter_bag_messages(Path(report.output), cameras=()))
    restored_topic = "/cam1/image_raw" + suffix
    assert len(copy) == len(source) + (3 if suffix else 0)
    originals = iter(m for m in source if m.connection.topic == "/cam1/image_raw")
    for message in copy:
        topic = message.connection.topic
        if topic == restored_topic:
            original = next(originals)
            assert message.log_time_ns == original.log_time_ns
            decoded = _decode(message, kind == "ros1")
            assert _header(decoded) == _header(original.message)  # stamp, frame id, seq
            assert original.frame is not None and original.frame.image is not None
            pixels = _pixels(decoded)
            np.testing.assert_array_equal(pixels, expected(backend, original.frame.image))
    untouched = [(m.connection.topic, m.log_time_ns, m.raw) for m in copy]
    for message in source:
        if message.connection.topic != "/cam1/image_raw" or suffix:
            key = (message.connection.topic, message.log_time_ns, message.raw)
            assert key in untouched


def _decode(message: BagMessage, ros1: bool) -> Any:
    from rosbags.typesys import Stores, get_typestore

    msgtype = message.connection.msgtype
    if ros1:
        return get_typestore(Stores.ROS1_NOETIC).deserialize_ros1(message.raw, msgtype)
    return get_typestore(Stores.ROS2_HUMBLE).deserialize_cdr(message.raw, msgtype)


def _header(message: Any) -> tuple[int, int, str, int]:
    header = message.header
    seq = int(getattr(header, "seq", -1))
    return int(header.stamp.sec), int(header.stamp.nanosec), str(header.frame_id), seq


def _pixels(message: Any) -> np.ndarray:
    from lenspair.capture.image_messages import decode_message

    return decode_message("sensor_msgs/msg/Image", message, "test")


def test_unreadable_image_costs_only_itself(tmp_path: Path, backend: TorchBackend) -> None:
    source = _folder(tmp_path / "in")
    (source / "sub" / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n not really")
    report = restore_input(source, tmp_path / "out", backend)
    assert (report.frames_read, report.restored, report.failed) == (4, 3, 1)
    (problem,) = report.problems
    assert problem["frame"] == "sub/broken.png" and "broken.png" in problem["reason"]
    assert (tmp_path / "out" / "sub" / "broken.png").read_bytes() == (
        source / "sub" / "broken.png"
    ).read_bytes()


@pytest.mark.parametrize("kind", ["ros1", "db3", "mcap"])
def test_truncated_bag_keeps_what_was_read(
    tmp_path: Path, backend: TorchBackend, kind: str
) -> None:
    bag = bag_from_recording(tmp_path, kind, frames=6)
    storage = bag if kind == "ros1" else next(bag.glob(f"*.{kind}"))
    data = storage.read_bytes()
    storage.write_bytes(data[: len(data) * 3 // 4])
    report = restore_input(bag, tmp_path / "out", backend)
    assert 1 <= report.restored < 6
    assert sum("stopped early" in p["reason"] for p in report.problems) == 1
    copied = list(iter_bag_messages(Path(report.output)))
    assert sum(m.frame is not None and m.frame.camera == "cam1" for m in copied) == report.restored


class _KilledError(Exception):
    """Stands in for a kill: raised by the backend part-way."""


class _DiesAfter:
    def __init__(self, inner: TorchBackend, calls: int) -> None:
        self.inner, self.left = inner, calls
        self.channels, self.fixed_size = inner.channels, None
        self.description, self.path = inner.description, inner.path  # the same model, killed

    def __call__(self, batch: np.ndarray) -> np.ndarray:
        self.left -= 1
        if self.left < 0:
            raise _KilledError
        return self.inner(batch)


def test_a_frame_its_extension_s_format_cannot_hold_is_failed_and_copied_not_mangled(
    tmp_path: Path, backend: TorchBackend
) -> None:
    """PNGs misnamed .jpg came out 8-bit or with the alpha as a colour; a .ppm stopped the run."""
    source = tmp_path / "in"
    grey = (texture((32, 48), seed=2) * 255).astype(np.uint8)
    write_image(source / "a.png", grey)
    write_image(tmp_path / "alpha.png", grey, alpha=np.full_like(grey, 200))
    write_image(tmp_path / "deep.png", grey.astype(np.uint16) * 257)
    (source / "b_alpha.jpg").write_bytes((tmp_path / "alpha.png").read_bytes())
    (source / "c_deep.jpg").write_bytes((tmp_path / "deep.png").read_bytes())
    (source / "d_alpha.ppm").write_bytes((tmp_path / "alpha.png").read_bytes())
    write_image(source / "e.png", grey)
    report = restore_input(source, tmp_path / "out", backend, RestoreOptions(batch_size=1))
    assert (report.frames_read, report.restored, report.failed) == (5, 2, 3)
    reasons = {p["frame"]: p["reason"] for p in report.problems}
    assert "JPEG holds no alpha channel" in reasons["b_alpha.jpg"]
    assert "JPEG holds uint8 values, not the image's uint16" in reasons["c_deep.jpg"]
    assert "4-channel" in reasons["d_alpha.ppm"] or "alpha" in reasons["d_alpha.ppm"]
    for name in ("b_alpha.jpg", "c_deep.jpg", "d_alpha.ppm"):  # as they were, not mangled
        assert (tmp_path / "out" / name).read_bytes() == (source / name).read_bytes()
    for name in ("a.png", "e.png"):  # the frames after them are restored
        np.testing.assert_array_equal(read_image(tmp_path / "out" / name), expected(backend, grey))


def test_bag_options_on_a_recording_are_said_unused(
    tmp_path: Path, backend: TorchBackend, caplog: pytest.LogCaptureFixture
) -> None:
    # on a EuRoC or left/right recording they were ignored without a word, exit 0
    source = make_recording(tmp_path / "rec", frames=2)
    options = RestoreOptions(camera="cam1", suffix="/r", topics=("/a", "/b"))
    with caplog.at_level("WARNING"):
        restore_input(source, tmp_path / "out", backend, options)
    said = [m for m in caplog.messages if "ignored for a EuRoC recording" in m]
    assert len(said) == 1 and "--suffix and --topics apply only to bags" in said[0]
    assert "--camera" not in said[0]


@pytest.mark.parametrize("kind", ["folder", "euroc"])
def test_resume_writes_the_same_bytes(tmp_path: Path, backend: TorchBackend, kind: str) -> None:
    if kind == "folder":
        source = tmp_path / "in"
        for index in range(7):
            write_image(
                source / f"{index:02d}.png", (texture((32, 48), seed=index) * 255).astype(np.uint8)
            )
    else:
        source = make_recording(tmp_path / "rec", frames=7)
    options = RestoreOptions(batch_size=2)
    restore_input(source, tmp_path / "whole", backend, options)
    with pytest.raises(_KilledError):
        restore_input(source, tmp_path / "resumed", _DiesAfter(backend, 2), options)  # type: ignore[arg-type]
    partial = restored_files(tmp_path / "resumed")
    with pytest.raises(ModelError, match="not empty; pass --resume"):
        restore_input(source, tmp_path / "resumed", backend, options)
    report = restore_input(
        source, tmp_path / "resumed", backend, RestoreOptions(batch_size=2, resume=True)
    )
    assert report.resumed == 4 and report.restored == 3
    assert len(partial) < len(restored_files(tmp_path / "whole"))
    assert restored_files(tmp_path / "resumed") == restored_files(tmp_path / "whole")


def test_resume_copies_again_only_the_files_changed_since(
    tmp_path: Path, backend: TorchBackend
) -> None:
    # every unrestored file (the other camera, truth/: tens of GB) was copied on every resume
    source = make_recording(tmp_path / "rec", frames=3)
    out = tmp_path / "out"
    restore_input(source, out, backend, RestoreOptions(camera="cam0"))
    copies = sorted(p.relative_to(out) for p in (out / "mav0" / "cam1").rglob("*") if p.is_file())
    assert len(copies) == 4  # data.csv and three frames
    before = {r: (out / r).stat().st_ino for r in copies}
    changed = copies[-1]
    (source / changed).write_bytes((source / changed).read_bytes() + b"\0")
    restore_input(source, out, backend, RestoreOptions(camera="cam0", resume=True))
    after = {r: (out / r).stat().st_ino for r in copies}
    assert [r for r in copies if after[r] != before[r]] == [changed]  # replaced: a new file
    for relative in copies:
        assert (out / relative).read_bytes() == (source / relative).read_bytes()
    # edited to the same size with its mtime put back (touch -r): the stale copy was kept
    edited = copies[0]
    times = (source / edited).stat()
    text = (source / edited).read_bytes()
    (source / edited).write_bytes(text.swapcase() if text.swapcase() != text else text[::-1])
    os.utime(source / edited, ns=(times.st_atime_ns, times.st_mtime_ns))
    restore_input(source, out, backend, RestoreOptions(camera="cam0", resume=True))
    assert (out / edited).read_bytes() == (source / edited).read_bytes() != text


def test_resume_into_a_folder_no_restore_run_wrote_is_refused(
    tmp_path: Path, backend: TorchBackend
) -> None:
    """Its files bore the inputs' names and newer times: they passed for finished frames."""
    source = tmp_path / "in"
    for name in ("a.png", "b.png"):
        write_image(source / name, (texture((32, 48), seed=1) * 255).astype(np.uint8))
    out = tmp_path / "other"
    unrelated = (texture((37, 53), seed=9) * 255).astype(np.uint8)
    write_image(out / "a.png", unrelated)
    with pytest.raises(ModelError, match=f"holds files but no {REPORT_NAME}"):
        restore_input(source, out, backend, RestoreOptions(resume=True))
    np.testing.assert_array_equal(read_image(out / "a.png"), unrelated)
    assert not (out / "b.png").exists()
    empty = tmp_path / "empty"
    empty.mkdir()  # an empty folder is a fresh start, resumed or not
    assert restore_input(source, empty, backend, RestoreOptions(resume=True)).restored == 2
    killed = tmp_path / "killed"  # killed while writing its first report: only that temporary
    killed.mkdir()
    (killed / f".{REPORT_NAME}.999999999.abcd1234.json.tmp").write_text("{")
    assert restore_input(source, killed, backend, RestoreOptions(resume=True)).restored == 2


def test_camera_options_on_a_folder_are_said_unused_and_do_not_bind_a_resume(
    tmp_path: Path, backend: TorchBackend, caplog: pytest.LogCaptureFixture
) -> None:
    """--camera made a --resume of a folder refuse, over a setting that changed nothing."""
    source = _folder(tmp_path / "in")
    with caplog.at_level("WARNING"):
        report = restore_input(
            source, tmp_path / "out", backend, RestoreOptions(camera="cam1", suffix="/r")
        )
    assert report.cameras == [] and report.restored == 3
    said = [m for m in caplog.messages if "ignored for a folder of images" in m]
    assert any("--camera applies only to recordings and bags" in m for m in said)
    assert any("--suffix applies only to bags" in m for m in said)
    again = restore_input(source, tmp_path / "out", backend, RestoreOptions(resume=True))
    assert again.resumed == 3


@pytest.mark.parametrize("suffix", ["db3", "mcap"])
def test_a_bare_bag_file_is_not_replaced_by_its_restored_folder(
    tmp_path: Path, backend: TorchBackend, suffix: str
) -> None:
    """OUT/<stem> is the restored bag's folder: when it holds the input, it would replace it."""
    image = (texture((32, 48), seed=3) * 255).astype(np.uint8)
    folder = write_bag(tmp_path / "src" / "run", suffix, {"cam0": [(10**18, image)]})
    bare = next(folder.glob(f"*.{suffix}"))
    before = bare.read_bytes()
    for resume in (False, True):
        with pytest.raises(ModelError, match="which holds the input"):
            restore_input(bare, folder.parent, backend, RestoreOptions(resume=resume))
    assert bare.read_bytes() == before


@pytest.mark.parametrize("kind", ["ros1", "db3"])
def test_bag_resume_reuses_frames_and_writes_the_same_bytes(
    tmp_path: Path, backend: TorchBackend, kind: str
) -> None:
    bag = bag_from_recording(tmp_path, kind, frames=5)
    options = RestoreOptions(batch_size=2)
    whole = restore_input(bag, tmp_path / "whole", backend, options)
    with pytest.raises(_KilledError):
        restore_input(bag, tmp_path / "out", _DiesAfter(backend, 1), options)  # type: ignore[arg-type]
    # the killed run's bag is not at its name: nothing reads as a complete bag
    assert not (tmp_path / "out" / Path(whole.output).name).exists()
    assert (tmp_path / "out" / ".restore-partial" / Path(whole.output).name).exists()
    resume = RestoreOptions(batch_size=2, resume=True)
    again = restore_input(bag, tmp_path / "out", backend, resume)
    assert (again.resumed, again.restored) == (2, 3)
    # the cache is gone too
    assert restored_files(tmp_path / "out") == restored_files(tmp_path / "whole")
    assert Path(again.output).name == Path(whole.output).name


class _Counting:
    """A backend that counts the frames it restores."""

    def __init__(self, inner: TorchBackend) -> None:
        self.inner, self.frames = inner, 0
        self.channels, self.fixed_size = inner.channels, None
        self.description, self.path = inner.description, inner.path

    def __call__(self, batch: np.ndarray) -> np.ndarray:
        self.frames += batch.shape[0]
        return self.inner(batch)


def test_bag_resume_after_failed_frames_restores_only_those_again(
    tmp_path: Path, backend: TorchBackend
) -> None:
    # one undecodable message: every --resume restored the whole bag again
    times = [T0 + k * 50_000_000 for k in range(4)]
    images = [(t, (texture((32, 48), seed=k) * 255).astype(np.uint8)) for k, t in enumerate(times)]
    bag = write_bag(tmp_path / "run", "ros1", {"cam0": images}, cut=frozenset({times[2]}))
    options = RestoreOptions(batch_size=1)
    first = restore_input(bag, tmp_path / "out", backend, options)
    assert (first.restored, first.failed) == (3, 1)
    written = restored_files(tmp_path / "out")
    counting = _Counting(backend)
    again = restore_input(bag, tmp_path / "out", counting, replace(options, resume=True))  # type: ignore[arg-type]
    assert (again.resumed, again.restored, again.failed) == (3, 0, 1)
    assert counting.frames == 0  # the three restored frames came from the cache
    assert restored_files(tmp_path / "out") == written


def test_only_obstructed_copies_clean_frames(tmp_path: Path, backend: TorchBackend) -> None:
    source = tmp_path / "in"
    write_image(source / "dark.png", (texture((32, 48), seed=1) * 60).astype(np.uint8))
    write_image(source / "bright.png", (texture((32, 48), seed=2) * 255).astype(np.uint8))
    report = restore_input(source, tmp_path / "out", backend, judge=ThresholdJudge(0.3))
    assert (report.restored, report.skipped) == (1, 1)
    assert report.skipped_frames == ["bright.png"]  # named, not only counted
    saved = json.loads((tmp_path / "out" / REPORT_NAME).read_text())
    assert saved["skipped_frames"] == ["bright.png"]
    assert (tmp_path / "out" / "bright.png").read_bytes() == (source / "bright.png").read_bytes()
    np.testing.assert_array_equal(
        read_image(tmp_path / "out" / "dark.png"),
        expected(backend, read_image(source / "dark.png")),
    )


def test_cli_single_image_and_one_line_errors(
    tmp_path: Path, checkpoint: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    image = tmp_path / "photo.png"
    write_image(image, (texture((30, 41), seed=0) * 255).astype(np.uint8))
    out = tmp_path / "out"
    assert main(["restore", str(checkpoint), str(image), "--out", str(out), "--device", "cpu"]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert line.startswith("restore: 1 frame (1 restored") and line.endswith(f"-> {out}")
    assert read_image(out / "photo.png").shape == (30, 41)
    missing = str(tmp_path / "no_detector.pt")
    for target, extra, message in (
        (out, [], "not empty; pass --resume"),
        (tmp_path / "out2", ["--only-obstructed", missing], f"{missing}: no such detector"),
    ):
        code = main(["restore", str(checkpoint), str(image), "--out", str(target), *extra])
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1, err
        assert err[0].startswith("lenspair restore: error:") and message in err[0]


def test_cli_names_each_bad_frame_where_the_run_is_watched(
    tmp_path: Path,
    checkpoint: Path,
    capsys: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
) -> None:
    # the summary only counted them ("2 problem(s) in restore_report.json")
    source = tmp_path / "in"
    source.mkdir()
    write_image(source / "good.png", (texture((30, 41), seed=0) * 255).astype(np.uint8))
    (source / "cut.png").write_bytes((source / "good.png").read_bytes()[:60])
    (source / "empty.png").write_bytes(b"")
    out = tmp_path / "out"
    assert (
        main(["restore", str(checkpoint), str(source), "--out", str(out), "--device", "cpu"]) == 0
    )
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert sorted(w.split(": ")[0] for w in warned) == [
        str(source / n) for n in ("cut.png", "empty.png")
    ]
    assert any("truncated" in w for w in warned) and any("empty file" in w for w in warned)
    assert "1 restored" in capsys.readouterr().out


def test_cli_jpeg_quality_sets_the_restored_jpegs_quality_and_leaves_pngs_alone(
    tmp_path: Path, checkpoint: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # restored JPEGs were written at OpenImageIO's default (about 98), whatever the input's
    source = tmp_path / "in"
    for index, name in enumerate(("a.jpg", "sub/b.JPEG", "c.png")):
        write_image(source / name, (texture((96, 128), seed=index) * 255).astype(np.uint8))
    base = ["restore", str(checkpoint), str(source), "--device", "cpu", "--precision", "fp32"]
    assert main([*base, "--out", str(tmp_path / "default")]) == 0
    assert main([*base, "--out", str(tmp_path / "q60"), "--jpeg-quality", "60"]) == 0
    capsys.readouterr()
    for name in ("a.jpg", "sub/b.JPEG"):
        low, high = (tmp_path / out / name for out in ("q60", "default"))
        assert low.stat().st_size < 0.75 * high.stat().st_size, name
        same = np.corrcoef(read_image(low).ravel(), read_image(high).ravel())[0, 1]
        assert same > 0.95, (name, same)  # the same restored frame, at a lower quality
    png = [(tmp_path / out / "c.png").read_bytes() for out in ("q60", "default")]
    assert png[0] == png[1]  # a PNG is not a JPEG: the same bytes at any quality
    saved = json.loads((tmp_path / "q60" / REPORT_NAME).read_text())
    assert saved["restored"] == 3 and saved["settings"]["jpeg_quality"] == 60


def test_restore_help_names_trains_checkpoint_and_where_each_input_goes(
    tmp_path: Path, checkpoint: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # the example read runs/rain/best.pt (train writes RUN/checkpoints/best.pt), and
    # "--out: output folder (empty or new)" left a bag's or a folder's outputs to be guessed
    with pytest.raises(SystemExit):
        main(["restore", "--help"])
    said = " ".join(capsys.readouterr().out.split())
    assert "restore runs/rain/checkpoints/best.pt " in said and "runs/rain/best.pt" not in said
    out_help = said.split("options:")[1].split(" --out OUT ")[1].split(" --camera ")[0]
    for place in ("OUT/<image name>", "OUT/<path inside the folder>", "OUT/mav0/"):
        assert place in out_help
    assert "OUT/<bag name> for a bag" in out_help and "OUT/<bag folder name>/" in out_help
    image = (texture((32, 48), seed=3) * 255).astype(np.uint8)
    bag = write_bag(tmp_path / "run", "db3", {"cam0": [(10**9, image)]})
    assert main(["restore", str(checkpoint), str(bag), "--out", str(tmp_path / "out")]) == 0
    assert len(list(iter_frames(tmp_path / "out" / bag.name))) == 1  # as the help says


def test_single_topic_bag_restores_that_topic(tmp_path: Path, backend: TorchBackend) -> None:
    """A mono-camera bag: its one image topic is restored whatever rig.yaml says."""
    image = (texture((32, 48), seed=3) * 255).astype(np.uint8)
    bag = write_bag(tmp_path / "front", "mcap", {"front": [(10**18, image), (10**18 + 50, image)]})
    report = restore_input(bag, tmp_path / "out", backend, RestoreOptions(camera="cam1"))
    assert report.cameras == ["cam0"] and report.restored == 2
    (frame, _) = list(iter_frames(Path(report.output)))
    assert frame.image is not None
    np.testing.assert_array_equal(frame.image, expected(backend, image))


def test_demo_restores_a_recording_and_shows_before_after(tmp_path: Path, checkpoint: Path) -> None:
    from lenspair.core.report import Image
    from lenspair.demo import QUICK, RESTORED_RECORDING, plan
    from lenspair.demo_report import restore_blocks

    out = tmp_path / "demo"
    (stage,) = [s for s in plan(out, QUICK) if s.name == "restore"]
    assert stage.argv[0] == "restore" and stage.argv[1].endswith("finetune/checkpoints/best.pt")
    recording = make_recording(out / "recordings" / RESTORED_RECORDING, frames=3)
    argv = ["restore", str(checkpoint), str(recording), *stage.argv[3:]]
    assert main(argv) == 0
    blocks = restore_blocks(out)
    assert any(isinstance(b, Image) and b.path == "restore_before_after.png" for b in blocks)
    strip = read_image(out / "restore_before_after.png")
    assert strip.ndim == 3 and strip.shape[0] > 100


def test_only_obstructed_uses_the_detector(tmp_path: Path, backend: TorchBackend) -> None:
    """The detector is the judge: blank frames (never obstructed) are copied unchanged."""
    torch.manual_seed(0)
    network = AnomalyDetector(
        DetectorSpec(widths=(4, 8, 8), context_dilations=(2,), input_size=(48, 64))
    )
    save_detector(tmp_path / "d.pt", network)
    detector_judge = default_judge(tmp_path / "d.pt", torch.device("cpu"))
    folder = tmp_path / "in"
    folder.mkdir()
    textured = (texture((40, 56), seed=3) * 255).astype(np.uint8)
    write_image(folder / "blank.png", np.zeros((40, 56), np.uint8))
    write_image(folder / "textured.png", textured)
    expected = bool(judge(network, [textured]).obstructed[0])
    frames = {f.name: f for f in iter_frames(folder)}
    assert detector_judge(frames["blank.png"], np.zeros((40, 56), np.uint8)) is False
    assert detector_judge(frames["textured.png"], textured) is expected
    out = tmp_path / "out"
    restore_input(folder, out, backend, RestoreOptions(), detector_judge)
    assert np.array_equal(read_image(out / "blank.png"), np.zeros((40, 56), np.uint8))


def test_a_bare_mcap_file_is_restored_into_a_bag_folder(
    tmp_path: Path, backend: TorchBackend
) -> None:
    """A .mcap without its metadata.yaml stores no RIHS01 type hashes: they are computed."""
    image = (texture((32, 48), seed=4) * 255).astype(np.uint8)
    folder = write_bag(tmp_path / "b", "mcap", {"cam0": [(10**18, image), (10**18 + 50, image)]})
    bare = tmp_path / "bare.mcap"
    shutil.copy(next(folder.glob("*.mcap")), bare)
    assert all(not m.connection.digest for m in iter_bag_messages(bare, cameras=("cam0",)))
    report = restore_input(bare, tmp_path / "out", backend, RestoreOptions(suffix="/restored"))
    assert report.restored == 2 and report.failed == 0
    copy = list(iter_bag_messages(Path(report.output), cameras=()))
    topics = sorted(m.connection.topic for m in copy)
    assert topics.count("/cam0/image_raw/restored") == 2 and topics.count("/status") == 2
    assert all(m.connection.digest.startswith("RIHS01_") for m in copy)


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_a_suffix_whose_topic_the_bag_has_is_refused_before_out_is_made(
    tmp_path: Path, backend: TorchBackend, kind: str
) -> None:
    """Restoring a restored bag again with the same --suffix would write one topic twice."""
    bag = bag_from_recording(tmp_path, kind)
    first = restore_input(bag, tmp_path / "once", backend, RestoreOptions(suffix="/restored"))
    again = Path(first.output)
    with pytest.raises(ModelError, match=r"topic /cam1/image_raw/restored is in the bag already"):
        restore_input(again, tmp_path / "twice", backend, RestoreOptions(suffix="/restored"))
    assert not (tmp_path / "twice").exists()
    # another suffix, or none (the camera's frames replaced), goes ahead
    options = RestoreOptions(suffix="/r2", camera="cam1")
    other = restore_input(again, tmp_path / "other", backend, options)
    assert other.restored == 3 and other.failed == 0


def test_a_missing_model_is_the_only_line_a_user_sees(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, capsys: pytest.CaptureFixture[str]
) -> None:
    caplog.set_level("INFO")
    image = tmp_path / "photo.png"
    write_image(image, (texture((30, 41), seed=0) * 255).astype(np.uint8))
    argv = ["restore", str(tmp_path / "nope.pt"), str(image), "--out", str(tmp_path / "out")]
    assert main(argv) == 2
    assert "nope.pt: checkpoint not found" in capsys.readouterr().err
    assert not [r for r in caplog.records if "precision" in r.getMessage()]  # decided after


def test_a_bag_with_three_image_topics_restores_the_named_ones_and_reports_the_third(
    tmp_path: Path, checkpoint: Path, backend: TorchBackend
) -> None:
    images = {
        name: [(10**9 + k * 10**8 + i * 1000, texture((40, 48), seed=k)) for k in range(2)]
        for i, name in enumerate(("infra1", "infra2", "color"))
    }
    bag = write_bag(tmp_path / "rs", "ros1", images)
    out = tmp_path / "out"  # the topics' names say nothing of cam0/cam1: they must be named
    assert main(["restore", str(checkpoint), str(bag), "--out", str(out)]) == 2
    assert not out.exists()
    # one spelling of --topics in every command: two words, or the comma form
    args = [
        "--camera",
        "cam1",
        "--device",
        "cpu",
        "--precision",
        "fp32",
        "--topics",
        "/infra2/image_raw",
    ]
    command = ["restore", str(checkpoint), str(bag), "--out", str(out), *args, "/infra1/image_raw"]
    assert main(command) == 0
    report = json.loads((out / REPORT_NAME).read_text())
    assert report["restored"] == 2 and report["settings"]["topics"] == [
        "/infra2/image_raw",
        "/infra1/image_raw",
    ]
    # the third image topic was copied as recorded, and the report says so
    (problem,) = [p for p in report["problems"] if "/color/image_raw" in str(p)]
    assert "left as recorded" in str(problem) and "cam1 /infra1/image_raw" in str(problem)
    copy = {
        (m.connection.topic, m.log_time_ns): m
        for m in iter_bag_messages(Path(report["output"]), cameras=())
    }
    for message in iter_bag_messages(
        bag, ("cam0", "cam1"), topics=("/infra2/image_raw", "/infra1/image_raw")
    ):
        copied = copy[(message.connection.topic, message.log_time_ns)]
        if message.connection.topic == "/infra1/image_raw":  # cam1: restored
            assert message.frame is not None and message.frame.image is not None
            decoded = _pixels(_decode(copied, ros1=True))
            np.testing.assert_array_equal(decoded, expected(backend, message.frame.image))
        else:
            assert copied.raw == message.raw
    comma = ["restore", str(checkpoint), str(bag), "--out", str(tmp_path / "o2"), "--device", "cpu"]
    assert (
        main([*comma, "--topics", "/infra2/image_raw,/infra1/image_raw", "--camera", "cam1"]) == 0
    )


@pytest.mark.parametrize(
    ("kind", "limit"), [("ros1", 60_000), ("ros1", 150_000), ("db3", 150_000), ("mcap", 150_000)]
)
def test_a_full_disk_is_one_line_naming_the_file_and_resume_finishes(
    tmp_path: Path, checkpoint: Path, kind: str, limit: int
) -> None:
    # 60 kB: a frame's cache file does not fit; 150 kB: the bag being written does not
    bag = bag_from_recording(tmp_path, kind, frames=3)
    out = tmp_path / "out"
    argv = ["restore", str(checkpoint), str(bag), "--out", str(out), "--device", "cpu"]
    failed = run_with_file_limit(argv, limit)
    assert failed.returncode == 1 and "Traceback" not in failed.stderr, failed.stderr
    line = failed.stderr.strip().splitlines()[-1]
    assert line.startswith(f"lenspair restore: error: {out}/"), line
    assert main([*argv, "--resume"]) == 0
    assert len(list(iter_bag_messages(out / bag.name))) == len(list(iter_bag_messages(bag)))


def test_resume_redoes_a_file_changed_after_the_kill(
    tmp_path: Path, backend: TorchBackend, caplog: pytest.LogCaptureFixture
) -> None:
    source = tmp_path / "in"
    for index in range(5):
        write_image(source / f"{index}.png", (texture((32, 48), seed=index) * 255).astype(np.uint8))
    options = RestoreOptions(batch_size=2)
    with pytest.raises(_KilledError):
        restore_input(source, tmp_path / "out", _DiesAfter(backend, 1), options)  # type: ignore[arg-type]
    assert (tmp_path / "out" / "0.png").is_file()  # restored before the kill ...
    edited = (texture((32, 48), seed=99) * 255).astype(np.uint8)
    write_image(source / "0.png", edited)  # ... and edited since
    with caplog.at_level("WARNING"):
        again = restore_input(source, tmp_path / "out", backend, replace(options, resume=True))
    assert (again.resumed, again.restored) == (1, 4)
    assert "1 frame(s) restored again: their input changed" in caplog.text
    np.testing.assert_array_equal(read_image(tmp_path / "out" / "0.png"), expected(backend, edited))


@pytest.mark.parametrize("kind", ["ros1", "db3"])
def test_bag_resume_restores_a_bag_changed_after_the_kill_anew(
    tmp_path: Path, backend: TorchBackend, kind: str, caplog: pytest.LogCaptureFixture
) -> None:
    bag = bag_from_recording(tmp_path, kind, frames=5)
    options = RestoreOptions(batch_size=2)
    with pytest.raises(_KilledError):
        restore_input(bag, tmp_path / "out", _DiesAfter(backend, 1), options)  # type: ignore[arg-type]
    inverted = {
        camera: [
            (int(p.stem), 255 - read_image(p)) for p in frame_files(tmp_path / "euroc", camera)
        ]
        for camera in ("cam0", "cam1")
    }
    shutil.rmtree(bag) if bag.is_dir() else bag.unlink()
    write_bag(bag.parent / "run", kind, inverted)  # the same name, other pixels
    fresh = restore_input(bag, tmp_path / "fresh", backend, options)
    again = restore_input(bag, tmp_path / "out", backend, replace(options, resume=True))
    assert (again.resumed, again.restored) == (0, fresh.restored)
    assert "changed since the run being resumed" in caplog.text
    assert restored_files(tmp_path / "out") == restored_files(tmp_path / "fresh")


def test_bag_resume_trusts_a_cache_without_a_stamp(
    tmp_path: Path, backend: TorchBackend, caplog: pytest.LogCaptureFixture
) -> None:
    # a run killed under an earlier version (or before its stamp was written)
    bag = bag_from_recording(tmp_path, "ros1", frames=5)
    options = RestoreOptions(batch_size=2)
    with pytest.raises(_KilledError):
        restore_input(bag, tmp_path / "out", _DiesAfter(backend, 1), options)  # type: ignore[arg-type]
    (stamp,) = (tmp_path / "out" / ".restore-cache").rglob("source.json")
    stamp.unlink()
    again = restore_input(bag, tmp_path / "out", backend, replace(options, resume=True))
    assert (again.resumed, again.restored) == (2, 3)
    assert "changed since the run being resumed" not in caplog.text


@pytest.mark.parametrize("vendor", [False, True], ids=["standard-types", "vendor-type"])
def test_a_humble_bag_is_restored_into_a_bag_readers_open(
    tmp_path: Path, backend: TorchBackend, vendor: bool
) -> None:
    # Humble stores no definitions or hashes: the copy had empty definitions beside the type
    # store's hashes (rosbags refused to open it, lenspair read it as cut short), and a
    # vendor's type stopped the run part-way.
    image = (texture((32, 48), seed=5) * 255).astype(np.uint8)
    source = humble_bag(tmp_path / "run", [(10**18, image), (10**18 + 50_000_000, image)], vendor)
    report = restore_input(source, tmp_path / "out", backend, RestoreOptions(suffix="/restored"))
    assert report.restored == 2 and report.failed == 0
    undefined = [p["reason"] for p in report.problems if "defines" in p["reason"]]
    assert len(undefined) == vendor and all(f"/vendor/health ({HEALTH})" in u for u in undefined)
    problems: list[str] = []
    copy = list(iter_bag_messages(Path(report.output), (), problems))
    assert problems == []  # read whole, not salvaged
    topics = sorted(m.connection.topic for m in copy)
    assert topics.count("/cam0/image_raw/restored") == 2 and topics.count("/status") == 2
    originals = {
        (m.connection.topic, m.log_time_ns): bytes(m.raw) for m in iter_bag_messages(source, ())
    }
    for message in copy:
        if not message.connection.topic.endswith("/restored"):
            assert bytes(message.raw) == originals[(message.connection.topic, message.log_time_ns)]
    # rosbags' reader checks that every definition agrees with its hash
    with AnyReader([Path(report.output)]) as reader:
        assert {c.topic for c in reader.connections} >= {"/cam0/image_raw", "/status"}


def test_a_bare_mcap_with_an_idl_vendor_type_is_copied_with_its_own_hash(
    tmp_path: Path, backend: TorchBackend
) -> None:
    # A bare .mcap stores definitions but no hashes: an IDL-defined vendor type stopped the
    # run ("restore the bag folder instead", which the user did not have).
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_types_from_idl, get_typestore

    idl = "module my_msgs { module msg { struct Health { string name; float temperature; }; }; };\n"
    store = get_typestore(Stores.ROS2_HUMBLE)
    store.register(get_types_from_idl(idl))
    truth = store.hash_rihs01(HEALTH)
    image = (texture((32, 48), seed=6) * 255).astype(np.uint8)
    folder = write_bag(tmp_path / "b", "mcap", {"cam0": [(10**18, image)]})
    with_vendor = tmp_path / "v"
    writer = Writer2(with_vendor, version=9, storage_plugin=StoragePlugin.MCAP)
    with writer:
        connections = {}
        for message in iter_bag_messages(folder, ()):
            c = message.connection
            if c.topic not in connections:
                connections[c.topic] = writer.add_connection(c.topic, c.msgtype, typestore=store)
            writer.write(connections[c.topic], message.log_time_ns, message.raw)
        vendor = writer.add_connection(
            "/vendor", HEALTH, msgdef="=" * 80 + f"\nIDL: {HEALTH}\n" + idl, rihs01=truth
        )
        health = store.types[HEALTH](name="cam0", temperature=40.5)
        writer.write(vendor, 10**18 + 5, bytes(store.serialize_cdr(health, HEALTH)))
    bare = tmp_path / "bare.mcap"
    shutil.copy(next(with_vendor.glob("*.mcap")), bare)
    report = restore_input(bare, tmp_path / "out", backend, RestoreOptions(suffix="/restored"))
    assert report.restored == 1 and report.problems == []
    copy = iter_bag_messages(Path(report.output), ())
    assert [m.connection.digest for m in copy if m.connection.topic == "/vendor"] == [truth]


def test_a_suffixed_topic_has_a_message_for_every_frame_of_the_camera(
    tmp_path: Path, backend: TorchBackend
) -> None:
    """Frames judged clean go to ``<topic><suffix>`` as recorded: a subscriber misses none."""
    dark = (texture((32, 48), seed=1) * 60).astype(np.uint8)
    bright = (texture((32, 48), seed=2) * 255).astype(np.uint8)
    times = [10**18 + k * 50_000_000 for k in range(3)]
    frames = [(times[0], dark), (times[1], bright), (times[2], dark)]
    bag = write_bag(tmp_path / "run", "mcap", {"front": frames})
    options = RestoreOptions(suffix="/restored")
    report = restore_input(bag, tmp_path / "out", backend, options, judge=ThresholdJudge(0.3))
    assert (report.restored, report.skipped) == (2, 1)
    copy = list(iter_bag_messages(Path(report.output), cameras=()))
    by_topic: dict[str, list[BagMessage]] = {}
    for message in copy:
        by_topic.setdefault(message.connection.topic, []).append(message)
    topic = "/front/image_raw"
    assert sorted(by_topic) == [topic, f"{topic}/restored", "/status"]
    source, restored = by_topic[topic], by_topic[f"{topic}/restored"]
    assert [m.log_time_ns for m in restored] == [m.log_time_ns for m in source]
    assert len(source) == len(times)
    assert restored[1].raw == source[1].raw  # the clean frame, as recorded
    assert restored[0].raw != source[0].raw and restored[2].raw != source[2].raw


def _fixed_size_onnx(path: Path, height: int, width: int) -> Path:
    """A restoring ONNX model of one size only, as ``export`` wrote them: out = sqrt(image)."""
    onnx = pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    from onnx import TensorProto, helper

    def value(name: str) -> Any:
        return helper.make_tensor_value_info(name, TensorProto.FLOAT, ["batch", 1, height, width])

    node = helper.make_node("Sqrt", ["image"], ["restored"])
    graph = helper.make_graph([node], "fixed", [value("image")], [value("restored")])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 9  # one ONNX Runtime reads
    onnx.save(model, str(path))
    return path


def test_a_fixed_size_model_warns_once_a_run_and_records_its_tile(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Frames of another size ran in tiles of the model's size without a word (report: tile null).

    Tiles are normalised each by its own statistics, so they differ from the
    checkpoint at the seams; the run says so in one line and records the tile.
    """
    from lenspair.model.inference.restorer import Restorer

    model = open_backend(_fixed_size_onnx(tmp_path / "old.onnx", 32, 48), CPU)
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, (65, 97), dtype=np.uint8) for _ in range(3)]
    for index, frame in enumerate(frames):
        write_image(tmp_path / "in" / f"{index}.png", frame)
    for run in ("out1", "out2"):  # once per run: the second run is told too
        caplog.clear()
        report = restore_input(tmp_path / "in", tmp_path / run, model)
        warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
        assert len(warnings) == 1, warnings
        assert (
            "old.onnx: frames of 97x65 are run in tiles of the model's fixed size 48x32"
            in (warnings[0])
        )
        assert "differ from the checkpoint at the tile seams" in warnings[0]
        assert "\n" not in warnings[0]
        assert report.restored == 3 and report.forced_tile == "48x32"
        written = json.loads((tmp_path / run / REPORT_NAME).read_text())
        assert written["forced_tile"] == "48x32" and written["settings"]["tile"] is None
    # a context-free model: the tiles blend back into the whole frame's result
    restored = read_image(tmp_path / "out1" / "0.png")
    assert np.abs(restored.astype(int) - np.rint(np.sqrt(frames[0] / 255) * 255)).max() <= 1
    # --tile cannot change its tiles: refused before anything is read (it was ignored)
    with pytest.raises(ModelError, match=r"--tile: .*old.onnx was exported at 48x32 and runs on"):
        restore_input(tmp_path / "in", tmp_path / "tiled", model, RestoreOptions(tile=64))
    assert not (tmp_path / "tiled").exists()
    # frames of the model's size run whole: nothing to say, nothing recorded
    write_image(tmp_path / "same" / "a.png", frames[0][:32, :48])
    caplog.clear()
    assert restore_input(tmp_path / "same", tmp_path / "out3", model).forced_tile is None
    assert not [r for r in caplog.records if r.levelname == "WARNING"]
    # a Restorer in a robot's loop says it once, not at every frame
    restorer = Restorer(tmp_path / "old.onnx", device="cpu")
    caplog.clear()
    for frame in frames:
        restorer(frame)
    assert len([r for r in caplog.records if "run in tiles" in r.getMessage()]) == 1


def test_a_kept_bag_keeps_the_tile_its_frames_ran_on(tmp_path: Path) -> None:
    # --resume of a finished bag keeps it: its report still says the frames ran on tiles
    model = open_backend(_fixed_size_onnx(tmp_path / "old.onnx", 32, 48), CPU)
    rng = np.random.default_rng(1)
    frames = {
        "cam0": [(10**9 + k * 10**8, rng.integers(0, 256, (65, 97), np.uint8)) for k in range(2)]
    }
    bag = write_bag(tmp_path / "run", "db3", frames)
    first = restore_input(bag, tmp_path / "out", model)
    again = restore_input(bag, tmp_path / "out", model, RestoreOptions(resume=True))
    assert (first.restored, again.resumed, again.restored) == (2, 2, 0)  # kept, not redone
    assert first.forced_tile == again.forced_tile == "48x32"
    assert json.loads((tmp_path / "out" / REPORT_NAME).read_text())["forced_tile"] == "48x32"


def test_a_bag_an_earlier_lenspair_restored_is_kept_at_the_default_quality(
    tmp_path: Path,
) -> None:
    # its report records no jpeg_quality: its JPEG messages were at OpenCV's 95, the
    # default now, so --resume keeps the finished bag (it was refused as "not recorded")
    model = open_backend(_fixed_size_onnx(tmp_path / "old.onnx", 32, 48), CPU)
    rng = np.random.default_rng(2)
    frames = {
        "cam0": [(10**9 + k * 10**8, rng.integers(0, 256, (32, 48), np.uint8)) for k in range(2)]
    }
    bag = write_bag(tmp_path / "run", "db3", frames)
    restore_input(bag, tmp_path / "out", model)
    report = tmp_path / "out" / REPORT_NAME
    recorded = json.loads(report.read_text())
    del recorded["settings"]["jpeg_quality"]
    report.write_text(json.dumps(recorded))
    again = restore_input(bag, tmp_path / "out", model, RestoreOptions(resume=True))
    assert (again.resumed, again.restored) == (2, 0)
    with pytest.raises(ModelError, match=r"jpeg_quality: 95 -> 80"):
        restore_input(bag, tmp_path / "out", model, RestoreOptions(resume=True, jpeg_quality=80))
