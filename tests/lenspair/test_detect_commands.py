"""The train-detector and detect commands, end to end on a tiny budget."""

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from lenspair.cli import main
from lenspair.core.imageio import read_image
from lenspair.core.imagewrite import write_image
from lenspair.model.detection.judge import judge
from lenspair.model.detection.train import load_detector
from tests.capture.ingest_helpers import make_recording
from tests.images import texture
from tests.model.restore_helpers import bag_from_recording, write_bag
from tests.model.train_fixtures import make_checkpoint


@pytest.fixture(scope="module")
def tiny_detector(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("detector")
    code = main(["train-detector", "--synthetic", "8", "--steps", "2", "--out", str(out)])
    assert code == 0
    return out / "detector.pt"


def test_train_detector_writes_its_run(tiny_detector: Path) -> None:
    run = tiny_detector.parent
    info = json.loads((run / "run.json").read_text())
    assert info["counts"]["train"] == 8
    assert info["training"]["steps"] == 2
    assert (run / "scores.md").is_file()


def test_detect_folder_writes_rows_sheet_and_records_bad_frames(
    tiny_detector: Path, tmp_path: Path
) -> None:
    frames = tmp_path / "frames"
    for index in range(3):
        image = (texture((120, 180), index) * 255).astype(np.uint8)
        write_image(frames / "sub" / f"{index}.png", image)
    (frames / "broken.png").write_bytes(b"\x89PNG not really")
    # restore refuses a frame under 8x8; detect gave it a confident verdict
    write_image(frames / "tiny.png", np.full((5, 5), 128, np.uint8))
    out = tmp_path / "out"
    assert main(["detect", str(tiny_detector), str(frames), "--out", str(out)]) == 0
    with (out / "detections.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    names = ["broken.png", "sub/0.png", "sub/1.png", "sub/2.png", "tiny.png"]
    assert [row["name"] for row in rows] == names
    assert rows[0]["error"] and rows[0]["probability"] == ""
    assert rows[4]["error"] == "5x5 pixels, smaller than the 8x8 minimum"
    assert rows[4]["probability"] == ""
    for row in rows[1:4]:
        assert 0.0 <= float(row["probability"]) <= 1.0 and not row["error"]
        assert row["kind"] in ("clean", "rain", "dust", "dirt")
    assert len(json.loads((out / "detections.json").read_text())) == 5
    assert read_image(out / "contact_sheet.png").ndim == 3


def test_a_frame_is_judged_alike_whatever_frames_share_its_batch(
    tiny_detector: Path, tmp_path: Path
) -> None:
    # a 12-bit frame in 16-bit words, then a true 16-bit one: the second raises the
    # depth, which rescaled the first in the batch they shared (judged 16x too dark)
    twelve = (texture((120, 180), 0) * 4095).astype(np.uint16)
    both, alone = tmp_path / "both", tmp_path / "alone"
    write_image(both / "a.png", twelve)
    write_image(both / "b.png", (texture((120, 180), 1) * 65535).astype(np.uint16))
    write_image(alone / "a.png", twelve)
    probability = {}
    for frames in (both, alone):
        out = tmp_path / f"out_{frames.name}"
        assert main(["detect", str(tiny_detector), str(frames), "--out", str(out)]) == 0
        with (out / "detections.csv").open() as handle:
            rows = {row["name"]: float(row["probability"]) for row in csv.DictReader(handle)}
        probability[frames.name] = rows["a.png"]
    assert probability["both"] == pytest.approx(probability["alone"], abs=1e-6)


def test_detect_bag_judges_both_cameras_frame_by_frame(tiny_detector: Path, tmp_path: Path) -> None:
    bag = bag_from_recording(tmp_path / "b", "mcap", frames=3)
    out = tmp_path / "out"
    args = ["detect", str(tiny_detector), str(bag), "--out", str(out), "--batch-size", "2"]
    assert main([*args, "--sheet-frames", "2"]) == 0
    with (out / "detections.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert [row["camera"] for row in rows] == ["cam0", "cam1"] * 3
    assert all(row["name"].startswith(f"/{row['camera']}/image_raw@") for row in rows)
    assert all(not row["error"] for row in rows)
    assert read_image(out / "contact_sheet.png").ndim == 3


@pytest.mark.parametrize("unset", [False, True], ids=["stamped", "stamps-never-set"])
def test_detect_times_bag_frames_by_header_else_by_log_time(
    tiny_detector: Path, tmp_path: Path, unset: bool
) -> None:
    # A driver that never sets header.stamp gave every row one t_ns (ingest used the log time).
    image = (texture((60, 80), 1) * 255).astype(np.uint8)
    times = [10**18 + k * 50_000_000 for k in range(3)]
    frames = {camera: [(t, image) for t in times] for camera in ("cam0", "cam1")}
    bag = write_bag(tmp_path / "b", "mcap", frames, stamp=0 if unset else None)
    out = tmp_path / "out"
    assert main(["detect", str(tiny_detector), str(bag), "--out", str(out)]) == 0
    with (out / "detections.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    expected = [t + 1_000_000 if unset else t for t in times for _ in ("cam0", "cam1")]
    assert [int(row["t_ns"]) for row in rows] == expected


def test_detect_gives_a_row_to_a_listed_frame_whose_file_is_missing(
    tiny_detector: Path, tmp_path: Path
) -> None:
    recording = make_recording(tmp_path / "rec", frames=3)
    missing = sorted((recording / "mav0" / "cam0" / "data").glob("*.png"))[1]
    extra = missing.with_name("extra.png")
    extra.write_bytes(missing.read_bytes())  # an image data.csv does not list
    missing.unlink()  # data.csv still lists it
    out = tmp_path / "out"
    assert main(["detect", str(tiny_detector), str(recording), "--out", str(out)]) == 0
    with (out / "detections.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 7  # every image of both cameras, judged or not
    lost, unlisted = [row for row in rows if row["error"]]
    assert lost["camera"] == "cam0" and lost["t_ns"] == missing.stem
    assert "missing" in lost["error"] and lost["probability"] == ""
    assert unlisted["name"] == "mav0/cam0/data/extra.png" and "not listed" in unlisted["error"]
    # named relative to the input, as the judged frames are (the left-out ones carried its path)
    assert not any(row["name"].startswith(str(recording)) for row in rows)
    assert len(json.loads((out / "detections.json").read_text())) == 7


def test_detect_judges_the_one_camera_of_a_mono_recording(
    tiny_detector: Path, tmp_path: Path
) -> None:
    recording = make_recording(tmp_path / "rec", frames=3)
    shutil.rmtree(recording / "mav0" / "cam1")  # a mono robot's EuRoC folder
    out = tmp_path / "out"
    assert main(["detect", str(tiny_detector), str(recording), "--out", str(out)]) == 0
    with (out / "detections.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert [row["camera"] for row in rows] == ["cam0"] * 3 and not any(r["error"] for r in rows)


def test_detect_bad_input_is_one_line(  # type: ignore[no-untyped-def]
    tiny_detector: Path, tmp_path: Path, capsys, monkeypatch
) -> None:
    monkeypatch.chdir(tmp_path)  # the default --out would land here
    assert main(["detect", str(tiny_detector), str(tmp_path / "nothing")]) == 2
    assert "no such file" in capsys.readouterr().err
    assert not (tmp_path / "detect_nothing").exists()  # refused before writing anything
    (tmp_path / "empty").mkdir()
    assert main(["detect", str(tiny_detector), str(tmp_path / "empty")]) == 2
    assert "no images" in capsys.readouterr().err
    (tmp_path / "notes.txt").write_text("x")
    assert main(["detect", str(tiny_detector), str(tmp_path / "notes.txt")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not an image" in err[0]
    assert main(["detect", str(tmp_path / "none.pt"), str(tmp_path)]) == 2
    assert main(["train-detector", "--out", str(tmp_path / "r")]) == 2


def test_train_detector_input_size_is_width_first(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from lenspair.model.detection import run as detection_run

    seen = []
    monkeypatch.setattr(
        detection_run, "run_training", lambda out, sources, spec, *a, **k: seen.append(spec) or {}
    )
    argv = ["train-detector", "--out", str(tmp_path / "d"), "--synthetic", "2"]
    assert main([*argv, "--input-size", "300x100"]) == 0
    assert seen[-1].input_size == (100, 300)  # (height, width), as every WxH option of lenspair


def test_detect_keeps_its_output_out_of_its_input(
    tiny_detector: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # a second run judged the first run's contact sheet as a frame
    folder = tmp_path / "frames"
    write_image(folder / "a.png", (texture((48, 64), seed=1) * 255).astype(np.uint8))
    assert main(["detect", str(tiny_detector), str(folder), "--out", str(folder / "d")]) == 2
    assert not (folder / "d").exists()
    monkeypatch.chdir(folder)  # the default lands beside the input, not in it
    for _ in range(2):
        assert main(["detect", str(tiny_detector), "."]) == 0
    rows = list(csv.DictReader((tmp_path / "detect_frames" / "detections.csv").open()))
    assert [row["name"] for row in rows] == ["a.png"]
    assert sorted(p.name for p in folder.iterdir()) == ["a.png"]
    # one image: its own folder is refused too (the sheet would sit among the frames); a
    # folder below it is not, since the default output is one when the image is here
    image = folder / "a.png"
    assert main(["detect", str(tiny_detector), str(image), "--out", str(folder)]) == 2
    assert sorted(p.name for p in folder.iterdir()) == ["a.png"]
    assert main(["detect", str(tiny_detector), "a.png"]) == 0  # here: detect_a below
    assert (folder / "detect_a" / "detections.csv").is_file()  # not a folder named like an image
    # a bag's folder is no image folder: its sheet beside it is fine
    bag = bag_from_recording(tmp_path / "b", "mcap", frames=2)
    assert main(["detect", str(tiny_detector), str(bag), "--out", str(bag.parent)]) == 0


def test_a_run_without_a_sheet_leaves_no_earlier_sheet(
    tiny_detector: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    frames = tmp_path / "frames"
    write_image(frames / "a.png", (texture((48, 64), seed=1) * 255).astype(np.uint8))
    out = tmp_path / "out"
    assert main(["detect", str(tiny_detector), str(frames), "--out", str(out)]) == 0
    assert (out / "contact_sheet.png").is_file()
    assert not any("replacing the detections" in m for m in caplog.messages)
    argv = ["detect", str(tiny_detector), str(frames), "--out", str(out), "--sheet-frames", "0"]
    assert main(argv) == 0
    assert any("replacing the detections of an earlier run" in m for m in caplog.messages)
    assert not (out / "contact_sheet.png").exists()  # it was the first run's, passing for this one


def test_train_detector_never_replaces_an_earlier_run(
    tiny_detector: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = tmp_path / "run"
    run.mkdir()
    kept = (run / "detector.pt").write_bytes(tiny_detector.read_bytes())
    capsys.readouterr()
    argv = ["train-detector", "--synthetic", "4", "--steps", "1", "--out", str(run)]
    assert main(argv) == 2  # it was replaced by the one-step detector, unsaid
    error = capsys.readouterr().err.strip()
    assert "already holds a detector run (detector.pt)" in error and "\n" not in error
    assert (run / "detector.pt").read_bytes() == tiny_detector.read_bytes() and kept
    assert sorted(p.name for p in run.iterdir()) == ["detector.pt"]


def test_train_detector_says_what_it_cannot_use_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    # each was a ValueError traceback
    clean = tmp_path / "clean"
    write_image(clean / "thin.png", (texture((15, 200), seed=1) * 255).astype(np.uint8))
    argv = ["train-detector", "--synthetic", "4", "--steps", "1", "--clean-images", str(clean)]
    assert main([*argv, "--out", str(tmp_path / "a")]) == 2
    assert "no clean image of at least 16x16" in capsys.readouterr().err
    write_image(clean / "wide.png", (texture((48, 64), seed=2) * 255).astype(np.uint8))
    caplog.clear()
    with caplog.at_level("WARNING"):
        assert main([*argv, "--out", str(tmp_path / "b")]) == 0
    said = [r.getMessage() for r in caplog.records if "left out of the synthetic" in r.getMessage()]
    assert len(said) == 1 and "thin.png" in said[0]
    # an unreadable image is one more left out, not the end of the run
    (clean / "empty.png").write_bytes(b"")
    caplog.clear()
    with caplog.at_level("WARNING"):
        assert main([*argv, "--out", str(tmp_path / "c")]) == 0
    said = [r.getMessage() for r in caplog.records if "left out of the synthetic" in r.getMessage()]
    assert len(said) == 2 and any("empty.png: empty file" in line for line in said)
    # a refused run leaves no empty --out behind
    assert main(["train-detector", "--steps", "1", "--out", str(tmp_path / "none")]) == 2
    assert not (tmp_path / "none").exists()


def test_train_detector_run_json_holds_plain_values(tiny_detector: Path) -> None:
    sources = json.loads((tiny_detector.parent / "run.json").read_text())["sources"]
    # were "()", "None" and "8": the reprs of the values
    assert sources["datasets"] == [] and sources["clean_folder"] is None
    assert sources["synthetic"] == 8


def test_detect_with_nothing_judged_says_so_cleanly(
    tiny_detector: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    fake = tmp_path / "notimage.png"
    fake.write_bytes(b"hello")
    # exit 2: no frame judged is no run to take for done (the summary is still said)
    assert main(["detect", str(tiny_detector), str(fake), "--out", str(tmp_path / "d")]) == 2
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert line.startswith("0 frames judged (1 not") and "; ;" not in line  # it printed "; ;"
    with pytest.raises(ValueError, match="an empty image"):
        judge(load_detector(tiny_detector), [np.zeros((0, 0), np.uint8)])  # a cv2.error


@pytest.mark.parametrize("command", ["detect", "restore"])
def test_a_bag_whose_camera_topics_hold_no_message_is_refused(
    command: str, tiny_detector: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # a recording stopped before the cameras started: "0 frames", exit 0, outputs written
    bag = write_bag(tmp_path / "run", "ros1", {"cam0": [], "cam1": []})
    model = tiny_detector if command == "detect" else make_checkpoint(tmp_path / "g.pt")
    out = tmp_path / "out"
    assert main([command, str(model), str(bag), "--out", str(out)]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.endswith(f"{bag}: no image messages on /cam0/image_raw, /cam1/image_raw: "
                         f"nothing to {'judge' if command == 'detect' else 'restore'}")  # fmt: skip
    assert not out.exists()


def test_detect_checks_its_default_out_and_a_read_only_out_before_judging(
    tiny_detector: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    from lenspair.core import fsutil
    from lenspair.model.detection import report

    write_image(tmp_path / "a.png", (texture((48, 64), seed=1) * 255).astype(np.uint8))
    monkeypatch.chdir(tmp_path)
    (tmp_path / "detect_a").write_text("a file where the default folder goes")
    assert main(["detect", str(tiny_detector), "a.png"]) == 2
    assert "the default --out 'detect_a' is a file; give a folder" in capsys.readouterr().err
    judged: list[Path] = []
    monkeypatch.setattr(report, "detect_frames", lambda *a, **k: judged.append(a[2]) or [])

    def read_only(*args: object, **kwargs: object) -> None:  # what a folder of another user gives
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(fsutil.tempfile, "mkstemp", read_only)
    assert main(["detect", str(tiny_detector), "a.png", "--out", "ro"]) == 1
    assert "ro/detections.csv: Permission denied" in capsys.readouterr().err
    assert judged == []  # refused before a frame was judged


def test_a_detect_output_inside_a_folder_is_left_out_of_it_and_said(
    tiny_detector: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # `detect a.png` beside the frame wrote detect_a/ there: a later detect of the folder
    # judged its contact sheet as a frame (restore would have restored it)
    folder = tmp_path / "frames"
    for seed, name in ((1, "a.png"), (2, "b.png")):
        write_image(folder / name, (texture((48, 64), seed=seed) * 255).astype(np.uint8))
    monkeypatch.chdir(folder)
    assert main(["detect", str(tiny_detector), "a.png"]) == 0
    assert (folder / "detect_a" / "contact_sheet.png").is_file()
    out = tmp_path / "whole"
    assert main(["detect", str(tiny_detector), str(folder), "--out", str(out)]) == 0
    rows = list(csv.DictReader((out / "detections.csv").open()))
    assert sorted(row["name"] for row in rows) == ["a.png", "b.png"]
