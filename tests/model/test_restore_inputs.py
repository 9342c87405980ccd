"""``restore`` keeps inputs safe and accounts for every frame of every input kind."""

import errno
import json
import logging
import os
import shutil
import threading
from pathlib import Path

import numpy as np
import pytest
import torch

from lenspair.capture.errors import CaptureError
from lenspair.capture.frame_types import InputFrame
from lenspair.capture.frames import detect_input
from lenspair.capture.rigfile import RigFile, write_rig_file
from lenspair.cli import main
from lenspair.core import imageio
from lenspair.core.errors import ImageIOError
from lenspair.core.imageio import read_image
from lenspair.core.imagewrite import write_image
from lenspair.model.errors import ModelError
from lenspair.model.inference import file_sink
from lenspair.model.inference.backends import TorchBackend, open_backend
from lenspair.model.inference.pipeline import restore_input
from lenspair.model.inference.report import REPORT_NAME, RESTORE_LOCK, RestoreReport
from lenspair.model.inference.restore_options import RestoreOptions
from tests.capture.ingest_helpers import make_recording
from tests.images import texture
from tests.model.restore_helpers import file_tree, write_bag
from tests.model.train_fixtures import make_checkpoint


@pytest.fixture
def backend(tmp_path: Path, one_thread: None) -> TorchBackend:
    loaded = open_backend(make_checkpoint(tmp_path / "ck.pt"), torch.device("cpu"), "fp32")
    assert isinstance(loaded, TorchBackend)
    return loaded


def _image(seed: int) -> np.ndarray:
    return (texture((32, 48), seed=seed) * 255).astype(np.uint8)


def _folder(source: Path, count: int) -> Path:
    """``count`` images ``0.png`` ... in ``source``."""
    for index in range(count):
        write_image(source / f"{index}.png", _image(index))
    return source


def _inputs(root: Path) -> dict[str, tuple[Path, Path]]:
    """``name: (input, OUT that overlaps it)`` for each way OUT can land on the input."""
    photos = _folder(root / "photos", 2)
    single = root / "single"
    write_image(single / "x.png", _image(3))
    frames = {"cam0": [(10**9 + k * 10**8, _image(k)) for k in range(2)]}
    for folder in ("ros1", "ros2"):
        (root / folder).mkdir()
    ros1 = write_bag(root / "ros1" / "run", "ros1", frames)
    ros2 = write_bag(root / "ros2" / "run", "db3", frames)
    return {
        "OUT is the input folder": (photos, photos),
        "OUT inside the input folder": (photos, photos / "clean"),
        "OUT holds the image": (single / "x.png", single),
        "OUT holds the ROS 1 bag": (ros1, ros1.parent),
        "OUT holds the ROS 2 bag folder": (ros2, ros2.parent),
        "OUT is the ROS 2 bag folder": (ros2, ros2),
        "OUT inside the ROS 2 bag folder": (ros2, ros2 / "x"),
    }


@pytest.mark.parametrize(
    "case",
    [
        "OUT is the input folder",
        "OUT inside the input folder",
        "OUT holds the image",
        "OUT holds the ROS 1 bag",
        "OUT holds the ROS 2 bag folder",
        "OUT is the ROS 2 bag folder",
        "OUT inside the ROS 2 bag folder",
    ],
)
def test_out_overlapping_the_input_is_refused_and_the_input_kept(
    tmp_path: Path, backend: TorchBackend, case: str
) -> None:
    source, out = _inputs(tmp_path)[case]
    before = file_tree(tmp_path)
    with pytest.raises(ModelError, match=r"^--out .*(inside the input|would replace it)"):
        restore_input(source, out, backend, RestoreOptions(resume=True))
    assert file_tree(tmp_path) == before  # nothing deleted, nothing written


def test_out_beside_the_input_is_fine(tmp_path: Path, backend: TorchBackend) -> None:
    write_image(tmp_path / "x.png", _image(0))
    report = restore_input(tmp_path / "x.png", tmp_path / "clean", backend)
    assert report.restored == 1 and (tmp_path / "clean" / "x.png").is_file()


def test_an_unreadable_frame_costs_only_itself(
    tmp_path: Path, backend: TorchBackend, monkeypatch: pytest.MonkeyPatch
) -> None:
    source = _folder(tmp_path / "in", 3)
    locked = source / "1.png"
    read_pixels = imageio._read_pixels

    def refuse(path: Path, *args: bool) -> np.ndarray:
        if path == locked:
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return read_pixels(path, *args)

    monkeypatch.setattr(imageio, "_read_pixels", refuse)
    with pytest.raises(ImageIOError, match=r"1\.png: cannot read \(Permission denied\)"):
        read_image(locked)
    real_open = open

    def no_copy(path: str, *args: object, **kwargs: object) -> object:
        if Path(path) == locked:
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return real_open(path, *args, **kwargs)  # type: ignore[call-overload]

    monkeypatch.setattr(file_sink, "open", no_copy, raising=False)
    report = restore_input(source, tmp_path / "out", backend)
    assert (report.frames_read, report.restored, report.failed) == (3, 2, 1)
    assert {p["frame"] for p in report.problems} == {"1.png"}
    assert any("not copied" in p["reason"] for p in report.problems)
    assert sorted(p.name for p in (tmp_path / "out").glob("*.png")) == ["0.png", "2.png"]
    assert "problem(s) in restore_report.json" in report.summary()


