"""``restore`` under trouble: a frame out of memory, a finished bag resumed, foreign ONNX files.

Also that a restored image keeps what describes it (ICC profile, EXIF), that a
bag frame with alpha fails alone, and that a folder's files of frames that are
not read (camera raw, video, a killed recorder's bag) are named.
"""

import json
import os
import re
import struct
from dataclasses import replace
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch
from onnx import TensorProto, helper
from rosbags.rosbag1 import Writer as Writer1
from rosbags.typesys import Stores, get_typestore

from lenspair.capture.bag_frames import iter_bag_messages
from lenspair.capture.folders import read_folders
from lenspair.capture.frames import frame_files
from lenspair.capture.image_messages import COMPRESSED_IMAGE as COMPRESSED
from lenspair.capture.recording import CAMERAS
from lenspair.cli import main
from lenspair.core import imageio
from lenspair.core.imageio import read_image
from lenspair.core.imagewrite import write_image
from lenspair.model.detection.unjudged import unjudged_files
from lenspair.model.errors import ModelError
from lenspair.model.inference.backends import TorchBackend, open_backend
from lenspair.model.inference.pipeline import restore_input
from lenspair.model.inference.report import REPORT_NAME
from lenspair.model.inference.restore_options import RestoreOptions
from lenspair.model.inference.tiling import from_batch, run_backend, to_batch
from tests.images import texture
from tests.model.restore_helpers import bag_from_recording, restored_files
from tests.model.train_fixtures import make_checkpoint, tiny_config

CPU = torch.device("cpu")


@pytest.fixture
def backend(tmp_path: Path, one_thread: None) -> TorchBackend:
    loaded = open_backend(make_checkpoint(tmp_path / "ck.pt"), CPU, "fp32")
    assert isinstance(loaded, TorchBackend)
    return loaded


def _expected(backend: TorchBackend, image: np.ndarray) -> np.ndarray:
    """What restoring ``image`` alone gives (batch 1, whole image)."""
    (out,) = from_batch(run_backend(backend, to_batch([image])), image.dtype, image.ndim == 2)
    return out


def _grey(shape: tuple[int, int], seed: int) -> np.ndarray:
    return (texture(shape, seed=seed) * 255).astype(np.uint8)


class _Starved(torch.nn.Module):
    """The network, on a machine whose memory holds frames of at most ``pixels`` pixels.

    A larger input fails as the CPU allocator does, so the backend's own
    out-of-memory handling (its one-line error with ``--tile`` advice) runs.
    """

    def __init__(self, network: torch.nn.Module, pixels: int) -> None:
        super().__init__()
        self.network, self.pixels = network, pixels

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        if x.shape[-2] * x.shape[-1] > self.pixels:
            raise RuntimeError(
                "[enforce fail at alloc_cpu.cpp:118] DefaultCPUAllocator: can't allocate memory"
            )
        return self.network(x)  # type: ignore[no-any-return]


def test_a_frame_out_of_memory_costs_only_itself_and_the_run_can_resume(
    tmp_path: Path, backend: TorchBackend
) -> None:
    # it stopped the run, which deleted restore_report.json, and --resume was then refused
    source = tmp_path / "in"
    write_image(source / "a.png", _grey((32, 48), 1))
    write_image(source / "b.png", _grey((64, 96), 2))  # too large for this machine
    write_image(source / "c.png", _grey((32, 48), 3))
    starved = replace(backend, network=_Starved(backend.network, 32 * 48))
    out = tmp_path / "out"
    report = restore_input(source, out, starved, RestoreOptions(batch_size=1))
    assert (report.frames_read, report.restored, report.failed) == (3, 2, 1)
    (problem,) = report.problems
    assert problem["frame"] == "b.png"
    assert "out of memory restoring one 96x64 image" in problem["reason"]
    assert "--tile" in problem["reason"]
    assert (out / "b.png").read_bytes() == (source / "b.png").read_bytes()  # copied unchanged
    np.testing.assert_array_equal(read_image(out / "c.png"), _expected(backend, _grey((32, 48), 3)))
    saved = json.loads((out / REPORT_NAME).read_text())
    assert saved["complete"] is True and saved["failed"] == 1
    # the same model with the memory to spare: only the failed frame is restored
    again = restore_input(source, out, backend, RestoreOptions(batch_size=1, resume=True))
    assert (again.resumed, again.restored, again.failed) == (2, 1, 0)
    np.testing.assert_array_equal(read_image(out / "b.png"), _expected(backend, _grey((64, 96), 2)))


