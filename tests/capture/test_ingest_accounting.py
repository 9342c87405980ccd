"""capture-ingest on input it must account for or refuse clearly: frames without a time,
a damaged registration cache, a calibration of another image size, bad options."""

import json
import logging
import shutil
from pathlib import Path

import pytest

from lenspair.capture.errors import CaptureError
from lenspair.capture.ingest import ingest_recording
from lenspair.capture.ingest_registration import REGISTRATION_FILE
from lenspair.capture.ingested import read_pairs, read_report
from lenspair.cli import main
from tests.capture.ingest_helpers import CROP, frame_files, make_recording, simulate
from tests.capture.test_ingest import _assert_counts_add_up
from tests.file_limits import run_with_file_limit

SIZE = (240, 160)


def _left_right(recording: Path) -> Path:
    """``recording`` (a EuRoC folder) as ``left/`` + ``right/`` folders of ``<t_ns>.png``."""
    for camera, folder in (("cam0", "left"), ("cam1", "right")):
        (recording / folder).mkdir()
        for path in frame_files(recording, camera):
            path.rename(recording / folder / path.name)
    shutil.rmtree(recording / "mav0")
    return recording


@pytest.mark.parametrize("layout", ["data.csv", "left/right"])
def test_an_obstructed_frame_without_a_time_is_named_and_counted(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], layout: str
) -> None:
    recording = make_recording(tmp_path / "rec", frames=5)
    if layout == "data.csv":  # a typo in one row: the frame cannot be timed
        csv1 = recording / "mav0" / "cam1" / "data.csv"
        lines = csv1.read_text().splitlines()
        lines[3] = "x" + lines[3]
        csv1.write_text("\n".join(lines) + "\n")
        listed = lines[3].split(",")[1]  # the image the bad row lists is named, not only the line
        where = f"{csv1}:4"
        reason = f"timestamp is not a non-negative integer (ns): {lines[3].split(',')[0]!r}; "
        reason += f"the row lists {listed!r}"
        frames, timed = 5, 4
    else:
        _left_right(recording)
        snapshot = recording / "right" / "snapshot.png"
        shutil.copy(next((recording / "right").iterdir()), snapshot)
        where, reason = str(snapshot), "no timestamp in file name"
        frames, timed = 6, 5
    out = tmp_path / "out"
    assert main(["capture-ingest", str(recording), "--out", str(out), "--size", CROP]) == 0
    # every frame is counted in the summary, and the one without a time is among the rejected
    summary = capsys.readouterr().out
    assert f"kept {timed} of {frames} cam1 frames" in summary
    assert "rejected 1: cam1 not listed: " in summary
    assert len(read_pairs(out / "rec" / "pairs.jsonl")) == timed  # one line per timed frame
    report = read_report(out / "rec" / "report.json")
    counts = report.counts
    assert counts["frames_cam1"] == frames and counts["kept"] + counts["rejected"] == frames
    assert counts["rejected_untimed"] == 1
    _assert_counts_add_up(counts)
    # named in report.json, with its file and reason, since pairs.jsonl cannot hold it
    (named,) = [p for p in report.recording_problems if "without a timestamp" in p]
    assert named.startswith("cam1 frame without a timestamp, in no line of pairs.jsonl: ")
    assert f"{where}: {reason}" in named
    assert counts["recording_problems"] == len(report.recording_problems)