def test_recording_frames_its_listing_dropped_are_reported(
    tmp_path: Path, backend: TorchBackend
) -> None:
    recording = make_recording(tmp_path / "rec", frames=3)
    data = recording / "mav0" / "cam1" / "data"
    shutil.copy(next(data.glob("*.png")), data / "unlisted.png")
    report = restore_input(recording, tmp_path / "out", backend, RestoreOptions(camera="cam1"))
    assert report.restored == 3
    (problem,) = report.problems
    assert "unlisted.png" in problem["reason"] and "not listed" in problem["reason"]
    assert (tmp_path / "out" / "mav0/cam1/data/unlisted.png").read_bytes() == (
        data / "unlisted.png"
    ).read_bytes()  # copied as it is, as every file the recording does not list


def test_a_recording_of_one_camera_restores_that_camera(
    tmp_path: Path, backend: TorchBackend
) -> None:
    """A mono robot's EuRoC folder (mav0/cam0 alone) is not refused for its missing cam1."""
    recording = make_recording(tmp_path / "rec", frames=3)
    shutil.rmtree(recording / "mav0" / "cam1")
    (recording / "rig.yaml").unlink()
    for camera in ("auto", "cam0"):
        out = tmp_path / f"out_{camera}"
        report = restore_input(recording, out, backend, RestoreOptions(camera=camera))
        assert report.cameras == ["cam0"] and report.restored == 3 and report.failed == 0
        assert len(list((out / "mav0" / "cam0" / "data").glob("*.png"))) == 3
        assert not (out / "mav0" / "cam1").exists()
    for camera in ("cam1", "both"):  # asked for by name: the missing folder is the one line
        with pytest.raises(CaptureError, match=r"cam1: missing camera folder \(cam1\)"):
            restore_input(recording, tmp_path / camera, backend, RestoreOptions(camera=camera))


def test_left_right_folders_named_by_frame_index_restore_every_frame(
    tmp_path: Path, backend: TorchBackend
) -> None:
    """Two runs' frame indices (run1_000001, run2_000001) are no timestamps: no duplicates."""
    names = [f"run{run}_00000{index}.png" for run in (1, 2) for index in (1, 2, 3)]
    root = _left_right(tmp_path / "seq", names)
    assert detect_input(root) == "folder"
    report = restore_input(root, tmp_path / "out", backend, RestoreOptions())
    assert report.restored == 12 and report.failed == 0 and not report.problems
    timestamps = _left_right(tmp_path / "ts", ["1000000000.png", "2000000000.png"])
    assert detect_input(timestamps) == "folders"  # unique timestamps: still a recording


def _left_right(root: Path, names: list[str]) -> Path:
    for side in ("left", "right"):
        for index, name in enumerate(names):
            write_image(root / side / name, _image(index))
    write_rig_file(root / "rig.yaml", RigFile(obstructed="cam1", anomaly=("rain",)))
    return root


def test_left_right_recording_restores_the_obstructed_camera(
    tmp_path: Path, backend: TorchBackend
) -> None:
    names = [f"{1_700_000_000_000_000_000 + k * 10**8}.png" for k in range(2)]
    recording = _left_right(tmp_path / "rec", names)
    assert detect_input(recording) == "folders"
    report = restore_input(recording, tmp_path / "out", backend)
    assert report.cameras == ["cam1"] and report.restored == 2
    out = tmp_path / "out"
    assert file_tree(out / "left") == file_tree(recording / "left")  # the clean camera: unchanged
    assert file_tree(out / "right") != file_tree(recording / "right")
    assert (out / "rig.yaml").read_bytes() == (recording / "rig.yaml").read_bytes()


def test_left_right_folders_without_timestamps_stay_a_folder(
    tmp_path: Path, backend: TorchBackend
) -> None:
    folder = _left_right(tmp_path / "pics", ["a.png", "b.png"])
    assert detect_input(folder) == "folder"
    assert restore_input(folder, tmp_path / "out", backend).restored == 4


def test_resume_with_other_settings_is_refused(tmp_path: Path, backend: TorchBackend) -> None:
    source = _folder(tmp_path / "in", 3)
    out = tmp_path / "out"
    first = restore_input(source, out, backend, RestoreOptions(batch_size=2))
    assert first.settings["batch_size"] == 2 and first.settings["model_sha256"]
    written = file_tree(out)
    with pytest.raises(ModelError, match=r"^--resume: .*batch_size: 2 -> 3"):
        restore_input(source, out, backend, RestoreOptions(batch_size=3, resume=True))
    assert file_tree(out) == written  # refused before anything was touched
    again = restore_input(source, out, backend, RestoreOptions(batch_size=2, resume=True))
    assert (again.resumed, again.restored) == (3, 0)