def test_a_frame_out_of_memory_is_redone_in_the_tiles_its_error_named_on_resume(
    tmp_path: Path, backend: TorchBackend, caplog: pytest.LogCaptureFixture
) -> None:
    # the error said "--tile 32", and `--resume --tile 32` was refused as other settings
    source = tmp_path / "in"
    write_image(source / "a.png", _grey((32, 48), 1))
    write_image(source / "b.png", _grey((64, 96), 2))  # too large for this machine
    starved = replace(backend, network=_Starved(backend.network, 32 * 48))
    out = tmp_path / "out"
    first = restore_input(source, out, starved, RestoreOptions(batch_size=1))
    assert first.failed == 1 and "--tile 32" in first.problems[0]["reason"]
    kept = (out / "a.png").read_bytes()
    tiled = RestoreOptions(batch_size=1, resume=True, tile=32, overlap=8)
    again = restore_input(source, out, starved, tiled)
    assert (again.resumed, again.restored, again.failed) == (1, 1, 0)
    assert (out / "a.png").read_bytes() == kept  # restored whole, and kept so
    assert (out / "b.png").read_bytes() != (source / "b.png").read_bytes()
    whole = {"tile": None, "overlap": first.settings["overlap"]}
    saved = json.loads((out / REPORT_NAME).read_text())["settings"]
    assert saved["tile"] == 32 and saved["earlier_tiling"] == [whole]
    assert any("frames already written keep the tiling" in m for m in caplog.messages)
    with pytest.raises(ModelError, match="batch_size"):  # the rest still binds a resume
        restore_input(source, out, starved, replace(tiled, batch_size=2))
    # resuming once more with the same tiles adds no record
    third = restore_input(source, out, starved, tiled)
    assert third.resumed == 2 and third.settings["earlier_tiling"] == [whole]


def test_a_batch_out_of_memory_fails_its_frames_only(tmp_path: Path, backend: TorchBackend) -> None:
    source = tmp_path / "in"
    for index in range(4):
        write_image(source / f"{index}.png", _grey((64, 96) if index < 2 else (32, 48), index))
    starved = replace(backend, network=_Starved(backend.network, 32 * 48))
    report = restore_input(source, tmp_path / "out", starved, RestoreOptions(batch_size=2))
    assert (report.restored, report.failed) == (2, 2)
    assert [p["frame"] for p in report.problems] == ["0.png", "1.png"]


def test_a_channel_mismatch_on_the_first_frame_still_leaves_out_as_it_was(
    tmp_path: Path, backend: TorchBackend
) -> None:
    colour = (texture((32, 48, 3), seed=1) * 255).astype(np.uint8)
    write_image(tmp_path / "in" / "x.png", colour)
    with pytest.raises(ModelError, match=r"3 channel.*network takes 1"):
        restore_input(tmp_path / "in", tmp_path / "out", backend)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("kind", ["ros1", "db3"])
def test_resuming_a_finished_bag_run_keeps_its_bag(
    tmp_path: Path, backend: TorchBackend, kind: str
) -> None:
    # the bag's cache is dropped once it is complete, and resume restored every frame again
    bag = bag_from_recording(tmp_path, kind, frames=3)
    options = RestoreOptions(batch_size=2)
    out = tmp_path / "out"
    whole = restore_input(bag, out, backend, options)
    written = restored_files(out)
    again = restore_input(bag, out, backend, replace(options, resume=True))
    assert (again.frames_read, again.restored, again.resumed) == (whole.frames_read, 0, 3)
    assert restored_files(out) == written
    saved = json.loads((out / REPORT_NAME).read_text())
    assert saved["complete"] is True and saved["resumed"] == 3 and saved["source_files"]
    # a bag changed since, or an output bag deleted, is written again
    files = [bag] if bag.is_file() else sorted(p for p in bag.iterdir() if p.is_file())
    later = files[0].stat().st_mtime_ns + 10**9
    os.utime(files[0], ns=(later, later))
    changed = restore_input(bag, out, backend, replace(options, resume=True))
    assert (changed.restored, changed.resumed) == (3, 0)
    assert restored_files(out) == written
    output = Path(changed.output)
    if output.is_dir():
        for part in output.iterdir():
            part.unlink()
        output.rmdir()
    else:
        output.unlink()
    rewritten = restore_input(bag, out, backend, replace(options, resume=True))
    assert (rewritten.restored, rewritten.resumed) == (3, 0)
    assert restored_files(out) == written
    # an output bag cut since (a copy interrupted) was kept because it still existed
    part = output if output.is_file() else max(output.iterdir(), key=lambda p: p.stat().st_size)
    part.write_bytes(part.read_bytes()[:-100])
    recut = restore_input(bag, out, backend, replace(options, resume=True))
    assert (recut.restored, recut.resumed) == (3, 0)
    assert restored_files(out) == written
    # a finished run that failed frames is not finished: resume tries them again
    saved = json.loads((out / REPORT_NAME).read_text())
    (out / REPORT_NAME).write_text(json.dumps({**saved, "failed": 1}))
    retried = restore_input(bag, out, backend, replace(options, resume=True))
    assert (retried.restored, retried.resumed) == (3, 0)


