import json
import multiprocessing
import pickle
from pathlib import Path

import cv2
import numpy as np
import pytest

from lenspair.capture.calibration_source import find_calibration
from lenspair.capture.errors import CaptureError
from lenspair.capture.folders import timestamp_from_name
from lenspair.capture.recording import (
    FrameRef,
    load_frame,
    open_recording,
    resolve_obstructed,
)
from lenspair.capture.recording_types import SIMULATION_INCOMPLETE
from lenspair.capture.rigfile import RigFile, write_rig_file
from lenspair.cli import main
from lenspair.core.errors import ConfigError, ImageIOError
from lenspair.core.imagewrite import write_image

MS = 1_000_000
T0 = 1_403_636_579_763_555_584


def _image(seed: int, dtype: type = np.uint8, colour: bool = False) -> np.ndarray:
    shape = (12, 16, 3) if colour else (12, 16)
    rng = np.random.default_rng(seed)
    return rng.integers(0, np.iinfo(dtype).max, shape, endpoint=True).astype(dtype)


def _write_camera(camera_dir: Path, stamps: list[int], rows: list[str] | None = None) -> None:
    """EuRoC camera folder; ``rows`` overrides the data.csv body."""
    (camera_dir / "data").mkdir(parents=True, exist_ok=True)
    for i, t in enumerate(stamps):
        write_image(camera_dir / "data" / f"{t}.png", _image(t % 1000 + i))
    body = rows if rows is not None else [f"{t},{t}.png" for t in stamps]
    text = "#timestamp [ns],filename\n" + "".join(r + "\n" for r in body)
    (camera_dir / "data.csv").write_text(text)
    (camera_dir / "sensor.yaml").write_text("sensor_type: camera\n")


def _euroc(root: Path, n: int = 4, offset: int = 2 * MS) -> list[int]:
    stamps = [T0 + i * 50 * MS for i in range(n)]
    _write_camera(root / "mav0" / "cam0", stamps)
    _write_camera(root / "mav0" / "cam1", [t + offset for t in stamps])
    return stamps