def test_resume_with_another_jpeg_quality_is_refused(
    tmp_path: Path, backend: TorchBackend, capsys: pytest.CaptureFixture[str]
) -> None:
    # the finished frames stay at the first quality: the output would mix two
    source = tmp_path / "in"
    for index in range(2):
        write_image(source / f"{index}.jpg", _image(index))
    out = tmp_path / "out"
    first = restore_input(source, out, backend, RestoreOptions(jpeg_quality=70))
    assert first.settings["jpeg_quality"] == 70
    written = file_tree(out)
    with pytest.raises(ModelError, match=r"^--resume: .*jpeg_quality: 70 -> 95"):
        restore_input(source, out, backend, RestoreOptions(resume=True))  # the default
    argv = ["restore", str(tmp_path / "ck.pt"), str(source), "--out", str(out), "--resume"]
    argv += ["--device", "cpu", "--precision", "fp32", "--jpeg-quality", "90"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "jpeg_quality: 70 -> 90" in err[0], err
    assert file_tree(out) == written  # refused before anything was touched
    again = restore_input(source, out, backend, RestoreOptions(jpeg_quality=70, resume=True))
    assert (again.resumed, again.restored) == (2, 0)
    # a run of an earlier version recorded no quality: its files are at OpenImageIO's 98
    report = out / REPORT_NAME
    recorded = json.loads(report.read_text())
    del recorded["settings"]["jpeg_quality"]
    report.write_text(json.dumps({**recorded, "complete": False}))
    written = file_tree(out)
    with pytest.raises(
        ModelError, match=r"jpeg_quality: 98 -> 70.*same ones \(--jpeg-quality 98\)"
    ):
        restore_input(source, out, backend, RestoreOptions(jpeg_quality=70, resume=True))
    assert file_tree(out) == written
    again = restore_input(source, out, backend, RestoreOptions(jpeg_quality=98, resume=True))
    assert again.resumed == 2


def test_an_earlier_lenspair_s_jpeg_files_were_written_at_98(tmp_path: Path) -> None:
    # what EARLIER_JPEG_QUALITY says of files: OpenImageIO's default is jpeg:98 to the byte
    from lenspair.model.inference.resume import EARLIER_JPEG_QUALITY

    image = _image(0)
    write_image(tmp_path / "default.jpg", image)
    write_image(tmp_path / "given.jpg", image, jpeg_quality=EARLIER_JPEG_QUALITY["files"])
    assert (tmp_path / "default.jpg").read_bytes() == (tmp_path / "given.jpg").read_bytes()


@pytest.mark.parametrize("quality", [0, 101])
def test_a_jpeg_quality_outside_1_to_100_is_refused_before_out_is_made(
    tmp_path: Path, backend: TorchBackend, quality: int
) -> None:
    source = _folder(tmp_path / "in", 1)
    with pytest.raises(ModelError, match=rf"^--jpeg-quality: expected .*1 to 100, got {quality}$"):
        restore_input(source, tmp_path / "out", backend, RestoreOptions(jpeg_quality=quality))
    assert not (tmp_path / "out").exists()


def test_resume_takes_the_same_model_however_its_path_is_typed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, backend: TorchBackend
) -> None:
    # A resume typed from another folder ("helperF/mono.pt" for "mono.pt") was refused.
    source = _folder(tmp_path / "in", 2)
    monkeypatch.chdir(tmp_path)
    typed = open_backend(Path("ck.pt"), torch.device("cpu"), "fp32")
    restore_input(source, tmp_path / "out", typed)
    monkeypatch.chdir(tmp_path / "in")
    again = open_backend(Path("../ck.pt"), torch.device("cpu"), "fp32")
    resumed = restore_input(source, tmp_path / "out", again, RestoreOptions(resume=True))
    assert (resumed.resumed, resumed.restored) == (2, 0)
    # a run recorded by an earlier version holds the path as typed: the same file resumes
    report = tmp_path / "out" / REPORT_NAME
    recorded = json.loads(report.read_text())
    recorded["settings"]["model"] = "torch checkpoint ck.pt on cpu (fp32)"
    report.write_text(json.dumps({**recorded, "complete": False}))
    resumed = restore_input(source, tmp_path / "out", again, RestoreOptions(resume=True))
    assert (resumed.resumed, resumed.restored) == (2, 0)
    recorded["settings"]["model"] = "torch checkpoint ck.pt on cpu (bf16)"  # but not another
    report.write_text(json.dumps({**recorded, "complete": False}))
    with pytest.raises(ModelError, match=r"--resume: .*\(bf16\)"):
        restore_input(source, tmp_path / "out", again, RestoreOptions(resume=True))


def test_an_image_too_small_for_the_network_costs_only_itself(
    tmp_path: Path, backend: TorchBackend
) -> None:
    source = tmp_path / "in"
    write_image(source / "a.png", _image(0))
    write_image(source / "tiny.png", _image(1)[:5, :7])
    report = restore_input(source, tmp_path / "out", backend)
    assert (report.restored, report.failed) == (1, 1)
    (problem,) = report.problems
    assert problem["frame"] == "tiny.png" and "7x5 pixels" in problem["reason"]
    assert (tmp_path / "out" / "tiny.png").read_bytes() == (source / "tiny.png").read_bytes()