def _icc_profile() -> bytes:
    """A small valid RGB display profile (ICC v4: matrix and gamma-2.2 curves)."""

    def fixed(value: float) -> bytes:  # s15Fixed16Number
        return struct.pack(">i", round(value * 65536))

    def xyz(x: float, y: float, z: float) -> bytes:
        return b"XYZ " + bytes(4) + fixed(x) + fixed(y) + fixed(z)

    def text(words: str) -> bytes:
        encoded = words.encode("utf-16-be")
        return (
            b"mluc"
            + bytes(4)
            + struct.pack(">II2s2sII", 1, 12, b"en", b"US", len(encoded), 28)
            + encoded
        )

    curve = b"curv" + bytes(4) + struct.pack(">IH", 1, round(2.2 * 256)) + bytes(2)
    tags = [
        (b"desc", text("lenspair test RGB")), (b"cprt", text("none")),
        (b"wtpt", xyz(0.9642, 1.0, 0.8249)), (b"rXYZ", xyz(0.4361, 0.2225, 0.0139)),
        (b"gXYZ", xyz(0.3851, 0.7169, 0.0971)), (b"bXYZ", xyz(0.1431, 0.0606, 0.7141)),
        (b"rTRC", curve), (b"gTRC", curve), (b"bTRC", curve),
    ]  # fmt: skip
    offset = 128 + 4 + 12 * len(tags)
    table, data = b"", b""
    for signature, body in tags:
        table += struct.pack(">4sII", signature, offset + len(data), len(body))
        data += body + bytes(-len(body) % 4)
    header = struct.pack(
        ">I4sI4s4s4s6H4s4sI4s4sQI", offset + len(data), b"lcms", 0x04300000, b"mntr", b"RGB ",
        b"XYZ ", 2024, 5, 1, 12, 0, 0, b"acsp", b"APPL", 0, bytes(4), bytes(4), 0, 0,
    )  # fmt: skip
    header += fixed(0.9642) + fixed(1.0) + fixed(0.8249) + b"lcms" + bytes(44)
    return header + struct.pack(">I", len(tags)) + table + data


@pytest.mark.parametrize("suffix", [".png", ".jpg", ".tif"])
def test_a_restored_image_keeps_its_colour_profile_and_exif(
    tmp_path: Path, one_thread: None, suffix: str
) -> None:
    import OpenImageIO as oiio  # the test writes metadata that lenspair's writer only passes on

    config = tiny_config()
    rgb = open_backend(
        make_checkpoint(
            tmp_path / "rgb.pt", replace(config, model=replace(config.model, channels=3))
        ),
        CPU,
        "fp32",
    )
    source = tmp_path / "in"
    source.mkdir()
    name = source / f"frame{suffix}"
    pixels = (texture((32, 48, 3), seed=5) * 255).astype(np.uint8)
    profile = _icc_profile()
    spec = oiio.ImageSpec(48, 32, 3, "uint8")
    spec.attribute(
        "ICCProfile", oiio.TypeDesc(f"uint8[{len(profile)}]"), np.frombuffer(profile, np.uint8)
    )
    spec.attribute("Make", "Acme")
    spec.attribute("Model", "RoverCam")
    spec.attribute("DateTime", "2024:05:01 12:00:00")
    spec.attribute("Exif:DateTimeOriginal", "2024:05:01 11:59:59")
    spec.attribute("GPS:LatitudeRef", "N")
    spec.attribute("GPS:Latitude", oiio.TypeDesc("float[3]"), (47.0, 30.0, 0.0))
    image = oiio.ImageOutput.create(str(name))
    assert image.open(str(name), spec) and image.write_image(pixels)
    image.close()
    report = restore_input(source, tmp_path / "out", rgb)
    assert report.restored == 1
    written = oiio.ImageInput.open(str(tmp_path / "out" / name.name))
    kept = {item.name: item.value for item in written.spec().extra_attribs}
    written.close()
    assert bytes(np.asarray(kept["ICCProfile"], np.uint8)) == profile
    assert (kept["Make"], kept["Model"], kept["DateTime"]) == (
        "Acme", "RoverCam", "2024:05:01 12:00:00",
    )  # fmt: skip
    assert kept["Exif:DateTimeOriginal"] == "2024:05:01 11:59:59"
    assert kept["GPS:LatitudeRef"] == "N" and tuple(kept["GPS:Latitude"]) == (47.0, 30.0, 0.0)


