"""capture-ingest from ROS bags: whole, truncated, and with chosen topics."""

import logging
import re
import shutil
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.typesys import Stores, get_typestore

from lenspair.capture import rosbag
from lenspair.capture.bag_frames import iter_bag_messages
from lenspair.capture.bagwrite import output_bag_path
from lenspair.capture.errors import CaptureError
from lenspair.capture.frames import detect_input
from lenspair.capture.image_messages import COMPRESSED_IMAGE as COMPRESSED
from lenspair.capture.image_messages import decode_compressed
from lenspair.capture.ingest import ingest_recording
from lenspair.capture.ingest_input import rectified_topics_note
from lenspair.capture.ingested import read_pairs, read_report
from lenspair.capture.rigfile import RigFile, write_rig_file
from lenspair.capture.rosbag import open_bag
from lenspair.cli import main
from lenspair.core.imageio import read_image
from lenspair.core.imagewrite import write_image
from lenspair.rectify.rig import write_kalibr
from tests.capture.ingest_helpers import CROP, frame_files, make_recording, rig
from tests.model.restore_helpers import bag_from_recording, write_bag

SIZE = (240, 160)


def _bag_from_euroc(tmp_path: Path, kind: str, frames: int = 4) -> Path:
    bag = bag_from_recording(tmp_path, kind, frames)
    write_kalibr(bag.parent / "camchain.yaml", rig())
    return bag


@pytest.mark.parametrize("kind", ["ros1", "db3"])
def test_bag_ingests_like_folders(tmp_path: Path, kind: str) -> None:
    bag = _bag_from_euroc(tmp_path, kind)
    report = ingest_recording(bag, tmp_path / "out", size=SIZE, workers=1)
    assert report.recording_id == "run" and report.counts["kept"] == 4
    assert report.calibration_source.endswith("camchain.yaml")


def test_topics_named_as_rectified_already_are_said_to_be_rectified_again(
    tmp_path: Path,
) -> None:
    # stereo_image_proc's image_rect through a raw camchain: warped twice, with no word
    bag = bag_from_recording(tmp_path, "db3", 3, topic="/{camera}/image_rect")
    write_kalibr(bag.parent / "camchain.yaml", rig())
    report = ingest_recording(bag, tmp_path / "out", size=SIZE, workers=1)
    (said,) = [line for line in report.recording_problems if "rectified already" in line]
    assert said.startswith("camera topic(s) /cam0/image_rect, /cam1/image_rect named as")
    raw = ingest_recording(_bag_from_euroc(tmp_path / "raw", "db3"), tmp_path / "o2", size=SIZE)
    assert not [line for line in raw.recording_problems if "rectified" in line]


@pytest.mark.parametrize(
    ("topic", "rectified"),
    [
        ("/stereo/left/image_rect", True),
        ("/stereo/left/image_rect_color/compressed", True),
        ("/camera/infra1/image_rect_raw", True),
        ("/rectified/left", True),
        ("/cam0/image_raw", False),
        ("/direct/cam0", False),
        ("/rectangle_detector/image", False),
    ],
)
def test_which_topic_names_say_rectified(topic: str, rectified: bool) -> None:
    assert (rectified_topics_note((topic, "/cam1/image_raw")) is not None) is rectified


def test_truncated_db3_keeps_what_was_read(tmp_path: Path) -> None:
    bag = _bag_from_euroc(tmp_path, "db3", frames=5)
    storage = next(bag.glob("*.db3"))
    data = storage.read_bytes()
    storage.write_bytes(data[: len(data) - 100])
    report = ingest_recording(bag, tmp_path / "out", size=SIZE)
    counts = report.counts
    assert counts["recording_problems"] == 1
    assert counts["frames_cam0"] + counts["frames_cam1"] < 10
    assert counts["kept"] >= 1
    assert counts["listed_cam1"] == counts["kept"] + counts["rejected"]
    assert len(read_pairs(tmp_path / "out" / "run" / "pairs.jsonl")) == counts["listed_cam1"]