def _restored_folder(tmp_path: Path, backend: TorchBackend) -> tuple[Path, Path]:
    """Two images restored from ``tmp_path/in`` into ``tmp_path/out``."""
    source = _folder(tmp_path / "in", 2)
    restore_input(source, tmp_path / "out", backend)
    return source, tmp_path / "out"


def test_resume_redoes_an_output_a_power_cut_left_empty(
    tmp_path: Path, backend: TorchBackend
) -> None:
    source, out = _restored_folder(tmp_path, backend)
    whole = (out / "1.png").read_bytes()
    (out / "1.png").write_bytes(b"")  # renamed into place, its data never reached the disk
    report = restore_input(source, out, backend, RestoreOptions(resume=True))
    assert (report.resumed, report.restored) == (1, 1)
    assert (out / "1.png").read_bytes() == whole


def test_resume_redoes_a_frame_that_was_copied_because_it_failed(
    tmp_path: Path, backend: TorchBackend
) -> None:
    source = _folder(tmp_path / "in", 3)
    whole = (source / "1.png").read_bytes()
    (source / "1.png").write_bytes(whole[:100])  # truncated: fails, copied unchanged
    out = tmp_path / "out"
    first = restore_input(source, out, backend)
    assert (first.restored, first.failed) == (2, 1)
    assert (out / "1.png").read_bytes() == whole[:100]
    (source / "1.png").write_bytes(whole)  # the file is whole again
    again = restore_input(source, out, backend, RestoreOptions(resume=True))
    assert (again.resumed, again.restored, again.failed, again.problems) == (2, 1, 0, [])
    restored = read_image(out / "1.png")
    assert restored.shape == _image(1).shape and (out / "1.png").read_bytes() != whole
    assert not (out / ".restore-copies").exists()  # no copy left
    third = restore_input(source, out, backend, RestoreOptions(resume=True))
    assert (third.resumed, third.restored) == (3, 0)


def test_a_kill_while_naming_a_copy_leaves_a_list_resume_reads(
    tmp_path: Path, backend: TorchBackend
) -> None:
    source, out = _restored_folder(tmp_path, backend)
    (out / "0.png").write_bytes((source / "0.png").read_bytes())  # a copy, named ...
    (out / ".restore-copies").write_text('"0.png"\n"1.p')  # ... and a name cut mid-line
    # reading a cut list ends it cleanly, so the next name stands alone
    sink = file_sink.FileSink(out)
    assert (out / ".restore-copies").read_text() == '"0.png"\n'
    assert sink.copies == {"0.png"}
    again = restore_input(source, out, backend, RestoreOptions(resume=True))
    assert (again.resumed, again.restored) == (1, 1)
    assert (out / "0.png").read_bytes() != (source / "0.png").read_bytes()


def test_a_ros2_bag_folder_keeps_its_rig_file(tmp_path: Path, backend: TorchBackend) -> None:
    (tmp_path / "b").mkdir()
    frames = {"cam0": [(10**9 + k * 10**8, _image(k)) for k in range(2)]}
    bag = write_bag(tmp_path / "b" / "run", "db3", frames)
    write_rig_file(bag / "rig.yaml", RigFile(obstructed="cam0", anomaly=("rain",)))
    report = restore_input(bag, tmp_path / "out", backend)
    written = Path(report.output)
    assert (written / "rig.yaml").read_bytes() == (bag / "rig.yaml").read_bytes()
    ours = sorted(p.name for p in written.iterdir())
    assert sum(name.endswith(".db3") for name in ours) == 1 and "metadata.yaml" in ours
    assert [p["reason"] for p in report.problems] == []  # a rig file holds no frame


@pytest.mark.parametrize("kind", ["db3", "mcap"])
def test_a_bag_recorded_with_file_compression_is_copied_into_its_own_storage(
    tmp_path: Path, backend: TorchBackend, kind: str
) -> None:
    # run.mcap.zstd: the storage was told by the last suffix, so an MCAP bag came out as
    # SQLite, and the source's compressed storage was copied beside the copy as a rig file
    (tmp_path / "b").mkdir()
    frames = {"cam0": [(10**9 + k * 10**8, _image(k)) for k in range(2)]}
    bag = write_bag(tmp_path / "b" / "run", kind, frames, compress_files=True)
    assert any(p.name.endswith(f".{kind}.zstd") for p in bag.iterdir())
    write_rig_file(bag / "rig.yaml", RigFile(obstructed="cam0", anomaly=("rain",)))
    report = restore_input(bag, tmp_path / "out", backend)
    assert (report.restored, report.failed) == (2, 0)
    ours = sorted(p.name for p in Path(report.output).iterdir())
    assert ours == ["metadata.yaml", "rig.yaml", f"run.{kind}"], ours