def test_metadata_of_the_files_format_is_not_carried(tmp_path: Path) -> None:
    import OpenImageIO as oiio  # the test writes attributes lenspair's writer does not

    path = tmp_path / "x.tif"
    spec = oiio.ImageSpec(48, 32, 1, "uint8")
    spec.attribute("Model", "RoverCam")
    spec.attribute("XResolution", 300.0)
    spec.attribute("compression", "lzw")
    image = oiio.ImageOutput.create(str(path))
    assert image.open(str(path), spec) and image.write_image(np.zeros((32, 48, 1), np.uint8))
    image.close()
    names = {name for name, _, _ in imageio.image_metadata(path)}
    assert "Model" in names  # with DateTime, which OpenImageIO's TIFF writer sets itself
    format_and_geometry = {"XResolution", "YResolution", "ResolutionUnit", "compression"}
    assert not names & format_and_geometry
    assert not any(name.startswith(("tiff:", "oiio:")) for name in names)


def _save(graph: onnx.GraphProto, path: Path) -> Path:
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)]), str(path))
    return path


def _tensor(name: str, shape: list[int | str]) -> onnx.ValueInfoProto:
    return helper.make_tensor_value_info(name, TensorProto.FLOAT, shape)


def _two_inputs(path: Path) -> Path:
    """out = a + b: a model of two inputs."""
    a, b = _tensor("a", ["N", 3, 48, 64]), _tensor("b", ["N", 3, 48, 64])
    node = helper.make_node("Add", ["a", "b"], ["o"])
    return _save(helper.make_graph([node], "g", [a, b], [_tensor("o", ["N", 3, 48, 64])]), path)


def _classifier(path: Path) -> Path:
    """(N, 3, 48, 64) -> (N, 3): pooled, as a classifier's scores."""
    nodes = [
        helper.make_node("GlobalAveragePool", ["x"], ["p"]),
        helper.make_node("Flatten", ["p"], ["y"]),
    ]
    graph = helper.make_graph(
        nodes, "g", [_tensor("x", ["N", 3, 48, 64])], [_tensor("y", ["N", 3])]
    )
    return _save(graph, path)