def test_an_unfinished_simulation_is_refused_until_it_is_done(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # a killed simulate had written some frames: read anyway, they became a dataset, exit 0
    _euroc(tmp_path / "sim")
    marker = tmp_path / "sim" / SIMULATION_INCOMPLETE
    marker.write_text("pid 1: simulating\n")
    for given in (tmp_path / "sim", tmp_path / "sim" / "mav0"):
        with pytest.raises(CaptureError, match="unfinished simulation") as caught:
            open_recording(given)
        assert str(marker) in str(caught.value)
    assert main(["capture-ingest", str(tmp_path / "sim"), "--out", str(tmp_path / "ds")]) == 2
    assert "unfinished simulation" in capsys.readouterr().err
    marker.unlink()
    assert open_recording(tmp_path / "sim").layout == "euroc"


def test_euroc_layouts_are_detected(tmp_path: Path) -> None:
    stamps = _euroc(tmp_path / "MH_01")
    for given in (tmp_path / "MH_01", tmp_path / "MH_01" / "mav0"):
        recording = open_recording(given)
        assert recording.layout == "euroc"
        assert recording.recording_id == "MH_01"
        assert recording.timestamps("cam0") == stamps
        assert recording.timestamps("cam1") == [t + 2 * MS for t in stamps]
        assert recording.problems == []
        assert set(recording.sensor_files) == {"cam0", "cam1"}
    frame = recording.frames["cam0"][1]
    np.testing.assert_array_equal(recording.load(frame), _image(stamps[1] % 1000 + 1))


def test_euroc_header_and_missing_data_csv(tmp_path: Path) -> None:
    stamps = _euroc(tmp_path)
    csv = tmp_path / "mav0" / "cam0" / "data.csv"
    csv.write_text(csv.read_text().lstrip("#"))  # header without '#' is still a header
    assert open_recording(tmp_path).problems == []
    for camera in ("cam0", "cam1"):
        (tmp_path / "mav0" / camera / "data.csv").unlink()
    assert open_recording(tmp_path).timestamps("cam0") == stamps


def test_a_camera_folder_that_cannot_be_listed_is_an_input_error_naming_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # "Permission denied" with exit 1, the code of a refused write (tests run as root,
    # whom chmod does not stop: the listing itself is refused here)
    _euroc(tmp_path / "rec")
    refused = tmp_path / "rec" / "mav0" / "cam1" / "data"
    real_iterdir = Path.iterdir

    def iterdir(self: Path):  # type: ignore[no-untyped-def]
        if self == refused:
            raise PermissionError(13, "Permission denied", str(self))
        return real_iterdir(self)

    monkeypatch.setattr(Path, "iterdir", iterdir)
    with pytest.raises(CaptureError, match=rf"^{refused}: cannot be read \(Permission denied\)$"):
        open_recording(tmp_path / "rec")
    assert main(["capture-ingest", str(tmp_path / "rec"), "--out", str(tmp_path / "out")]) == 2
    assert f"{refused}: cannot be read" in capsys.readouterr().err


def test_euroc_problems_are_recorded(tmp_path: Path) -> None:
    stamps = [T0 + i * 50 * MS for i in range(5)]
    cam0 = tmp_path / "mav0" / "cam0"
    _write_camera(cam0, stamps)
    write_image(cam0 / "data" / "unlisted.png", _image(0))
    rows = [
        f"{stamps[0]},{stamps[0]}.png",
        f"{stamps[2]},{stamps[2]}.png",
        f"{stamps[1]},{stamps[1]}.png",  # goes back: kept, warned
        f"{stamps[2]},{stamps[3]}.png",  # duplicate timestamp: dropped
        f"{stamps[4]},gone.png",  # missing file
        "not-a-number,x.png",
        "only-one-field",
    ]
    (cam0 / "data.csv").write_text("#timestamp [ns],filename\n" + "\n".join(rows) + "\n")
    _write_camera(tmp_path / "mav0" / "cam1", stamps)
    recording = open_recording(tmp_path)
    assert recording.timestamps("cam0") == stamps[:3]
    problems = {(p.reason.split(" (")[0].split(":")[0], p.dropped) for p in recording.problems}
    assert problems == {
        ("timestamp goes back by 50.000 ms after t_ns=" + str(stamps[2]), False),
        ("duplicate timestamp", True),
        ("listed file missing", True),
        ("timestamp is not a non-negative integer", True),
        ("expected '<t_ns>,<file>', got 'only-one-field'", True),
        ("image not listed in data.csv", True),
    }
    where = {p.reason.split(":")[0]: p.source for p in recording.problems}
    assert where["listed file missing"] == f"{cam0 / 'data.csv'}:6"
    assert all(p.camera == "cam0" for p in recording.problems)


def test_a_file_listed_at_two_timestamps_is_one_frame(tmp_path: Path) -> None:
    """Its second row made a second frame of one file (one output name): a fresh restore
    counted it as resumed, or restored and wrote the file twice, and nothing was said."""
    stamps = [T0 + i * 50 * MS for i in range(4)]
    cam0 = tmp_path / "mav0" / "cam0"
    _write_camera(cam0, stamps)
    rows = [f"{t},{t}.png" for t in stamps] + [f"{stamps[-1] + 50 * MS},{stamps[1]}.png"]
    (cam0 / "data.csv").write_text("#timestamp [ns],filename\n" + "\n".join(rows) + "\n")
    _write_camera(tmp_path / "mav0" / "cam1", stamps)
    recording = open_recording(tmp_path)
    assert recording.timestamps("cam0") == stamps  # the file once, at its first time
    (problem,) = recording.problems
    assert problem.reason == (
        f"listed again with another timestamp (first at t_ns={stamps[1]}); counted once, "
        "at its first"
    )
    assert problem.t_ns == stamps[-1] + 50 * MS and not problem.dropped
    assert problem.camera == "cam0"


def test_euroc_names_outside_the_data_folder_are_problems(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    stamps = [T0 + i * 50 * MS for i in range(4)]
    cam0 = tmp_path / "rec" / "mav0" / "cam0"
    _write_camera(cam0, stamps)
    write_image(tmp_path / "escaped.png", _image(0))  # exists: only its place is wrong
    rows = [
        f"{stamps[0]},{stamps[0]}.png",
        f"{stamps[1]},{(cam0 / 'data' / f'{stamps[1]}.png').resolve()}",  # absolute, inside
        f"{stamps[2]},sub/../{stamps[2]}.png",  # stays inside
        f"{stamps[3]},../../../../escaped.png",
    ]
    (cam0 / "data.csv").write_text("\n".join(rows) + "\n")
    _write_camera(tmp_path / "rec" / "mav0" / "cam1", stamps)
    monkeypatch.chdir(tmp_path)  # a relative recording path, as typed on a command line
    recording = open_recording(Path("rec"))
    assert recording.timestamps("cam0") == stamps[:3]
    assert all(not ref.source.is_absolute() for ref in recording.frames["cam0"])
    # the escaping row, and the data/ file that no row names any more
    unlisted, problem = sorted(recording.problems, key=lambda p: p.reason)
    assert problem.reason.startswith("listed file lies outside") and problem.t_ns == stamps[3]
    assert unlisted.reason.startswith("image not listed") and unlisted.t_ns == stamps[3]
    assert problem.source.endswith("data.csv:4") and problem.dropped


def test_euroc_absolute_names_through_a_linked_folder_stay_inside(tmp_path: Path) -> None:
    # data.csv names the real path; the recording is opened through a link to its parent
    stamps = [T0 + i * 50 * MS for i in range(3)]
    real = tmp_path / "disk" / "rec"
    for camera in ("cam0", "cam1"):
        folder = real / "mav0" / camera
        _write_camera(folder, stamps)
        rows = [f"{t},{(folder / 'data' / f'{t}.png').resolve()}" for t in stamps]
        (folder / "data.csv").write_text("\n".join(rows) + "\n")
    (tmp_path / "link").symlink_to(tmp_path / "disk")
    recording = open_recording(tmp_path / "link" / "rec")
    assert recording.timestamps("cam0") == stamps == recording.timestamps("cam1")
    assert not [p for p in recording.problems if "outside" in p.reason]


def test_corrupt_image_lists_but_load_names_the_file(tmp_path: Path) -> None:
    _euroc(tmp_path)
    recording = open_recording(tmp_path)
    frame = recording.frames["cam1"][2]
    data = frame.source.read_bytes()
    frame.source.write_bytes(data[: len(data) // 2])
    assert open_recording(tmp_path).timestamps("cam1") == recording.timestamps("cam1")
    with pytest.raises(ImageIOError, match=frame.source.name):
        recording.load(frame)


def test_missing_camera_and_empty_recording(tmp_path: Path) -> None:
    _write_camera(tmp_path / "a" / "mav0" / "cam0", [T0])
    with pytest.raises(CaptureError, match=r"mav0/cam1: missing camera folder \(cam1\)"):
        open_recording(tmp_path / "a")
    _write_camera(tmp_path / "b" / "cam0", [], rows=[])
    _write_camera(tmp_path / "b" / "cam1", [], rows=[])
    with pytest.raises(CaptureError, match="no cam0 frames could be listed"):
        open_recording(tmp_path / "b")
    _write_camera(tmp_path / "c" / "cam0", [T0])
    _write_camera(tmp_path / "c" / "cam1", [T0], rows=[f"{T0},gone.png"])
    with pytest.raises(CaptureError, match=r"no cam1 frames.*listed file missing"):
        open_recording(tmp_path / "c")


def test_unknown_layout_and_bad_arguments(tmp_path: Path) -> None:
    (tmp_path / "stuff").mkdir()
    with pytest.raises(CaptureError, match=r"unknown recording layout; expected an EuRoC/ASL"):
        open_recording(tmp_path / "stuff")
    (tmp_path / "notes.txt").write_text("hi")
    with pytest.raises(CaptureError, match=r"notes.txt: unknown recording layout"):
        open_recording(tmp_path / "notes.txt")
    with pytest.raises(CaptureError, match="no such file or folder"):
        open_recording(tmp_path / "nope")
    _euroc(tmp_path / "rec")
    with pytest.raises(CaptureError, match="topics can only be chosen for bags"):
        open_recording(tmp_path / "rec", topics=("/a", "/b"))


def test_left_right_folders(tmp_path: Path) -> None:
    stamps = [T0 + i * 50 * MS for i in range(3)]
    for i, t in enumerate(stamps):
        write_image(tmp_path / "left" / f"left_{i:04d}_{t}.png", _image(i, np.uint16))
        write_image(
            tmp_path / "right" / f"{t // 10**9}.{t % 10**9:09d}.png", _image(i, colour=True)
        )
    write_image(tmp_path / "right" / "nostamp.png", _image(9))
    write_image(tmp_path / "left" / f"x_{stamps[0]}.tif", _image(9, np.uint16))  # same time
    (tmp_path / "left" / "notes.txt").write_text("ignored")
    recording = open_recording(tmp_path)
    assert recording.layout == "folders" and recording.recording_id == tmp_path.name
    assert recording.timestamps("cam0") == stamps == recording.timestamps("cam1")
    reasons = sorted(p.reason.split(" (")[0] for p in recording.problems)
    assert reasons == ["duplicate timestamp", "no timestamp in file name"]
    np.testing.assert_array_equal(recording.load(recording.frames["cam0"][0]), _image(0, np.uint16))
    np.testing.assert_array_equal(
        recording.load(recording.frames["cam1"][2]), _image(2, colour=True)
    )
    (tmp_path / "right" / "nostamp.png").unlink()
    for file in (tmp_path / "right").iterdir():
        file.unlink()
    (tmp_path / "right").rmdir()
    with pytest.raises(CaptureError, match=r"right: missing camera folder \(cam1\)"):
        open_recording(tmp_path)


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("1700000002_001058405.png", 1_700_000_002_001_058_405),  # ROS <s>_<ns>
        ("left-1700000002-000000007.png", 1_700_000_002_000_000_007),
        ("1700000002_7.png", 1_700_000_002_000_000_007),  # nanoseconds printed unpadded
        ("1700000002_58405.png", 1_700_000_002_000_058_405),
        ("1700000002.5.png", 1_700_000_002_500_000_000),
        ("left_000017_1403636579763555584.png", 1_403_636_579_763_555_584),
        ("frame_000017.png", 17),  # a frame index stays an index
        # a digit after the time (cam0) was read as the time: every frame at 0
        ("1700000000449938042_cam0.png", 1_700_000_000_449_938_042),
        ("1700000000449938042_1.png", 1_700_000_000_449_938_042),
        # seconds with a fraction, then more: read as nanoseconds, the seconds were lost
        ("1700000000.449938042_left.png", 1_700_000_000_449_938_042),
        ("1700000002_001058405_left.png", 1_700_000_002_001_058_405),
        ("v1.2_1403636579763555584.png", 1_403_636_579_763_555_584),  # not Unix seconds
        ("12.5.png", 12_500_000_000),  # seconds from the start, ending the name
        ("frame_12_34.png", 34),  # as long: the last
        # a date or a serial is no time: the frame number after it stays the number
        ("rec_20240501_000001.png", 1),
        ("cam0_SN12345678_000017.png", 17),
        ("12_001058405.png", 1_058_405),  # too few digits for Unix seconds
        ("nostamp.png", None),
        # microseconds with a fraction were read as seconds: 1.7e24 ns, past int64
        ("1700000000050164.0.png", 1_700_000_000_050_164),
        ("0000012.5.png", 12_500_000_000),  # zeros in front of seconds are no digits
        ("9999999999.5.png", None),  # 2286: past int64 nanoseconds (2262), no time
    ],
)
def test_timestamp_from_name(name: str, expected: int | None) -> None:
    assert timestamp_from_name(name) == expected


@pytest.mark.parametrize(
    ("unit", "digits", "scale", "suffix", "period_ms"),
    [
        ("milliseconds", 13, 10**6, "", 50),
        ("microseconds", 16, 10**3, "", 50),
        ("microseconds", 16, 10**3, ".0", 50),  # read as seconds: 1.7e24 ns, accepted
        ("microseconds", 16, 10**3, "", 100),  # 100 us read as ns: a 10,000 frames/s camera
    ],
)
def test_unix_milli_and_microsecond_names_are_refused_naming_the_unit(
    tmp_path: Path, unit: str, digits: int, scale: int, suffix: str, period_ms: int
) -> None:
    # read as nanoseconds they were "frame numbers" (or passed, at 10 frames/s or slower)
    stamps = [1_700_000_000_049_941_000 + i * period_ms * MS for i in range(4)]
    for i, t in enumerate(stamps):
        for side in ("left", "right"):
            write_image(tmp_path / side / f"{t // scale}{suffix}.png", _image(i))
    with pytest.raises(
        CaptureError,
        match=rf"^{tmp_path / 'left'}: these cam0 file names look like Unix times in {unit} "
        rf"\({digits} digits: .* 2023-11-14 .*\): name frames in nanoseconds or seconds\.fraction",
    ) as info:
        open_recording(tmp_path)
    assert "\n" not in str(info.value)


def test_a_clock_since_boot_in_nanoseconds_is_no_millisecond_time(tmp_path: Path) -> None:
    # 13 digits in ns: 1234 s after boot, at a camera's period, is read as nanoseconds
    stamps = [1_234_567_890_123 + i * 33 * MS for i in range(3)]
    for i, t in enumerate(stamps):
        for side in ("left", "right"):
            write_image(tmp_path / side / f"{t}.png", _image(i))
    write_image(tmp_path / "right" / "9999999999.5.png", _image(7))  # past int64 ns: named
    recording = open_recording(tmp_path)
    assert recording.timestamps("cam0") == stamps == recording.timestamps("cam1")
    [problem] = recording.problems
    assert "timestamp 9999999999500000000 ns in file name is past 2262" in problem.reason


def test_a_filestorage_without_an_image_size_takes_each_cameras_frame_size(
    tmp_path: Path,
) -> None:
    # cam1 at twice cam0's size: both cameras were given cam0's, and cam1's frames refused
    rec = tmp_path / "rec"
    for i in range(2):
        write_image(rec / "left" / f"{T0 + i * 50 * MS}.png", _image(i))
        write_image(rec / "right" / f"{T0 + i * 50 * MS}.png", np.zeros((24, 32), np.uint8))
    storage = cv2.FileStorage(str(tmp_path / "stereo.yml"), cv2.FILE_STORAGE_WRITE)
    for key, value in {
        "M1": np.array([[20.0, 0, 8], [0, 20, 6], [0, 0, 1]]), "D1": np.zeros((1, 5)),
        "M2": np.array([[40.0, 0, 16], [0, 40, 12], [0, 0, 1]]), "D2": np.zeros((1, 5)),
        "R": np.eye(3), "T": np.array([[-0.11], [0.0], [0.0]]),
    }.items():  # fmt: skip
        storage.write(key, value)
    storage.release()
    recording = open_recording(rec)
    rig, source = find_calibration(recording, RigFile("cam1"), (tmp_path / "stereo.yml",))
    assert source.startswith("OpenCV FileStorage")
    assert rig.cam0.resolution == (16, 12) and rig.cam1.resolution == (32, 24)


def test_seconds_nanoseconds_names_pair_within_their_second(tmp_path: Path) -> None:
    # read as nanoseconds alone, 1700000002_001058405 came before 1700000000_101770880
    stamps = [1_700_000_000_101_770_880, 1_700_000_001_001_000_000, 1_700_000_002_001_058_405]
    for i, t in enumerate(stamps):
        for side in ("left", "right"):
            name = f"{t // 10**9}_{t % 10**9:09d}.png"
            write_image(tmp_path / side / name, _image(i))
    recording = open_recording(tmp_path)
    assert recording.timestamps("cam0") == stamps == recording.timestamps("cam1")
    assert recording.problems == []


def _load_in_worker(frame: FrameRef) -> np.ndarray:
    return load_frame(pickle.loads(pickle.dumps(frame)))


def test_frame_refs_load_in_worker_processes(tmp_path: Path) -> None:
    _euroc(tmp_path)
    recording = open_recording(tmp_path)
    frames = recording.frames["cam0"]
    with multiprocessing.get_context("fork").Pool(1) as pool:
        images = pool.map(_load_in_worker, frames)
    for frame, image in zip(frames, images, strict=True):
        np.testing.assert_array_equal(image, recording.load(frame))


def test_resolve_obstructed(tmp_path: Path) -> None:
    _euroc(tmp_path / "rec")
    with pytest.raises(CaptureError, match=r"Add rig.yaml .* or pass --obstructed cam0\|cam1"):
        resolve_obstructed(tmp_path / "rec", None)
    assert resolve_obstructed(tmp_path / "rec", "cam0") == RigFile("cam0")
    with pytest.raises(CaptureError, match="--obstructed: expected cam0 or cam1, got 'left'"):
        resolve_obstructed(tmp_path / "rec", "left")
    write_rig_file(tmp_path / "rec" / "rig.yaml", RigFile("cam1", ("rain",), "camchain.yaml"))
    assert resolve_obstructed(tmp_path / "rec", None) == RigFile("cam1", ("rain",), "camchain.yaml")
    assert resolve_obstructed(tmp_path / "rec", "cam0").obstructed == "cam0"
    assert resolve_obstructed(tmp_path / "rec", "cam0").anomaly == ("rain",)
    # Beside a bag file (here any file): rig.yaml in the same folder.
    bag = tmp_path / "bags" / "run.bag"
    bag.parent.mkdir()
    bag.write_bytes(b"")
    write_rig_file(bag.parent / "rig.yaml", RigFile("cam0", ("dust",)))
    assert resolve_obstructed(bag, None).anomaly == ("dust",)
    (bag.parent / "rig.yaml").write_text("obstructed: cam2\n")
    with pytest.raises(ConfigError, match=r"rig.yaml: obstructed"):
        resolve_obstructed(bag, None)


def test_rig_yaml_may_leave_obstructed_to_the_option(tmp_path: Path) -> None:
    # --obstructed wins over rig.yaml, whose labels and calibration are kept: a rig.yaml
    # naming only those was refused ("obstructed: required key is missing") all the same
    _euroc(tmp_path / "rec")
    rig_yaml = tmp_path / "rec" / "rig.yaml"
    rig_yaml.write_text("anomaly: [rain]\ncalibration: camchain.yaml\n")
    assert resolve_obstructed(tmp_path / "rec", "cam1") == RigFile(
        "cam1", ("rain",), "camchain.yaml"
    )
    assert resolve_obstructed(tmp_path / "rec", "cam0").obstructed == "cam0"
    with pytest.raises(ConfigError, match=r"rig.yaml: obstructed: required key is missing"):
        resolve_obstructed(tmp_path / "rec", None)
    rig_yaml.write_text("")  # nothing in it: the option alone
    assert resolve_obstructed(tmp_path / "rec", "cam1") == RigFile("cam1")
    rig_yaml.write_text("obstructed: cam2\nanomaly: [rain]\n")  # a wrong value is still wrong
    with pytest.raises(ConfigError, match=r"rig.yaml: obstructed"):
        resolve_obstructed(tmp_path / "rec", "cam1")


def test_capture_ingest_takes_obstructed_from_the_option_when_rig_yaml_has_none(
    tmp_path: Path,
) -> None:
    from lenspair.cli import main
    from tests.capture.ingest_helpers import CROP, make_recording

    recording = make_recording(tmp_path / "rec", frames=2)
    (recording / "rig.yaml").write_text("anomaly: [rain]\n")
    args = ["capture-ingest", str(recording), "--out", str(tmp_path / "out"), "--size", CROP]
    assert main([*args, "--obstructed", "cam1"]) == 0
    report = json.loads((tmp_path / "out" / "rec" / "report.json").read_text())
    assert (report["obstructed"], report["anomaly"]) == ("cam1", ["rain"])


def test_empty_left_right_folders(tmp_path: Path) -> None:
    (tmp_path / "left").mkdir()
    (tmp_path / "right").mkdir()
    with pytest.raises(CaptureError, match="no cam0 frames could be listed"):
        open_recording(tmp_path)


def test_frame_numbers_after_a_date_are_read_as_frame_numbers(tmp_path: Path) -> None:
    # read as the date, every file of a camera had one time and the folder was refused
    for i in range(1, 4):
        for side in ("left", "right"):
            write_image(tmp_path / side / f"rec_20240501_{i:06d}.png", _image(i))
    recording = open_recording(tmp_path)
    assert recording.timestamps("cam0") == [1, 2, 3] == recording.timestamps("cam1")


@pytest.mark.parametrize("layout", ["folders", "euroc", "euroc with data.csv"])
def test_frames_that_are_not_read_are_named_not_passed_over(tmp_path: Path, layout: str) -> None:
    # a WebP, a raw file, a link to nothing or a folder named as a frame vanished from the
    # recording without a word: "kept 8 of 8", and nothing in report.json; a file beside a
    # frame that is read, named by its time, is no frame lost
    stamps = [T0 + i * 50 * MS for i in range(3)]
    if layout == "folders":
        for camera in ("left", "right"):
            for t in stamps:
                write_image(tmp_path / camera / f"{t}.png", _image(t % 97))
        folder = tmp_path / "right"
    else:
        for camera in ("cam0", "cam1"):
            _write_camera(tmp_path / "mav0" / camera, stamps)
            if layout == "euroc":
                (tmp_path / "mav0" / camera / "data.csv").unlink()
        folder = tmp_path / "mav0" / "cam1" / "data"
    late = [T0 + i * 50 * MS for i in range(3, 7)]
    (folder / f"{late[0]}.webp").write_bytes(b"RIFF")
    (folder / f"{late[1]}.DNG").write_bytes(b"II*\x00")
    (folder / f"{late[2]}.png").symlink_to(tmp_path / "gone.png")
    (folder / f"{late[3]}.png").mkdir()
    (folder / ".hidden.webp").write_bytes(b"RIFF")  # hidden files are not frames
    (folder / "notes.txt").write_text("not a frame")
    for t in stamps:  # a frame's companions (raw + PNG, a depth map): no frame is lost
        (folder / f"{t}.dng").write_bytes(b"II*\x00")
        (folder / f"{t}_depth.exr").write_bytes(b"v/1\x01")
        if layout == "euroc with data.csv":  # a readable one too, where data.csv tells
            write_image(folder / f"{t}_depth.png", _image(5))
    recording = open_recording(tmp_path)
    said = sorted((p.t_ns, p.reason, p.dropped) for p in recording.problems)
    if layout == "euroc with data.csv":  # data.csv says what the frames are
        assert said == []
        return
    assert said == [
        (late[0], ".webp images are not read: convert it to PNG or TIFF", True),
        (late[1], "a camera raw file: export it as PNG or TIFF", True),
        (late[2], f"a link to nothing ({tmp_path / 'gone.png'}); left out", True),
        (late[3], "a folder named as an image; left out", True),
    ]
    assert recording.timestamps("cam1") == stamps


@pytest.mark.parametrize("separator", ["_", "-", "."])
def test_readable_companions_named_by_a_frames_time_are_not_frames(
    tmp_path: Path, separator: str
) -> None:
    # a depth map or a thumbnail beside each frame, named by the frame's name and a word,
    # was a "duplicate timestamp" of its frame; "<t>-depth.png" sorts before "<t>.png", so
    # it became the frame and the camera image was dropped
    stamps = [T0 + i * 50 * MS for i in range(3)]
    frames = {}
    for camera in ("left", "right"):
        for t in stamps:
            frames[camera, t] = _image(t % 97 + len(camera))
            write_image(tmp_path / camera / f"{t}.png", frames[camera, t])
            write_image(tmp_path / camera / f"{t}{separator}depth.png", _image(5, np.uint16))
    write_image(tmp_path / "right" / f"{stamps[0]}.tif", _image(6))  # the same stem: a twin
    write_image(tmp_path / "right" / f"{stamps[1]}_1.png", _image(7))  # a second save: a twin
    recording = open_recording(tmp_path)
    assert recording.timestamps("cam0") == stamps == recording.timestamps("cam1")
    for camera, name in (("cam0", "left"), ("cam1", "right")):
        for frame in recording.frames[camera]:
            assert frame.source == tmp_path / name / f"{frame.t_ns}.png"
    said = [(p.t_ns, Path(p.source).name, p.reason, p.dropped) for p in recording.problems]
    first = sorted(f"{t}{separator}depth.png" for t in stamps)[0]
    companions = (
        f"3 files named as a frame of the same time and a word (the first: {first}): "
        "companions of those frames (depth maps, thumbnails), not frames"
    )
    kept = f"{tmp_path}/right"
    assert sorted(said, key=str) == sorted(
        [
            (None, "left", companions, False),
            (None, "right", companions, False),
            (
                stamps[0],
                f"{stamps[0]}.tif",
                f"duplicate timestamp (kept {kept}/{stamps[0]}.png)",
                True,
            ),
            (
                stamps[1],
                f"{stamps[1]}_1.png",
                f"duplicate timestamp (kept {kept}/{stamps[1]}.png)",
                True,
            ),
        ],
        key=str,
    )


def test_a_companion_named_by_a_word_that_starts_with_a_digit_is_no_frame(tmp_path: Path) -> None:
    # an 8-bit preview "<t>-8bit.png" beside a 16-bit frame sorted first and became the
    # frame, the camera's image a duplicate; "<t>-2.png" (a second save) stays a duplicate
    stamps = [T0 + i * 50 * MS for i in range(4)]
    for camera in ("left", "right"):
        for t in stamps:
            write_image(tmp_path / camera / f"{t}.png", _image(t % 89, np.uint16))
            write_image(tmp_path / camera / f"{t}-8bit.png", _image(t % 89))
    write_image(tmp_path / "left" / f"{stamps[0]}-2.png", _image(3, np.uint16))
    recording = open_recording(tmp_path)
    for camera, name in (("cam0", "left"), ("cam1", "right")):
        assert [f.source for f in recording.frames[camera]] == [
            tmp_path / name / f"{t}.png" for t in stamps
        ]
    dropped = [Path(p.source).name for p in recording.problems if p.dropped]
    assert dropped == [f"{stamps[0]}-2.png"]