def test_a_ros1_bag_kept_in_a_ros2_bag_folder_is_copied_and_named(
    tmp_path: Path, backend: TorchBackend
) -> None:
    # its frames were not restored: the report says so, as for one found in a folder
    (tmp_path / "b").mkdir()
    frames = {"cam0": [(10**9 + k * 10**8, _image(k)) for k in range(2)]}
    bag = write_bag(tmp_path / "b" / "run", "db3", frames)
    write_rig_file(bag / "rig.yaml", RigFile(obstructed="cam0", anomaly=("rain",)))
    (bag / "older.bag").write_bytes(b"#ROSBAG V2.0\n")
    for run in range(2):  # the rerun, which finds the copy in place, says it again
        report = restore_input(bag, tmp_path / "out", backend, RestoreOptions(resume=run > 0))
        written = Path(report.output)
        assert (written / "older.bag").read_bytes() == (bag / "older.bag").read_bytes()
        reasons = [p["reason"] for p in report.problems]
        assert reasons == [
            f"{bag / 'older.bag'}: a bag, copied as it is: restore it as an INPUT of its own"
        ]


def _zlib_level(png: bytes) -> int:
    """FLEVEL of the zlib stream in a PNG's first IDAT (0 fastest ... 2 default ... 3 best)."""
    at = png.index(b"IDAT") + 4
    return png[at + 1] >> 6


def test_restored_pngs_are_written_for_speed(tmp_path: Path, backend: TorchBackend) -> None:
    write_image(tmp_path / "in" / "a.png", _image(0))
    assert _zlib_level((tmp_path / "in" / "a.png").read_bytes()) == 2  # the library default
    restore_input(tmp_path / "in", tmp_path / "out", backend)
    assert _zlib_level((tmp_path / "out" / "a.png").read_bytes()) == 0  # FAST_PNG: level 1


def test_a_restored_frame_that_cannot_be_written_is_copied_and_counted_once(
    tmp_path: Path, backend: TorchBackend, monkeypatch: pytest.MonkeyPatch
) -> None:
    source = _folder(tmp_path / "in", 4)
    real_write = file_sink.FileSink.write
    writer_threads = []

    def write(self: file_sink.FileSink, item: object, restored: np.ndarray | None) -> None:
        writer_threads.append(threading.current_thread().name)
        if restored is not None and getattr(item, "name", "") == "2.png":
            raise ValueError("2.png: cannot encode")
        real_write(self, item, restored)  # type: ignore[arg-type]

    counted_in = set()

    def count(self: RestoreReport, name: str, value: object) -> None:
        counted_in.add(threading.current_thread().name)
        object.__setattr__(self, name, value)

    monkeypatch.setattr(file_sink.FileSink, "write", write)
    monkeypatch.setattr(RestoreReport, "__setattr__", count)
    report = restore_input(source, tmp_path / "out", backend, RestoreOptions(batch_size=2))
    assert set(writer_threads) == {"restore-writer"}
    assert counted_in == {threading.main_thread().name}  # counters never raced by the writer
    assert (report.frames_read, report.restored, report.failed) == (4, 3, 1)
    assert report.problems == [{"frame": "2.png", "reason": "2.png: cannot encode"}]
    assert (tmp_path / "out" / "2.png").read_bytes() == (source / "2.png").read_bytes()
    assert (tmp_path / "out" / "1.png").read_bytes() != (source / "1.png").read_bytes()


def test_a_frame_that_can_be_neither_read_nor_copied_is_one_problem(
    tmp_path: Path, backend: TorchBackend, monkeypatch: pytest.MonkeyPatch
) -> None:
    source = tmp_path / "in"
    write_image(source / "a.png", (texture((32, 48), seed=1) * 255).astype(np.uint8))
    (source / "gone.png").write_bytes(b"")  # cannot be read ...
    real_open = open

    def refusing(path: object, *args: object, **kwargs: object) -> object:
        if str(path).endswith("gone.png"):  # ... nor copied (chmod 000 does not stop root)
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return real_open(path, *args, **kwargs)  # type: ignore[call-overload]

    monkeypatch.setattr(file_sink, "open", refusing, raising=False)
    report = restore_input(source, tmp_path / "out", backend)
    assert (report.restored, report.failed) == (1, 1)
    (problem,) = report.problems  # it was listed twice: unreadable, then not copied
    assert problem["frame"] == "gone.png" and problem["reason"].endswith("not copied to OUT")


def test_input_files_named_like_restores_own_are_said_not_overwritten(
    tmp_path: Path, backend: TorchBackend
) -> None:
    source = tmp_path / "in"
    write_image(source / "a.png", (texture((32, 48), seed=1) * 255).astype(np.uint8))
    (source / "restore_report.json").write_text('{"mine": 1}')
    (source / ".restore-copies").write_text("x\n")
    (source / "sub").mkdir()
    (source / "sub" / "restore_report.json").write_text('{"deeper": 1}')  # no clash there
    report = restore_input(source, tmp_path / "out", backend)
    clashes = sorted(p["reason"] for p in report.problems)
    assert len(clashes) == 2
    assert ".restore-copies: not copied" in clashes[0] and "restore_report.json: not" in clashes[1]
    assert "mine" not in (tmp_path / "out" / "restore_report.json").read_text()
    assert (tmp_path / "out" / "sub" / "restore_report.json").read_text() == '{"deeper": 1}'