def _halving(path: Path) -> Path:
    """(N, 3, H, W) -> (N, 3, H/2, W/2): the right rank and channels, another size."""
    node = helper.make_node("MaxPool", ["x"], ["y"], kernel_shape=[2, 2], strides=[2, 2])
    x, y = _tensor("x", ["N", 3, "H", "W"]), _tensor("y", ["N", 3, "h", "w"])
    return _save(helper.make_graph([node], "g", [x], [y]), path)


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (_two_inputs, r"2 inputs \(a, b\); a restoring model takes one image batch"),
        (_classifier, r"output y is \['N', 3\], not \(N, 3, H, W\)"),
    ],
)
def test_an_onnx_file_that_is_no_restoring_model_is_one_line_before_out_is_made(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], make: object, message: str
) -> None:
    # a traceback (too many values to unpack; axes don't match) and a half report in OUT
    model = make(tmp_path / "other.onnx")  # type: ignore[operator]
    with pytest.raises(ModelError, match=rf"^{re.escape(str(model))}: {message}"):
        open_backend(model, CPU)
    write_image(tmp_path / "f.png", np.full((48, 64, 3), 100, np.uint8))
    out = tmp_path / "out"
    code = main(["restore", str(model), str(tmp_path / "f.png"), "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith("lenspair restore: error:") and str(model) in err[0]
    assert not out.exists()


def test_an_onnx_model_that_returns_another_size_fails_the_frame(
    tmp_path: Path, one_thread: None
) -> None:
    # the half-size output was written as the restored frame
    model = open_backend(_halving(tmp_path / "halving.onnx"), CPU)
    colour = (texture((32, 48, 3), seed=2) * 255).astype(np.uint8)
    write_image(tmp_path / "in" / "x.png", colour)
    report = restore_input(tmp_path / "in", tmp_path / "out", model)
    assert (report.restored, report.failed) == (0, 1)
    (problem,) = report.problems
    assert "returned (1, 3, 16, 24) for a batch of (1, 3, 32, 48)" in problem["reason"]
    assert (tmp_path / "out" / "x.png").read_bytes() == (tmp_path / "in" / "x.png").read_bytes()


def _compressed_bag(
    tmp_path: Path,
    alpha: tuple[str, int] | None = None,
    fmt: str = "png",
    shape: tuple[int, int] = (32, 48),
) -> Path:
    """A ROS 1 bag of grey PNG ``CompressedImage`` frames on ``/cam0/compressed`` and ``/cam1/...``.

    Two frames a camera, at log time = stamp = ``index + 1`` s (cam1 5 ns later);
    the frame ``alpha`` (camera, index) is a PNG with a half-transparent alpha
    channel, as a camera publishing ``bgra8`` sends. ``fmt="jpeg"``: JPEG frames
    (written at OpenImageIO's default quality) instead.
    """
    store = get_typestore(Stores.ROS1_NOETIC)
    types = store.types
    bag = tmp_path / "run.bag"
    png = tmp_path / ("frame.jpg" if fmt == "jpeg" else "frame.png")
    with Writer1(bag) as writer:
        for camera in ("cam0", "cam1"):
            connection = writer.add_connection(f"/{camera}/compressed", COMPRESSED, typestore=store)
            nanosec = 5 if camera == "cam1" else 0
            for index in range(2):
                grey = _grey(shape, seed=10 * index + nanosec)
                see_through = np.full_like(grey, 255)
                see_through[:, :24] = 0
                write_image(png, grey, alpha=see_through if (camera, index) == alpha else None)
                stamp = types["builtin_interfaces/msg/Time"](sec=index + 1, nanosec=nanosec)
                header = types["std_msgs/msg/Header"](seq=index, stamp=stamp, frame_id=camera)
                data = np.frombuffer(png.read_bytes(), np.uint8)
                message = types[COMPRESSED](header=header, format=fmt, data=data)
                t_ns = (index + 1) * 10**9 + nanosec
                writer.write(connection, t_ns, store.serialize_ros1(message, COMPRESSED))
    png.unlink()
    return bag


def test_a_compressed_frame_with_alpha_is_failed_copied_unchanged_and_listed(
    tmp_path: Path, backend: TorchBackend
) -> None:
    # its alpha was dropped as it was decoded: restore wrote the frame back as a grey PNG
    # under the same message, and the report said 0 failed
    bag = _compressed_bag(tmp_path, alpha=("cam1", 1))
    report = restore_input(bag, tmp_path / "out", backend, RestoreOptions(batch_size=1))
    assert (report.frames_read, report.restored, report.failed) == (4, 3, 1)
    (problem,) = report.problems
    assert problem["frame"] == f"/cam1/compressed@{2 * 10**9 + 5}#0"
    assert re.fullmatch(
        rf"{re.escape(str(bag))} /cam1/compressed @ log time {2 * 10**9 + 5}: compressed "
        r"image with an alpha channel \([24] channels, format 'png'\): not read, since its "
        r"alpha would be lost",
        problem["reason"],
    ), problem["reason"]
    before = {(m.connection.topic, m.log_time_ns): m.raw for m in iter_bag_messages(bag)}
    after = {
        (m.connection.topic, m.log_time_ns): m.raw for m in iter_bag_messages(Path(report.output))
    }
    assert before.keys() == after.keys()
    copied = [key for key in before if before[key] == after[key]]
    assert copied == [("/cam1/compressed", 2 * 10**9 + 5)]  # the others were restored


def test_jpeg_compressed_frames_are_written_at_the_jpeg_quality_and_pngs_stay_lossless(
    tmp_path: Path, backend: TorchBackend
) -> None:
    # JPEG messages were encoded at OpenCV's default quality (95) whatever was asked
    bag = _compressed_bag(tmp_path, fmt="jpeg", shape=(96, 128))
    sizes: dict[int | None, list[int]] = {}
    for quality in (None, 40):  # None: the default
        options = RestoreOptions() if quality is None else RestoreOptions(jpeg_quality=quality)
        report = restore_input(bag, tmp_path / f"q{quality}", backend, options)
        assert (report.restored, report.failed) == (4, 0)
        messages = [m for m in iter_bag_messages(Path(report.output)) if m.frame is not None]
        assert [str(m.message.format) for m in messages] == ["jpeg"] * 4
        sizes[quality] = [len(m.message.data) for m in messages]
    assert all(low < 0.75 * high for low, high in zip(sizes[40], sizes[None], strict=True)), sizes
    # a PNG frame is lossless at any quality: the restored pixels exactly
    (tmp_path / "png").mkdir()
    png_bag = _compressed_bag(tmp_path / "png")
    report = restore_input(png_bag, tmp_path / "png_out", backend, RestoreOptions(jpeg_quality=1))
    for source, written in zip(
        iter_bag_messages(png_bag), iter_bag_messages(Path(report.output)), strict=True
    ):
        if source.frame is not None:
            assert written.frame is not None and source.frame.image is not None
            np.testing.assert_array_equal(
                written.frame.image, _expected(backend, source.frame.image)
            )


def _pbm(shape: tuple[int, int], seed: int) -> bytes:
    """A 1-bit netpbm bitmap (P4) of a texture thresholded at its middle."""
    bits = np.packbits(_grey(shape, seed) < 128, axis=1)  # in PBM, 1 is black
    return f"P4\n{shape[1]} {shape[0]}\n".encode() + bits.tobytes()


def test_a_folder_restores_every_name_of_its_images_and_names_raw_video_and_bags(
    tmp_path: Path, backend: TorchBackend
) -> None:
    # .jpe, .jfif, .pnm (read by OpenImageIO as well as .jpg and .ppm are) were copied
    # unrestored without a word, and so were a camera raw .dng, an MPEG-TS video and a
    # killed recorder's .bag.active; detect passed over them the same way
    source = tmp_path / "in"
    for index, name in enumerate(["a.jpe", "b.JFIF", "c.pnm"]):
        write_image(source / name, _grey((32, 48), seed=index))
    (source / "d.pbm").write_bytes(_pbm((32, 48), seed=3))
    write_image(tmp_path / "raw.tif", _grey((32, 48), seed=4))
    unread = {
        "e.dng": (tmp_path / "raw.tif").read_bytes(),  # DNG: raw data in a TIFF container
        "f.nef": b"MM\x00\x2a" + bytes(60),
        "g.ts": b"\x47" + bytes(187),  # one MPEG-TS packet
        "h.3gp": bytes(4) + b"ftyp3gp4",
        "run.bag.active": b"#ROSBAG V2.0\n",
    }
    for name, data in unread.items():
        (source / name).write_bytes(data)
    (source / "notes.ts").write_text("export const frames = 0;\n")  # TypeScript: no video
    out = tmp_path / "out"
    report = restore_input(source, out, backend, RestoreOptions(batch_size=1))
    assert (report.frames_read, report.restored, report.failed) == (4, 4, 0)
    for name in ("a.jpe", "b.JFIF", "c.pnm", "d.pbm"):
        assert (out / name).read_bytes() != (source / name).read_bytes(), name
        assert read_image(out / name).shape == (32, 48)
    for name in [*unread, "notes.ts"]:
        assert (out / name).read_bytes() == (source / name).read_bytes(), name
    assert [p["reason"] for p in report.problems] == [
        f"{source / 'e.dng'}: a camera raw file, copied as it is: it needs demosaicing by the "
        "camera's software; export it as PNG or TIFF to restore it",
        f"{source / 'f.nef'}: a camera raw file, copied as it is: it needs demosaicing by the "
        "camera's software; export it as PNG or TIFF to restore it",
        f"{source / 'g.ts'}: a video, copied as it is: restore takes its frames as images",
        f"{source / 'h.3gp'}: a video, copied as it is: restore takes its frames as images",
        f"{source / 'run.bag.active'}: a bag, copied as it is: restore it as an INPUT of its own",
    ]
    # detect reads the same images and names the same files, in its own words
    judged = frame_files(source, "folder", CAMERAS)
    assert [p.name for p in judged] == ["a.jpe", "b.JFIF", "c.pnm", "d.pbm"]
    notes = unjudged_files(source, "folder", judged)
    assert [note.split(":")[0] for note in notes] == [str(source / name) for name in unread]
    assert all(", not judged: " in note for note in notes)
    # and capture-ingest's left/ + right/ folders read them as frames
    recording = tmp_path / "rec"
    for folder, name in (("left", "1403636579763555584.jpe"), ("right", "1403636579763555584.pnm")):
        write_image(recording / folder / name, _grey((32, 48), seed=5))
    listed = read_folders(recording)
    assert {
        camera: [f.source.name for f in frames] for camera, frames in listed.frames.items()
    } == {"cam0": ["1403636579763555584.jpe"], "cam1": ["1403636579763555584.pnm"]}


def test_a_ros1_bag_inside_a_ros2_bag_folder_is_copied_as_a_file_of_the_recording(
    tmp_path: Path, backend: TorchBackend
) -> None:
    # the folder's files are copied beside the restored bag, but a .bag was taken for
    # the folder's own storage and left out, where a .bag.active was copied
    bag = bag_from_recording(tmp_path, "db3", frames=2)
    for name in ("before.bag", "killed.bag.active", "notes.txt"):
        (bag / name).write_bytes(b"#ROSBAG V2.0\n" + name.encode())
    report = restore_input(bag, tmp_path / "out", backend, RestoreOptions(batch_size=1))
    output = Path(report.output)
    for name in ("before.bag", "killed.bag.active", "notes.txt"):
        assert (output / name).read_bytes() == (bag / name).read_bytes(), name
    assert [p.name for p in output.iterdir() if p.suffix == ".db3"] == ["run.db3"]


class _FileJudge:
    """A judge loaded from a file (as ``--only-obstructed DETECTOR`` is)."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def __call__(self, frame: object, image: np.ndarray) -> bool:
        return True


def test_resume_with_another_detector_is_refused(tmp_path: Path, backend: TorchBackend) -> None:
    # only "judged: yes" was recorded, so a run judged by another detector was resumed,
    # and a finished bag judged by the old one kept
    folder = tmp_path / "in"
    write_image(folder / "a.png", _grey((24, 32), 1))
    first, second = tmp_path / "one.pt", tmp_path / "two.pt"
    first.write_bytes(b"one")
    second.write_bytes(b"two")
    out = tmp_path / "out"
    restore_input(folder, out, backend, RestoreOptions(), judge=_FileJudge(first))
    with pytest.raises(ModelError, match="detector_sha256"):
        restore_input(folder, out, backend, RestoreOptions(resume=True), judge=_FileJudge(second))
    again = restore_input(
        folder, out, backend, RestoreOptions(resume=True), judge=_FileJudge(first)
    )
    assert again.resumed == 1


class _StarvedSession:
    """An ONNX Runtime session on a machine whose memory holds one frame at a time."""

    def __init__(self, session: object) -> None:
        self.session, self.sizes = session, []  # type: list[int]

    def run(self, names: object, feed: dict[str, np.ndarray]) -> list[np.ndarray]:
        (batch,) = feed.values()
        self.sizes.append(len(batch))
        if len(batch) > 1 or batch.shape[-1] > 48:
            raise RuntimeError(
                "[ONNXRuntimeError] : 1 : FAIL : BFCArena::AllocateRawInternal Failed to "
                "allocate memory for requested buffer of size 2304000000"
            )
        return self.session.run(names, feed)  # type: ignore[attr-defined,no-any-return]


def test_an_onnx_model_out_of_memory_fails_only_the_frame_that_does_not_fit(
    tmp_path: Path, one_thread: None
) -> None:
    """ONNX Runtime's allocation failure ended the run with its traceback, the frames that
    fit included; Restorer raised onnxruntime's own exception."""
    pytest.importorskip("onnxruntime")
    from lenspair.model.evaluation.export import export_onnx
    from lenspair.model.inference.backends import OnnxBackend

    network = open_backend(make_checkpoint(tmp_path / "ck.pt"), CPU, "fp32")
    assert isinstance(network, TorchBackend)
    export_onnx(network.network, 1, tmp_path / "m.onnx", (32, 48), runs=1)
    backend = OnnxBackend(tmp_path / "m.onnx", CPU)
    starved = _StarvedSession(backend.session)
    backend.session = starved  # type: ignore[assignment]
    source = tmp_path / "in"
    write_image(source / "a.png", _grey((32, 48), 1))
    write_image(source / "b.png", _grey((64, 96), 2))  # too large for this machine
    write_image(source / "b2.png", _grey((64, 96), 4))
    write_image(source / "c.png", _grey((32, 48), 3))
    report = restore_input(source, tmp_path / "out", backend, RestoreOptions(batch_size=2))
    assert (report.restored, report.failed) == (2, 2)
    assert [p["frame"] for p in report.problems] == ["b.png", "b2.png"]
    problem = report.problems[0]
    assert "out of memory restoring one 96x64 image" in problem["reason"]
    assert "--tile 32" in problem["reason"] and str(tmp_path / "m.onnx") in problem["reason"]
    # a batch that does not fit runs frame by frame, as a checkpoint's does
    starved.sizes.clear()
    frames = np.random.default_rng(0).random((3, 1, 32, 48), dtype=np.float32)
    assert backend(frames).shape == frames.shape and starved.sizes == [3, 1, 1, 1]


def test_numpy_out_of_memory_around_the_network_fails_the_frame_not_the_run(
    tmp_path: Path, backend: TorchBackend, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The frames' float copies (to_batch), tiles and padding raised numpy's MemoryError,
    which only a ModelError is caught as: the run ended, nothing restored."""
    from lenspair.model.inference import tiling

    real = tiling.to_batch

    def starved(images: list[np.ndarray]) -> np.ndarray:
        if images[0].shape[1] > 48:
            raise MemoryError("Unable to allocate 412. MiB for an array")
        return real(images)

    monkeypatch.setattr(tiling, "to_batch", starved)
    source = tmp_path / "in"
    write_image(source / "a.png", _grey((32, 48), 1))
    write_image(source / "big.png", _grey((64, 96), 2))
    report = restore_input(source, tmp_path / "out", backend, RestoreOptions(batch_size=1))
    assert (report.restored, report.failed) == (1, 1)
    (problem,) = report.problems
    assert problem["frame"] == "big.png"
    assert "out of memory restoring one 96x64 image on this machine" in problem["reason"]
    assert "--tile 32" in problem["reason"]


def test_tiles_go_to_the_network_a_bounded_number_of_pixels_at_a_time(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Eight 1024-px tiles went to the network in one call: 4 megapixels of activations
    for a 3-megapixel frame, so --tile 1024 took 43 % more memory than no tiles."""
    from lenspair.model.inference import tiling

    sizes: list[tuple[int, ...]] = []

    def identity(batch: np.ndarray) -> np.ndarray:
        sizes.append(batch.shape)
        return batch

    batch = np.random.default_rng(0).random((1, 3, 96, 96), dtype=np.float32)
    out = tiling.run_tiled(identity, batch, (32, 32), 8)  # type: ignore[arg-type]
    np.testing.assert_allclose(out, batch, atol=1e-6)
    assert max(s[0] for s in sizes) == 8  # small tiles: eight a call
    for tile, frames, most in ((32, 1, 2), (32, 2, 1), (48, 1, 1), (20, 2, 2), (48, 3, 1)):
        sizes.clear()
        monkeypatch.setattr(tiling, "CHUNK_PIXELS", 2 * 32 * 32)  # two 32-px tiles' worth
        wide = np.repeat(batch, frames, axis=0)
        out = tiling.run_tiled(identity, wide, (tile, tile), 8)  # type: ignore[arg-type]
        np.testing.assert_allclose(out, wide, atol=1e-6)
        assert max(s[0] for s in sizes) == most * min(frames, max(1, 2 * 32 * 32 // tile**2))
        assert all(s[0] * s[2] * s[3] <= max(2 * 32 * 32, tile * tile) for s in sizes)


def test_a_colour_profile_for_other_colours_than_those_read_is_left_out_said_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    # a CMYK JPEG reads as RGB: its CMYK profile on the restored RGB file made viewers
    # reject it or misread every colour. Here: an RGB profile on a grey image.
    import OpenImageIO as oiio  # the test writes metadata that lenspair's writer only passes on

    monkeypatch.setattr(imageio, "_SAID", set())
    profile = _icc_profile()
    for name, channels in (("grey1.tif", 1), ("grey2.tif", 1), ("rgb.tif", 3)):
        spec = oiio.ImageSpec(16, 8, channels, "uint8")
        spec.attribute(
            "ICCProfile", oiio.TypeDesc(f"uint8[{len(profile)}]"), np.frombuffer(profile, np.uint8)
        )
        image = oiio.ImageOutput.create(str(tmp_path / name))
        assert image.open(str(tmp_path / name), spec)
        assert image.write_image(np.zeros((8, 16, channels), np.uint8))
        image.close()
    with caplog.at_level("WARNING"):
        kept = {
            n: {a for a, _, _ in imageio.image_metadata(tmp_path / n)}
            for n in ("grey1.tif", "grey2.tif", "rgb.tif")
        }
    assert "ICCProfile" not in kept["grey1.tif"] | kept["grey2.tif"]
    assert "ICCProfile" in kept["rgb.tif"]
    said = [r.getMessage() for r in caplog.records if "ICC profile" in r.getMessage()]
    assert said == [
        f"{tmp_path / 'grey1.tif'}: its ICC profile is for RGB colours, and the image is read "
        "as grey: the profile is left out of the image written in its place (so for every such "
        "file)"
    ]