def test_truncated_ros1_bag_ingests_the_frames_before_the_cut(tmp_path: Path) -> None:
    bag = _bag_from_euroc(tmp_path, "ros1")
    data = bag.read_bytes()
    bag.write_bytes(data[: len(data) * 3 // 4])
    report = ingest_recording(bag, tmp_path / "out", size=SIZE)
    counts = report.counts
    assert counts["recording_problems"] == 1
    assert counts["kept"] >= 1
    assert len(read_pairs(tmp_path / "out" / "run" / "pairs.jsonl")) == counts["listed_cam1"]


def test_bag_cut_before_any_frame_is_a_one_line_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = _bag_from_euroc(tmp_path, "ros1")
    bag.write_bytes(bag.read_bytes()[:300])
    code = main(["capture-ingest", str(bag), "--out", str(tmp_path / "out"), "--size", CROP])
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and line.startswith(f"lenspair capture-ingest: error: {bag}")
    assert "cannot open bag" in line and "nothing to keep" in line


def test_topics_must_name_two_topics(tmp_path: Path) -> None:
    bag = _bag_from_euroc(tmp_path, "ros1", frames=3)
    out = str(tmp_path / "out")
    args = ["capture-ingest", str(bag), "--out", out, "--size", CROP]
    assert main([*args, "--topics", "/cam0/image_raw,/cam1/image_raw"]) == 0
    with pytest.raises(SystemExit):
        main([*args, "--topics", "/cam0/image_raw"])


def test_topics_the_other_way_round_from_the_camchain(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Reversed topics rectified each camera with the other's calibration and made the
    # clean camera's frames the input, silently: refused when typed, and when chosen
    # by name the camchain's rostopic order wins.
    bag = _bag_from_euroc(tmp_path, "ros1", frames=3)
    cam0, cam1 = "/cam0/image_raw", "/cam1/image_raw"
    with pytest.raises(CaptureError, match=r"other way round from the calibration .*camchain"):
        ingest_recording(bag, tmp_path / "refused", size=SIZE, topics=(cam1, cam0))
    assert not (tmp_path / "refused").exists()
    swapped = tmp_path / "swapped"  # the same bag, its camchain naming the topics crossed
    swapped.mkdir()
    (swapped / bag.name).write_bytes(bag.read_bytes())
    write_rig_file(swapped / "rig.yaml", RigFile(obstructed="cam0", anomaly=("rain",)))
    write_kalibr(swapped / "camchain.yaml", replace(rig(), topics=(cam1, cam0)))
    typed = ingest_recording(swapped / bag.name, tmp_path / "typed", size=SIZE, topics=(cam1, cam0))
    opened = []
    monkeypatch.setattr(rosbag, "open_bag", lambda path: opened.append(path) or open_bag(path))
    chosen = ingest_recording(swapped / bag.name, tmp_path / "chosen", size=SIZE)
    assert opened == [swapped / bag.name]  # listed once: a bag of hours is not read twice
    assert (
        rosbag.read_bag(swapped / bag.name, (cam1, cam0))
        == rosbag.read_bag(swapped / bag.name, (cam0, cam1)).swapped()
    )
    assert typed.counts["kept"] == chosen.counts["kept"] == 3
    # a camchain that names no topics states nothing to contradict: typed, they stand
    camchain = bag.parent / "camchain.yaml"
    lines = camchain.read_text().splitlines(keepends=True)
    camchain.write_text("".join(line for line in lines if "rostopic" not in line))
    unstated = ingest_recording(bag, tmp_path / "unstated", size=SIZE, topics=(cam1, cam0))
    assert unstated.counts["frames_cam0"] == unstated.counts["frames_cam1"] == 3
    for name in ("input", "target"):
        for image in sorted((tmp_path / "typed" / "run" / name).iterdir()):
            other = tmp_path / "chosen" / "run" / name / image.name
            assert read_image(other).tobytes() == read_image(image).tobytes()


def test_topics_read_in_the_calibrations_order_are_said_and_in_report_json(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # The calibration's rostopic swapped which topic is cam0 (which physical camera
    # became the input) without a log line or a trace in report.json.
    bag = _bag_from_euroc(tmp_path, "ros1", frames=3)
    cam0, cam1 = "/cam0/image_raw", "/cam1/image_raw"
    with caplog.at_level(logging.WARNING):
        plain = ingest_recording(bag, tmp_path / "plain", size=SIZE)
    assert plain.topics == {"cam0": cam0, "cam1": cam1}
    assert not any("is read as cam0" in m for m in caplog.messages)
    write_kalibr(bag.parent / "camchain.yaml", replace(rig(), topics=(cam1, cam0)))
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        swapped = ingest_recording(bag, tmp_path / "swapped", size=SIZE)
    said = [m for m in caplog.messages if "is read as cam0" in m]
    assert said == [
        f"{bag}: topic {cam1} is read as cam0 and {cam0} as cam1, the other way round from the "
        f"order they were picked in, because the calibration's rostopic states it "
        f"({swapped.calibration_source})"
    ]
    assert swapped.topics == {"cam0": cam1, "cam1": cam0}
    assert read_report(tmp_path / "swapped" / "run" / "report.json").topics == swapped.topics


def test_bag_messages_sharing_a_stamp_each_get_a_line(tmp_path: Path) -> None:
    """Two obstructed-camera messages with one header stamp are two frames to account for."""
    euroc = make_recording(tmp_path / "euroc", frames=4)
    images = {
        camera: [(int(p.stem), read_image(p)) for p in frame_files(euroc, camera)]
        for camera in ("cam0", "cam1")
    }
    stamp, image = images["cam1"][1]
    images["cam1"].insert(2, (stamp, image))  # a second message, same stamp
    folder = tmp_path / "bags"
    folder.mkdir()
    write_rig_file(folder / "rig.yaml", RigFile(obstructed="cam1", anomaly=("rain",)))
    write_kalibr(folder / "camchain.yaml", rig())
    bag = write_bag(folder / "run", "ros1", images)
    report = ingest_recording(bag, tmp_path / "out", size=SIZE, workers=1)
    records = read_pairs(tmp_path / "out" / "run" / "pairs.jsonl")
    assert report.counts["frames_cam1"] == 5
    assert len(records) == 5  # every obstructed message, the repeated one rejected
    assert sum("duplicate timestamp" in (r.reason or "") for r in records) == 1


def _compressed_bag(
    tmp_path: Path, frames: int, empty: set[int], alpha: frozenset[int] = frozenset()
) -> Path:
    """A ROS 1 bag of PNG ``CompressedImage`` frames; cam1's frames in ``empty`` carry no data.

    A driver's failed frame: the message is there, its payload is not. cam1's
    frames in ``alpha`` are grey + alpha PNGs (half transparent).
    """
    euroc = make_recording(tmp_path / "euroc", frames=frames)
    store = get_typestore(Stores.ROS1_NOETIC)
    types = store.types
    folder = tmp_path / "bags"
    folder.mkdir()
    write_rig_file(folder / "rig.yaml", RigFile(obstructed="cam1", anomaly=("rain",)))
    write_kalibr(folder / "camchain.yaml", rig())
    messages = sorted(
        (int(path.stem), camera, index, path)
        for camera in ("cam0", "cam1")
        for index, path in enumerate(frame_files(euroc, camera))
    )
    bag = folder / "run.bag"
    with Writer1(bag) as writer:
        topics = {
            camera: writer.add_connection(f"/{camera}/compressed", COMPRESSED, typestore=store)
            for camera in ("cam0", "cam1")
        }
        for t_ns, camera, index, path in messages:
            ok, png = cv2.imencode(".png", read_image(path))
            assert ok
            if camera == "cam1" and index in alpha:
                png = np.frombuffer(_png(tmp_path, read_image(path), alpha=True), np.uint8)
            data = np.zeros(0, np.uint8) if camera == "cam1" and index in empty else png
            stamp = types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
            header = types["std_msgs/msg/Header"](seq=index, stamp=stamp, frame_id=camera)
            message = types[COMPRESSED](header=header, format="png", data=data.reshape(-1))
            raw = store.serialize_ros1(message, COMPRESSED)
            writer.write(topics[camera], t_ns + 1_000_000, raw)
    return bag


def _one_of_five_rejected(
    bag: Path, out: Path, capsys: pytest.CaptureFixture[str], runs: int = 1
) -> str:
    """Ingest ``bag`` (five frames) ``runs`` times; the reason of its one rejected cam1 frame."""
    args = ["capture-ingest", str(bag), "--out", str(out), "--size", CROP, "--workers", "1"]
    for _ in range(runs):
        assert main(args) == 0
        assert "kept 4 of 5 cam1 frames" in capsys.readouterr().out
    records = read_pairs(out / "run" / "pairs.jsonl")
    (rejected,) = [r for r in records if r.status == "rejected"]
    assert rejected.reason is not None
    assert rejected.reason.startswith(f"cannot read input frame: {bag} /cam1/compressed @ t_ns=")
    counts = read_report(out / "run" / "report.json").counts
    assert (counts["kept"], counts["rejected"]) == (4, 1)
    return rejected.reason


def test_an_empty_compressed_image_is_one_rejected_frame(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # cv2.imdecode asserts on an empty buffer: the ingest died with a cv2.error traceback,
    # and every rerun died at the same frame
    bag = _compressed_bag(tmp_path, frames=5, empty={3})
    reason = _one_of_five_rejected(bag, tmp_path / "out", capsys, runs=2)  # the rerun too
    assert reason.endswith("empty compressed image (format 'png', no data)")
    recording = rosbag.read_bag(bag)
    with pytest.raises(CaptureError, match=r"/cam1/compressed @ t_ns=\d+ .*: empty compressed"):
        recording.load(recording.frames["cam1"][3])
    # restore and detect read the same message through the shared decoder: that frame's error
    errors = [m.frame.error for m in iter_bag_messages(bag) if m.frame is not None]
    assert [e for e in errors if e is not None] == [
        f"{bag} /cam1/compressed @ log time {recording.frames['cam1'][3].log_time_ns}: "
        "empty compressed image (format 'png', no data)"
    ]


def test_undecodable_compressed_bytes_are_a_capture_error() -> None:
    with pytest.raises(CaptureError, match=r"^here: empty compressed image \(format 'jpeg'"):
        decode_compressed("jpeg", b"", "here")
    with pytest.raises(CaptureError, match=r"^here: cannot decode compressed image"):
        decode_compressed("jpeg", b"\xff\xd8\xff" + bytes(61), "here")


def _png(folder: Path, image: np.ndarray, alpha: bool = False) -> bytes:
    """The PNG lenspair writes of ``image``, with a half-transparent alpha channel if asked."""
    see_through = np.full(image.shape[:2], np.iinfo(image.dtype).max, image.dtype)
    see_through[:, : image.shape[1] // 2] = 0
    write_image(folder / "frame.png", image, alpha=see_through if alpha else None)
    return (folder / "frame.png").read_bytes()


def test_a_compressed_png_with_alpha_is_that_frames_error_naming_the_alpha(
    tmp_path: Path,
) -> None:
    # the BGRA PNG of a "bgra8; png compressed bgra8" message came back as RGB without a
    # word (restore wrote it back as three channels under the same format), and a grey +
    # alpha PNG as a two-channel array of alpha then grey
    grey = np.arange(48 * 64, dtype=np.uint8).reshape(48, 64)
    colour = np.dstack([grey, grey // 2, grey // 3])
    fmt = "bgra8; png compressed bgra8"
    for image in (colour, grey, colour.astype(np.uint16) * 257):
        with pytest.raises(CaptureError) as raised:
            decode_compressed(fmt, _png(tmp_path, image, alpha=True), "run.bag /cam0 @ 1")
        (line,) = str(raised.value).splitlines()
        # OpenCV decodes grey + alpha as two channels or, in some versions, as BGRA
        assert re.fullmatch(
            rf"run\.bag /cam0 @ 1: compressed image with an alpha channel \([24] channels, "
            rf"format {re.escape(repr(fmt))}\): not read, since its alpha would be lost",
            line,
        ), line
    # without alpha: grey stays grey, and colour comes back in RGB order
    for image in (grey, colour):
        decoded = decode_compressed("png", _png(tmp_path, image), "here")
        np.testing.assert_array_equal(decoded, image)


def test_a_compressed_frame_with_alpha_is_one_rejected_frame(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = _compressed_bag(tmp_path, frames=5, empty=set(), alpha=frozenset({2}))
    reason = _one_of_five_rejected(bag, tmp_path / "out", capsys)
    assert reason.endswith("channels, format 'png'): not read, since its alpha would be lost")
    assert "compressed image with an alpha channel (" in reason


def test_bag_files_are_named_by_their_whole_suffix(tmp_path: Path) -> None:
    # a killed recorder's run.bag.active was no bag to a folder's listing (its suffix is
    # .active), so restore and detect copied or passed it over without a word
    for name in ("run.bag", "run.BAG.active", "run.db3", "run.mcap"):
        assert rosbag.is_bag_name(Path(name)), name
    for name in ("run.active", "bag.txt", "run.bag.orig", "notes"):
        assert not rosbag.is_bag_name(Path(name)), name
    unknown = tmp_path / "run.txt"
    unknown.write_text("x")
    with pytest.raises(CaptureError, match=r"or a bag \(\.bag, \.bag\.active, \.db3, \.mcap\)"):
        detect_input(unknown)


def test_a_storage_file_rewritten_in_place_is_ingested_anew(tmp_path: Path) -> None:
    # the folder's size and time stay when its .db3 is overwritten (cp onto the same name):
    # the rerun kept the outputs, and the homography, of the images that were there before
    bag = _bag_from_euroc(tmp_path, "db3")
    out = tmp_path / "out"
    ingest_recording(bag, out, size=SIZE, workers=1)
    before = {p.name: read_image(p) for p in sorted((out / "run" / "input").iterdir())}
    darker = {
        camera: [(int(p.stem), read_image(p) // 2) for p in frame_files(tmp_path / "euroc", camera)]
        for camera in ("cam0", "cam1")
    }
    other = write_bag(tmp_path / "other" / "run", "db3", darker)  # the same stamps, other pixels
    storage = next(bag.glob("*.db3"))
    folder_time = bag.stat().st_mtime_ns
    shutil.copyfile(next(other.glob("*.db3")), storage)
    assert bag.stat().st_mtime_ns == folder_time  # nothing in the folder's own stat changed
    again = ingest_recording(bag, out, size=SIZE, workers=1)
    fresh = ingest_recording(bag, tmp_path / "fresh", size=SIZE, workers=1)
    assert again.counts["kept"] == fresh.counts["kept"] == 4
    for kind in ("input", "target"):
        for path in sorted((tmp_path / "fresh" / "run" / kind).iterdir()):
            np.testing.assert_array_equal(
                read_image(out / "run" / kind / path.name), read_image(path)
            )
    assert any(
        not np.array_equal(image, read_image(out / "run" / "input" / name))
        for name, image in before.items()
    )
    assert again.homography == fresh.homography


def test_a_killed_recorders_bag_active_is_read_as_a_cut_ros1_bag(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # rosbag record writes run.bag.active and renames it when it closes: one killed
    # leaves the .active file, unindexed; it was an "unknown recording layout"
    bag = _bag_from_euroc(tmp_path, "ros1", frames=5)
    active = bag.with_name("killed.bag.active")
    data = bag.read_bytes()
    active.write_bytes(data[: len(data) * 3 // 4])
    assert rosbag.is_bag(active) and detect_input(active) == "rosbag1"
    out = tmp_path / "out"
    assert main(["capture-ingest", str(active), "--out", str(out), "--size", CROP]) == 0
    report = read_report(out / "killed" / "report.json")
    assert report.counts["kept"] >= 1 and report.counts["recording_problems"] == 1
    (cut,) = report.recording_problems
    assert cut.startswith(f"{active}: reading stopped early ({active}: cut short")
    assert output_bag_path(active, out) == out / "killed.bag"  # restore's copy is closed


def test_a_cut_is_said_on_its_own_not_among_the_rejected_frames(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    # "rejected 1: recording not listed: reading stopped early" is no frame: the printed
    # rejections added up to more than the frames rejected
    bag = _bag_from_euroc(tmp_path, "ros1", frames=5)
    data = bag.read_bytes()
    bag.write_bytes(data[: len(data) * 3 // 4])
    out = tmp_path / "out"
    with caplog.at_level(logging.WARNING):
        assert main(["capture-ingest", str(bag), "--out", str(out), "--size", CROP]) == 0
    printed = capsys.readouterr().out
    report = read_report(out / "run" / "report.json")
    rejected = [int(n) for n in re.findall(r"^  rejected (\d+): ", printed, re.MULTILINE)]
    assert sum(rejected) == sum(report.rejection_reasons.values()) == report.counts["rejected"]
    # the summary names the cut once, on a line of its own
    cut_lines = [line for line in printed.splitlines() if "reading stopped early" in line]
    assert len(cut_lines) == 1 and cut_lines[0].startswith("  recording: ")
    assert not any("reading stopped early" in reason for reason in report.rejection_reasons)
    # the cut is its own line: in the log and in the report's recording problems
    said = [r.getMessage() for r in caplog.records if "reading stopped early" in r.getMessage()]
    assert len(said) == 1 and "\n" not in said[0] and said[0].startswith(f"{bag}: ")
    assert report.recording_problems == said


def test_the_calibration_s_rostopics_choose_among_topics_whose_names_tell_nothing(
    tmp_path: Path,
) -> None:
    """Four image topics named neither cam0/cam1 nor left/right: it asked for --topics though
    the camchain beside the bag names each camera's rostopic."""
    euroc = make_recording(tmp_path / "euroc", frames=3)
    images = {
        camera: [(int(p.stem), read_image(p)) for p in frame_files(euroc, source)]
        for camera, source in (("front_a", "cam0"), ("front_b", "cam1"), ("rear_a", "cam0"))
    }
    images["rear_b"] = images["front_b"]
    folder = tmp_path / "bags"
    folder.mkdir()
    write_rig_file(folder / "rig.yaml", RigFile(obstructed="cam1", anomaly=("rain",)))
    bag = write_bag(folder / "run", "ros1", images)
    with pytest.raises(CaptureError, match="cannot tell which of 4 image topics"):
        ingest_recording(bag, tmp_path / "unnamed", size=SIZE)  # nothing states them: asked
    absent = ("/left_x/image_raw", "/right_x/image_raw")  # a camchain of another rig
    write_kalibr(folder / "camchain.yaml", replace(rig(), topics=absent))
    with pytest.raises(CaptureError, match=r"calibration states /left_x/image_raw and /right_x"):
        ingest_recording(bag, tmp_path / "absent", size=SIZE)
    stated = ("/front_a/image_raw", "/front_b/image_raw")
    write_kalibr(folder / "camchain.yaml", replace(rig(), topics=stated))
    report = ingest_recording(bag, tmp_path / "out", size=SIZE)
    assert (report.topics["cam0"], report.topics["cam1"]) == stated
    assert report.counts["kept"] == 3
    # rig.yaml's calibration wins over a camchain beside the bag, for the topics as for the rest
    rear = ("/rear_a/image_raw", "/rear_b/image_raw")
    write_kalibr(folder / "rear.yaml", replace(rig(), topics=rear))
    write_rig_file(folder / "rig.yaml", RigFile("cam1", ("rain",), calibration="rear.yaml"))
    by_rig = ingest_recording(bag, tmp_path / "by_rig", size=SIZE)
    assert (by_rig.topics["cam0"], by_rig.topics["cam1"]) == rear
    assert by_rig.calibration_source.endswith("rear.yaml")