def test_an_earlier_restores_output_restores_without_problems(
    tmp_path: Path, backend: TorchBackend, caplog: pytest.LogCaptureFixture
) -> None:
    # restoring a restore's OUT listed its report and lock as two problems, each
    # advising to rename a file lenspair wrote
    source = tmp_path / "in"
    write_image(source / "a.png", (texture((32, 48), seed=1) * 255).astype(np.uint8))
    restore_input(source, tmp_path / "first", backend)
    assert (tmp_path / "first" / RESTORE_LOCK).exists()
    with caplog.at_level(logging.INFO, logger="lenspair"):
        report = restore_input(tmp_path / "first", tmp_path / "second", backend)
    assert (report.restored, report.problems) == (1, [])
    said = [r.getMessage() for r in caplog.records if "earlier restore" in r.getMessage()]
    assert said == [
        f"{tmp_path / 'first'} is an earlier restore's output: its "
        f"{RESTORE_LOCK}, restore_report.json not copied"
    ]
    second = json.loads((tmp_path / "second" / "restore_report.json").read_text())
    assert second["input"] == str(tmp_path / "first")  # its own report, not the first's


def test_a_file_name_that_is_not_utf8_costs_only_its_frame(
    tmp_path: Path, backend: TorchBackend
) -> None:
    # OpenImageIO's binding raised TypeError on it: a traceback, the run stopped
    source = tmp_path / "in"
    pixels = (texture((32, 48), seed=1) * 255).astype(np.uint8)
    write_image(source / "ok.png", pixels)
    odd = source / os.fsdecode(b"x\xff.png")  # a Latin-1 name from an old camera
    shutil.copyfile(source / "ok.png", odd)
    report = restore_input(source, tmp_path / "out", backend)
    assert (report.restored, report.failed) == (1, 1)
    (problem,) = report.problems
    assert "not UTF-8" in problem["reason"]
    assert (tmp_path / "out" / odd.name).read_bytes() == odd.read_bytes()  # copied as it is
    with pytest.raises(ImageIOError, match=r"x\\udcff\.png: the file name is not UTF-8"):
        imageio.read_image(odd)


def test_links_a_folder_listing_passes_over_are_said(tmp_path: Path, backend: TorchBackend) -> None:
    # a linked folder and a dangling link were left out without a word
    source = tmp_path / "in"
    write_image(source / "real" / "a.png", (texture((32, 48), seed=1) * 255).astype(np.uint8))
    write_image(tmp_path / "other" / "b.png", (texture((32, 48), seed=2) * 255).astype(np.uint8))
    (source / "linked").symlink_to(tmp_path / "other")
    (source / "dangling.png").symlink_to(tmp_path / "gone.png")
    report = restore_input(source, tmp_path / "out", backend)
    assert report.restored == 1
    reasons = sorted(p["reason"] for p in report.problems)
    assert len(reasons) == 2
    assert reasons[0].startswith(f"{source / 'dangling.png'}: a link to nothing")
    assert reasons[1].startswith(f"{source / 'linked'}: a link to a folder, not followed")


def test_a_subfolder_that_cannot_be_read_is_said_not_skipped(
    tmp_path: Path, backend: TorchBackend, monkeypatch: pytest.MonkeyPatch
) -> None:
    # a folder its user may not read: its frames were missing from every count, unsaid
    source = tmp_path / "in"
    write_image(source / "a.png", (texture((32, 48), seed=1) * 255).astype(np.uint8))
    write_image(source / "locked" / "b.png", (texture((32, 48), seed=2) * 255).astype(np.uint8))
    scandir = os.scandir

    def refuse(path: str) -> object:  # what a folder without read permission gives (not root)
        if Path(path) == source / "locked":
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return scandir(path)

    monkeypatch.setattr(os, "scandir", refuse)
    report = restore_input(source, tmp_path / "out", backend)
    assert (report.frames_read, report.restored) == (1, 1)
    (problem,) = report.problems
    assert problem["reason"] == (
        f"{source / 'locked'}: cannot read this folder (Permission denied); its images are left out"
    )


def test_a_restored_image_keeps_its_orientation_and_a_multi_page_file_is_kept_whole(
    tmp_path: Path,
    backend: TorchBackend,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
) -> None:
    import OpenImageIO as oiio  # the test writes what lenspair's own writer does not

    source = tmp_path / "in"
    source.mkdir()
    pixels = (texture((32, 48), seed=1) * 255).astype(np.uint8)
    spec = oiio.ImageSpec(48, 32, 1, "uint8")
    spec.attribute("Orientation", 6)  # a phone held upright: viewers turn it 90 degrees
    turned = oiio.ImageOutput.create(str(source / "turned.png"))
    assert turned.open(str(source / "turned.png"), spec) and turned.write_image(pixels[:, :, None])
    turned.close()
    pages = oiio.ImageOutput.create(str(source / "pages.tif"))
    plain = oiio.ImageSpec(48, 32, 1, "uint8")
    assert pages.open(str(source / "pages.tif"), (plain, plain))
    pages.write_image(pixels[:, :, None])
    assert pages.open(str(source / "pages.tif"), plain, "AppendSubimage")
    pages.write_image(pixels[:, :, None])
    pages.close()
    monkeypatch.setattr(imageio, "_SAID", set())
    with caplog.at_level("WARNING", logger="lenspair.core.imageio"):
        report = restore_input(source, tmp_path / "out", backend)
    assert not caplog.messages  # not "only the first is read": it is copied whole
    assert (report.restored, report.failed) == (1, 1)
    # the orientation was dropped: the restored image showed turned against the input
    assert imageio.image_layout(tmp_path / "out" / "turned.png") == (6, 1)
    # the second page was dropped without a word; now the file is copied whole and listed
    (problem,) = report.problems
    assert problem["frame"] == "pages.tif" and "several pages" in problem["reason"]
    assert (tmp_path / "out" / "pages.tif").read_bytes() == (source / "pages.tif").read_bytes()


