"""capture-ingest from ROS bags: whole, truncated, and with chosen topics."""

from dataclasses import replace
from pathlib import Path

import pytest

from lenspair.capture import rosbag
from lenspair.capture.errors import CaptureError
from lenspair.capture.ingest import ingest_recording
from lenspair.capture.ingested import read_pairs
from lenspair.capture.rigfile import RigFile, write_rig_file
from lenspair.capture.rosbag import _open as open_bag
from lenspair.cli import main
from lenspair.core.imageio import read_image
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
    monkeypatch.setattr(rosbag, "_open", lambda path: opened.append(path) or open_bag(path))
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