def test_a_clean_frame_without_a_time_is_counted_but_not_rejected(tmp_path: Path) -> None:
    recording = make_recording(tmp_path / "rec", frames=4)
    csv0 = recording / "mav0" / "cam0" / "data.csv"
    lines = csv0.read_text().splitlines()
    csv0.write_text("\n".join([*lines[:2], "x" + lines[2], *lines[3:]]) + "\n")
    report = ingest_recording(recording, tmp_path / "out", size=SIZE)
    counts = report.counts
    assert counts["dropped_cam0"] == 1 and counts["rejected_untimed"] == 0
    assert counts["kept"] + counts["rejected"] == counts["frames_cam1"] == 4
    _assert_counts_add_up(counts)


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "1e303", "-1e13"])
def test_a_time_offset_that_is_not_a_finite_number_of_ms_is_an_option_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], value: str
) -> None:
    recording = make_recording(tmp_path / "rec", frames=2)
    argv = ["capture-ingest", str(recording), "--out", str(tmp_path / "out")]
    with pytest.raises(SystemExit) as stopped:
        main([*argv, f"--time-offset={value}"])
    assert stopped.value.code == 2
    (line,) = capsys.readouterr().err.strip().splitlines()  # no traceback
    assert line.startswith("lenspair capture-ingest: error: argument --time-offset: expected ")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "damage",
    [
        "[]",
        '"registration"',
        "null",
        "{bad",
        "no matrix",
        "matrix 2x2",
        "matrix text",
        "inliers text",
    ],
)
def test_a_registration_cache_of_another_shape_is_computed_again(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, damage: str
) -> None:
    recording = make_recording(tmp_path / "rec", frames=3)
    out = tmp_path / "out"
    ingest_recording(recording, out, size=SIZE)
    cache = out / "rec" / REGISTRATION_FILE
    good = cache.read_bytes()
    record = json.loads(good)  # the fingerprint stays: only the shape is wrong
    if damage == "no matrix":
        del record["matrix"]
    elif damage == "matrix 2x2":
        record["matrix"] = [[1.0, 0.0], [0.0, 1.0]]
    elif damage == "matrix text":
        record["matrix"] = [[str(value) for value in row] for row in record["matrix"]]
    elif damage == "inliers text":
        record["inliers"] = "many"
    edited = damage in ("no matrix", "matrix 2x2", "matrix text", "inliers text")
    cache.write_text(json.dumps(record) if edited else damage)
    with caplog.at_level(logging.WARNING):
        report = ingest_recording(recording, out, size=SIZE)
    assert report.counts["kept"] == 3
    said = [m for m in caplog.messages if REGISTRATION_FILE in m]
    assert len(said) == 1 and said[0].endswith("computing the registration again")
    assert cache.read_bytes() == good  # computed again from the same frames


def test_a_calibration_for_another_image_size_is_named_before_rectifying(
    tmp_path: Path,
) -> None:
    recording = simulate("rain", tmp_path / "rain", frames=2)
    camchain = recording / "camchain.yaml"
    assert camchain.read_text().count("resolution: [720, 540]") == 2
    other = tmp_path / "r1280.yaml"  # rectifying 720x540 frames with it fails at its edges
    other.write_text(camchain.read_text().replace("[720, 540]", "[1280, 720]"))
    first = frame_files(recording, "cam1")[0]
    with pytest.raises(
        CaptureError,
        match=rf"no usable frame pair to register: size mismatch: {first} is 720x540 px, "
        rf"the calibration says 1280x720 \(with Kalibr camchain {other}\)$",
    ):
        ingest_recording(recording, tmp_path / "out", calibration=(other,))
    assert not (tmp_path / "out" / "rain").exists()


def test_a_refused_write_exits_1_as_the_help_says(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recording = make_recording(tmp_path / "rec", frames=2)
    argv = ["capture-ingest", str(recording), "--out", str(tmp_path / "out"), "--size", CROP]
    failed = run_with_file_limit(argv, 300)  # as on a full disk
    assert failed.returncode == 1, failed.stderr
    with pytest.raises(SystemExit):
        main(["capture-ingest", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "1 when the file system refuses a write (read-only folder, full disk" in text
    assert "2 on an error in the recording, the calibration or the options" in text


def test_left_right_names_with_a_digit_after_the_time_keep_every_frame(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # <t_ns>_cam0.png read as t=0 (the digit of cam0): "kept 1 of 4", and exit 0
    recording = _left_right(make_recording(tmp_path / "rec", frames=4))
    for camera, folder in (("cam0", "left"), ("cam1", "right")):
        for path in sorted((recording / folder).iterdir()):
            path.rename(path.with_name(f"{path.stem}_{camera}.png"))
    out = tmp_path / "out"
    assert main(["capture-ingest", str(recording), "--out", str(out), "--size", CROP]) == 0
    assert "kept 4 of 4 cam1 frames" in capsys.readouterr().out
    report = read_report(out / "rec" / "report.json")
    assert report.counts["pairs"] == 4 and report.rejection_reasons == {}


def test_a_camera_whose_names_mostly_read_as_one_time_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # names whose time is not read (all "1" here) kept one frame, and called it a success
    recording = _left_right(make_recording(tmp_path / "rec", frames=4))
    for folder in ("left", "right"):
        for letter, path in zip("abcd", sorted((recording / folder).iterdir()), strict=True):
            path.rename(path.with_name(f"shot_{letter}_cam1.png"))
    out = tmp_path / "out"
    assert main(["capture-ingest", str(recording), "--out", str(out), "--size", CROP]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f"lenspair capture-ingest: error: {recording / 'left'}: 4 of 4 cam0 ")
    assert "read as one timestamp, t_ns=1 (e.g. shot_a_cam1.png)" in line
    assert not out.exists()