@pytest.mark.parametrize("name", ["../escaped.png", "a/../../escaped.png", "/tmp/escaped.png"])
def test_a_file_sink_writes_nothing_outside_out(tmp_path: Path, name: str) -> None:
    original = tmp_path / "in.png"
    write_image(original, np.full((8, 8), 7, np.uint8))
    frame = InputFrame(0, name, None, None, str(original), None)
    sink = file_sink.FileSink(tmp_path / "OUT")
    for restored in (None, np.zeros((8, 8), np.uint8)):
        with pytest.raises(CaptureError, match="leaves OUT; not written"):
            sink.write(frame, restored)
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["in.png"]


class _Hungry(torch.nn.Module):
    """Runs batches of up to ``fits`` frames; a larger one fails as the CPU allocator does."""

    def __init__(self, fits: int) -> None:
        super().__init__()
        self.fits = fits
        self.sizes: list[int] = []

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        self.sizes.append(len(x))
        if len(x) > self.fits:
            raise RuntimeError(
                "[enforce fail at alloc_cpu.cpp:118] DefaultCPUAllocator: can't allocate memory"
            )
        return x, 1.0 - x


def test_a_batch_out_of_memory_runs_frame_by_frame_and_one_frame_says_tile() -> None:
    batch = np.random.default_rng(0).random((3, 1, 8, 12), dtype=np.float32)
    network = _Hungry(fits=1)
    backend = TorchBackend(network, 1, torch.device("cpu"), path=Path("m.pt"))
    np.testing.assert_allclose(backend(batch), 1.0 - batch)
    assert network.sizes == [3, 1, 1, 1]
    starved = TorchBackend(_Hungry(fits=0), 1, torch.device("cpu"), path=Path("m.pt"))
    with pytest.raises(
        ModelError, match=r"^m.pt: out of memory restoring one 12x8 image .*--tile 16"
    ):
        starved(batch)
    # the tiles it suggests are at most half the image's longer side (a tile that fails
    # suggests smaller tiles): 600 -> 256, 512 -> 256
    for width, tile in ((600, 256), (512, 256)):
        with pytest.raises(
            ModelError, match=rf"one {width}x8 image .*\(--tile {tile}, or a smaller"
        ):
            starved(np.zeros((1, 1, 8, width), np.float32))
    with pytest.raises(RuntimeError, match="other"):  # not an allocation failure: as raised
        TorchBackend(_Raises(), 1, torch.device("cpu"))(batch)


class _Raises(torch.nn.Module):
    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        raise RuntimeError("other")


def test_a_run_that_restores_no_frame_at_all_is_not_done(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """One unreadable image (or a folder of them) exited 0, "1 failed": a script read it
    as done. Partial failures still end 0, each listed."""
    from lenspair.cli import main

    checkpoint = make_checkpoint(tmp_path / "ck.pt")
    (tmp_path / "junk.png").write_bytes(b"\x89PNG\r\n\x1a\nnot an image")
    args = ["restore", str(checkpoint), str(tmp_path / "junk.png"), "--precision", "fp32"]
    assert main([*args, "--out", str(tmp_path / "o1")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "none of the 1 frame(s) could be restored" in err[0]
    assert "junk.png" in err[0] and str(tmp_path / "o1" / REPORT_NAME) in err[0]
    assert json.loads((tmp_path / "o1" / REPORT_NAME).read_text())["failed"] == 1
    source = _folder(tmp_path / "in", 2)
    shutil.copy(tmp_path / "junk.png", source / "junk.png")
    args = ["restore", str(checkpoint), str(source), "--precision", "fp32"]
    assert main([*args, "--out", str(tmp_path / "o2")]) == 0  # two restored, one listed


def test_problem_lines_name_each_frame_once_and_count_the_rest() -> None:
    report = RestoreReport(input="in", kind="folder", output="out", model="m", cameras=[])
    report.problems = [
        {"frame": "a.png", "reason": "in/a.png: empty file (0 bytes)"},
        {"frame": "b.png", "reason": "1 channel(s), the network takes 3"},
        {"frame": "", "reason": "notes.txt: copied unrestored"},
    ]
    assert report.problem_lines(limit=2) == [
        "in/a.png: empty file (0 bytes)",
        "b.png: 1 channel(s), the network takes 3",
        f"... and 1 more in {REPORT_NAME}",
    ]
    assert report.problem_lines()[-1] == "notes.txt: copied unrestored"


def test_an_overlap_past_half_the_tile_is_said_with_its_cost(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # --tile 16 --overlap 15 stepped one pixel at a time: 124 s for five small frames, unsaid
    from lenspair.model.inference.restore_options import RestoreOptions, check_options

    with caplog.at_level("WARNING"):
        check_options(RestoreOptions(tile=64, overlap=32))  # half: each pixel about 4 times
        assert not caplog.records
        check_options(RestoreOptions(tile=16, overlap=15))
    (said,) = [r.getMessage() for r in caplog.records]
    assert said.startswith("--overlap 15 of --tile 16: tiles step 1 px")
    assert "computed about 256 times" in said


@pytest.mark.parametrize(("stray", "refused"), [(1, False), (2, False), (3, True)])
def test_frames_of_other_channels_first_in_a_folder_refuse_the_run_only_when_three(
    tmp_path: Path, backend: TorchBackend, stray: int, refused: bool
) -> None:
    # a grey thumbnail named first in a folder of the mono network's... RGB frames here:
    # whether it was one failed frame or stopped the run depended on its name's order
    source = tmp_path / "in"
    for index in range(stray):
        rgb = np.repeat(_image(10 + index)[..., None], 3, axis=2)
        write_image(source / f"a_{index}.png", rgb)
    for index in range(3):  # named after the strays: the order the folder is read in
        write_image(source / f"f_{index}.png", _image(index))
    out = tmp_path / "out"
    if refused:
        with pytest.raises(ModelError, match=r"a_0\.png: 3 channel\(s\) but the network takes 1"):
            restore_input(source, out, backend)
        assert not out.exists() or not any(out.iterdir())  # nothing written
        return
    report = restore_input(source, out, backend)
    assert (report.restored, report.failed) == (3, stray)
    failed = sorted(p["frame"] for p in report.problems if "network takes 1" in p["reason"])
    assert failed == [f"a_{index}.png" for index in range(stray)]
    assert sorted(p.name for p in out.glob("*.png")) == [
        *(f"a_{i}.png" for i in range(stray)), "f_0.png", "f_1.png", "f_2.png"
    ]  # fmt: skip


def test_one_restore_writes_an_out_at_a_time(
    tmp_path: Path, backend: TorchBackend, monkeypatch: pytest.MonkeyPatch
) -> None:
    # two runs started together both found OUT empty and both wrote it (23 images beside
    # a 12-row data.csv); a --resume retry ran beside the live run
    from lenspair.core.folderlock import lock_file
    from lenspair.model.inference import pipeline

    source, out = _folder(tmp_path / "in", 2), tmp_path / "out"
    restore_input(source, out, backend)
    before = file_tree(out)
    held = lock_file(out / pipeline.RESTORE_LOCK, "restore")  # a --resume of it, running
    assert held is not None
    try:
        with pytest.raises(ModelError, match=r"^--out .*out: another restore is writing it"):
            restore_input(source, out, backend, RestoreOptions(resume=True))
    finally:
        os.close(held)
    assert file_tree(out) == before
    make_folder, taken = pipeline.make_folder, []

    def started_together(folder: Path) -> list[Path]:  # the other run, a moment ahead
        made = make_folder(folder)
        taken.append(lock_file(folder / pipeline.RESTORE_LOCK, "restore"))
        return made

    monkeypatch.setattr(pipeline, "make_folder", started_together)
    try:
        with pytest.raises(ModelError, match=r"another restore is writing it"):
            restore_input(source, tmp_path / "new", backend)
    finally:
        os.close(taken[0])
    assert [p.name for p in (tmp_path / "new").iterdir()] == [pipeline.RESTORE_LOCK]


def test_an_out_filled_while_the_model_loaded_is_refused_and_left_as_it_was(
    tmp_path: Path, backend: TorchBackend, monkeypatch: pytest.MonkeyPatch
) -> None:
    from lenspair.model.inference import pipeline
    from lenspair.model.inference.input_checks import check_input

    source, out = _folder(tmp_path / "in", 2), tmp_path / "out"
    checked = check_input(source, out, RestoreOptions())  # OUT empty then (it is not there)
    make_folder = pipeline.make_folder

    def finished_meanwhile(folder: Path) -> list[Path]:
        made = make_folder(folder)
        (folder / "0.png").write_bytes(b"another run's output")
        return made

    monkeypatch.setattr(pipeline, "make_folder", finished_meanwhile)
    with pytest.raises(ModelError, match=r"another restore filled it meanwhile; pass --resume"):
        restore_input(source, out, backend, checked=checked)
    assert sorted(p.name for p in out.iterdir()) == ["0.png"]


@pytest.mark.parametrize("resume", [False, True])
def test_a_run_killed_before_its_first_report_leaves_an_out_a_rerun_takes(
    tmp_path: Path, backend: TorchBackend, resume: bool
) -> None:
    # killed before its first report, a run left OUT holding its lock alone: the rerun
    # was refused as "not empty", and --resume as "no restore run wrote it"
    from lenspair.model.inference.report import RESTORE_LOCK

    source, out = _folder(tmp_path / "in", 2), tmp_path / "out"
    out.mkdir()
    (out / RESTORE_LOCK).touch()
    report = restore_input(source, out, backend, RestoreOptions(resume=resume))
    assert (report.restored, report.failed) == (2, 0)
