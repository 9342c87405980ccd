"""capture-ingest on small hand-made recordings: outputs, bookkeeping, bad input."""

import contextlib
import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from lenspair.capture.errors import CaptureError
from lenspair.capture.ingest import ingest_recording
from lenspair.capture.ingest_report import set_report_aside
from lenspair.capture.ingested import IngestReport, PairRecord, read_pairs, read_report
from lenspair.capture.journal import remove_stale_outputs
from lenspair.cli import main
from lenspair.core.bitdepth import narrow, significant_bits, widen
from lenspair.core.imageio import read_image
from lenspair.core.imagewrite import write_image
from lenspair.rectify.errors import CropError, RectifyError
from lenspair.rectify.registration import EstimationParams, VerifyParams
from tests.capture.ingest_helpers import CROP, DISPARITY, frame_files, make_recording

SIZE = (240, 160)


def _ingest(
    recording: Path, out: Path, **kwargs: Any
) -> tuple[Path, list[PairRecord], IngestReport]:
    report = ingest_recording(recording, out, size=SIZE, **kwargs)
    out_dir = out / report.recording_id
    return out_dir, read_pairs(out_dir / "pairs.jsonl"), report


def _assert_counts_add_up(counts: dict[str, int], obstructed: str = "cam1") -> None:
    clean = "cam0" if obstructed == "cam1" else "cam1"
    for camera in ("cam0", "cam1"):
        assert (
            counts[f"frames_{camera}"] == counts[f"listed_{camera}"] + counts[f"dropped_{camera}"]
        )
        assert counts[f"listed_{camera}"] == counts["pairs"] + counts[f"unpaired_{camera}"]
    unlisted = counts["rejected_unlisted"]  # dropped obstructed frames with their own line
    untimed = counts["rejected_untimed"]  # and those without a time: named in report.json
    assert counts[f"dropped_{obstructed}"] == unlisted + untimed
    assert counts[f"frames_{obstructed}"] == counts["kept"] + counts["rejected"]
    assert (
        counts["rejected"]
        == counts["rejected_paired"] + counts[f"unpaired_{obstructed}"] + unlisted + untimed
    )
    assert counts[f"listed_{clean}"] >= counts["pairs"]


def test_ingest_writes_the_contract(tmp_path: Path) -> None:
    recording = make_recording(tmp_path / "rec")
    out_dir, records, _ = _ingest(recording, tmp_path / "out")
    assert [r.status for r in records] == ["kept"] * 4
    assert [r.t_ns for r in records] == [int(p.stem) for p in frame_files(recording, "cam1")]
    for record in records:
        image_in = read_image(out_dir / record.files["input"])
        image_target = read_image(out_dir / record.files["target"])
        assert image_in.shape == image_target.shape == (160, 240) and image_in.dtype == np.uint8
        assert record.t_clean_ns is not None and record.inliers and record.inliers > 50
        assert record.residual_px is not None and record.residual_px < 0.1
        assert record.sharpness and record.saturated is not None and record.black is not None
        assert set(record.sha256) == set(record.files)
        # registered: the target matches the input outside the drops, exposure aside
        difference = np.abs(image_in.astype(float) - image_target.astype(float) / 0.85)
        assert np.median(difference) < 3
    saved = read_report(out_dir / "report.json")
    assert saved.obstructed == "cam1" and saved.anomaly == ("rain",)
    assert saved.calibration_source.endswith("camchain.yaml")
    assert saved.crop[2:] == SIZE
    assert saved.homography[0][2] == pytest.approx(-DISPARITY, abs=0.05)  # cam0 -> cam1 shift
    assert saved.counts["kept"] == 4 and saved.rejection_reasons == {}
    assert set(saved.timings_s) >= {"homography", "frames", "total"}
    assert (out_dir / "qa.png").is_file() and (out_dir / "registration.json").is_file()
    _assert_counts_add_up(saved.counts)


@pytest.mark.parametrize(("dtype", "colour"), [(np.uint16, False), (np.uint8, True)])
def test_bit_depth_and_channels_are_kept(tmp_path: Path, dtype: type, colour: bool) -> None:
    recording = make_recording(tmp_path / "rec", frames=3, dtype=dtype, colour=colour)
    out_dir, records, _ = _ingest(recording, tmp_path / "out")
    assert all(r.status == "kept" for r in records)
    for kind in ("input", "target"):
        image = read_image(out_dir / records[0].files[kind])
        assert image.dtype == dtype and image.shape == ((160, 240, 3) if colour else (160, 240))
    if dtype == np.uint16:
        assert image.max() > 255


def test_bad_frames_are_rejected_and_the_rest_processes(tmp_path: Path) -> None:
    recording = make_recording(tmp_path / "rec", frames=6)
    cam1 = frame_files(recording, "cam1")
    cam0 = frame_files(recording, "cam0")
    cam1[1].write_bytes(b"this is not a png")  # corrupt
    cam0[2].write_bytes(cam0[2].read_bytes()[:300])  # truncated (clean side)
    write_image(cam1[3], np.zeros((100, 120), np.uint8))  # wrong size
    out_dir, records, report = _ingest(recording, tmp_path / "out")
    status = {r.t_ns: r for r in records}
    bad_input = status[int(cam1[1].stem)]
    assert bad_input.status == "rejected"
    assert bad_input.reason is not None and bad_input.reason.startswith("cannot read input frame: ")
    assert str(cam1[1]) in bad_input.reason
    truncated = status[int(cam1[2].stem)]
    assert truncated.reason is not None and str(cam0[2]) in truncated.reason
    assert truncated.reason.startswith("cannot read clean frame: ")
    size = status[int(cam1[3].stem)].reason
    assert size == (f"size mismatch: {cam1[3]} is 120x100 px, the calibration says 320x240")
    assert [r.status for r in records].count("kept") == 3
    assert not (out_dir / "input" / f"{cam1[1].stem}.png").exists()
    assert report.rejection_reasons == {
        "cannot read clean frame": 1,
        "cannot read input frame": 1,
        "size mismatch": 1,
    }
    _assert_counts_add_up(report.counts)


def test_unpaired_duplicate_and_backward_frames_are_accounted_for(tmp_path: Path) -> None:
    recording = make_recording(tmp_path / "rec", frames=6)
    csv1 = recording / "mav0" / "cam1" / "data.csv"
    lines = csv1.read_text().splitlines()
    # cam1: a duplicate row and two rows out of order; cam0: one frame missing
    csv1.write_text(
        "\n".join([lines[0], lines[1], lines[3], lines[2], lines[3], *lines[4:]]) + "\n"
    )
    csv0 = recording / "mav0" / "cam0" / "data.csv"
    rows0 = csv0.read_text().splitlines()
    csv0.write_text("\n".join(rows0[:5] + rows0[6:]) + "\n")  # drop cam0's 5th frame
    _, records, report = _ingest(recording, tmp_path / "out")
    counts = report.counts
    _assert_counts_add_up(counts)
    # the repeated row is the same file at the same time: one frame, counted once (it
    # was a second frame, dropped: 7 frames of 6 files, and rejections that did not
    # add up to the summary's)
    assert counts["frames_cam1"] == 6 and counts["dropped_cam1"] == 0
    assert counts["listed_cam0"] == 5 and counts["unpaired_cam1"] == 1
    assert len(records) == 6  # one line per listed obstructed frame
    unpaired = [r for r in records if r.t_clean_ns is None]
    assert len(unpaired) == 1 and unpaired[0].reason == "no cam0 frame within 25.0 ms"
    of_cam1 = {k: n for k, n in report.rejection_reasons.items() if not k.startswith("cam0")}
    assert of_cam1 == {"no cam0 frame within 25.0 ms": counts["rejected"]}
    warned = [r for r in records if r.reason and "timestamp goes back" in r.reason]
    assert len(warned) == 1 and warned[0].status == "kept"
    twice = [r for r in records if r.reason and "listed twice" in r.reason]
    assert [r.t_ns for r in twice] == [int(lines[3].split(",")[0])] and twice[0].status == "kept"
    # every camera problem is in the report, also the clean camera's (the log says 10)
    said = report.camera_problems
    assert counts["camera_problems"] == len(said) == 3
    assert sum("cam0" in p and "image not listed in data.csv" in p for p in said) == 1, said
    assert sum("timestamp goes back" in p for p in said) == 1


def test_cameras_whose_clocks_disagree_are_said_in_the_log_and_report(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    recording = make_recording(tmp_path / "rec", frames=6)
    csv1 = recording / "mav0" / "cam1" / "data.csv"
    rows = csv1.read_text().splitlines()
    period = int(rows[2].split(",")[0]) - int(rows[1].split(",")[0])
    shifted = [f"{int(t) + period * 3 // 5},{f}" for t, f in (r.split(",") for r in rows[1:])]
    csv1.write_text("\n".join([rows[0], *shifted]) + "\n")
    _, _, report = _ingest(recording, tmp_path / "out")
    (said,) = [p for p in report.recording_problems if "clocks may differ" in p]
    assert said.startswith("cam1's frames are -")  # paired with the frame before
    assert report.counts["recording_problems"] == len(report.recording_problems)
    assert any("clocks may differ" in r.getMessage() for r in caplog.records)
    _, _, synchronised = _ingest(make_recording(tmp_path / "sync", frames=6), tmp_path / "o2")
    assert not any("clocks" in p for p in synchronised.recording_problems)
    # given the offset, each frame pairs with its true partner, recorded stamps kept
    offset = period * 3 // 5
    argv = ["capture-ingest", str(recording), "--out", str(tmp_path / "o3"), "--size", "240x160"]
    assert main([*argv, "--time-offset", str(offset / 1e6)]) == 0
    report = read_report(tmp_path / "o3" / "rec" / "report.json")
    assert report.time_offset_ns == offset and report.recording_problems == []
    records = read_pairs(tmp_path / "o3" / "rec" / "pairs.jsonl")
    kept = [r for r in records if r.t_clean_ns is not None]
    assert len(kept) == 6 and all(abs(r.t_ns - r.t_clean_ns - offset) < period // 4 for r in kept)


def test_one_stamp_far_in_the_future_is_not_blamed_on_every_later_frame(tmp_path: Path) -> None:
    from lenspair.capture.recording_types import FrameProblem, FrameRef, order_frames

    stamps = [100, 200, 10**19, 300, 400, 500]  # a garbled data.csv row in the middle
    frames = [FrameRef("cam1", t, tmp_path / f"{k}.png") for k, t in enumerate(stamps)]
    problems: list[FrameProblem] = []
    ordered = order_frames("cam1", frames, problems)
    assert [f.t_ns for f in ordered] == sorted(stamps)
    # one warning, on the frame after the odd one, naming it (each later frame had one)
    assert [(p.t_ns, p.dropped) for p in problems] == [(300, False)]
    assert f"after t_ns={10**19}" in problems[0].reason


def test_an_image_data_csv_does_not_list_is_named_in_pairs_jsonl(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recording = make_recording(tmp_path / "rec", frames=4)
    data = recording / "mav0" / "cam1" / "data"
    last = frame_files(recording, "cam1")[-1]
    extra = data / f"{int(last.stem) + 10**6}.png"  # between frames, on no row of data.csv
    extra.write_bytes(last.read_bytes())
    out = tmp_path / "out"
    assert main(["capture-ingest", str(recording), "--out", str(out), "--size", "240x160"]) == 0
    records = read_pairs(out / "rec" / "pairs.jsonl")
    (unlisted,) = [r for r in records if r.reason and extra.name in r.reason]
    assert unlisted.status == "rejected" and unlisted.t_ns == int(extra.stem)
    assert unlisted.reason.startswith("image not listed in")
    summary = capsys.readouterr().out
    assert "kept 4 of 5 cam1 frames" in summary and "rejected 1: image not listed" in summary
    report = read_report(out / "rec" / "report.json")
    _assert_counts_add_up(report.counts)
    # counted under a name that is the same on every machine (it held the csv's path)
    assert report.rejection_reasons == {"image not listed in data.csv": 1}


def test_a_second_file_with_a_repeated_timestamp_gets_its_own_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recording = make_recording(tmp_path / "rec", frames=5)
    csv1 = recording / "mav0" / "cam1" / "data.csv"
    lines = csv1.read_text().splitlines()
    t_ns, name = lines[3].split(",")
    copy = recording / "mav0" / "cam1" / "data" / "second.png"
    copy.write_bytes((recording / "mav0" / "cam1" / "data" / name.strip()).read_bytes())
    csv1.write_text("\n".join([*lines, f"{t_ns},second.png"]) + "\n")
    out = tmp_path / "out"
    assert main(["capture-ingest", str(recording), "--out", str(out), "--size", "240x160"]) == 0
    records = read_pairs(out / "rec" / "pairs.jsonl")
    assert len(records) == 6  # one line per obstructed file: 5 + the second one
    second = [r for r in records if r.reason and "second.png" in r.reason]
    assert len(second) == 1 and second[0].status == "rejected"
    assert second[0].reason.startswith("duplicate timestamp")
    summary = capsys.readouterr().out
    assert "kept 5 of 6 cam1 frames" in summary
    assert "rejected 1: duplicate timestamp" in summary
    _assert_counts_add_up(read_report(out / "rec" / "report.json").counts)


def test_all_frames_of_the_wrong_size_is_a_clear_error(tmp_path: Path) -> None:
    recording = make_recording(tmp_path / "rec", frames=2)
    for path in frame_files(recording, "cam0") + frame_files(recording, "cam1"):
        write_image(path, np.zeros((200, 300), np.uint8))
    first = frame_files(recording, "cam1")[0]
    with pytest.raises(
        CaptureError,
        match=rf"no usable frame pair to register: size mismatch: {first} is 300x200 px, "
        r"the calibration says 320x240 \(with Kalibr camchain \S+camchain\.yaml\)$",
    ):
        _ingest(recording, tmp_path / "out")
    # nothing was paired: no empty OUT/rec left to stop `dataset-build OUT/*`
    assert not (tmp_path / "out" / "rec").exists()


def test_missing_camera_empty_recording_and_no_calibration(tmp_path: Path) -> None:
    recording = make_recording(tmp_path / "a", frames=2)
    for path in frame_files(recording, "cam0"):
        path.unlink()
    (recording / "mav0" / "cam0" / "data.csv").write_text("#timestamp [ns],filename\n")
    with pytest.raises(CaptureError, match="no cam0 frames could be listed"):
        _ingest(recording, tmp_path / "out")
    bare = make_recording(tmp_path / "b", frames=2)
    import shutil

    shutil.rmtree(bare / "mav0" / "cam1")
    with pytest.raises(CaptureError, match=r"cam1: missing camera folder \(cam1\)"):
        _ingest(bare, tmp_path / "out")
    uncalibrated = make_recording(tmp_path / "c", frames=2, camchain=False)
    (uncalibrated / "rig.yaml").write_text("obstructed: cam1\n")
    with pytest.raises(CaptureError, match=r"c: no calibration: pass --calib FILE"):
        _ingest(uncalibrated, tmp_path / "out")


def test_an_opencv_calibration_without_an_image_size_takes_the_frames(tmp_path: Path) -> None:
    """OpenCV's stereo_calib sample writes M1 D1 M2 D2 and R T, but no image size."""
    import cv2

    from lenspair.rectify.rig import read_kalibr

    recording = make_recording(tmp_path / "rec", frames=3)
    rig = read_kalibr(recording / "camchain.yaml")
    files = []
    for name, values in (
        ("intrinsics.yml", {"M1": rig.cam0.K, "D1": rig.cam0.dist_coeffs,
                            "M2": rig.cam1.K, "D2": rig.cam1.dist_coeffs}),
        ("extrinsics.yml", {"R": rig.R, "T": rig.t.reshape(3, 1)}),
    ):  # fmt: skip
        storage = cv2.FileStorage(str(tmp_path / name), cv2.FILE_STORAGE_WRITE)
        for key, value in values.items():
            storage.write(key, value)
        storage.release()
        files.append(tmp_path / name)
    assert rig.cam0.distortion_model == "radtan"  # what the sample's files hold
    _, records, report = _ingest(recording, tmp_path / "out", calibration=tuple(files))
    assert report.calibration_source.startswith("OpenCV FileStorage")
    assert sum(r.status == "kept" for r in records) == 3


def test_nan_in_calibration_names_the_file(tmp_path: Path) -> None:
    recording = make_recording(tmp_path / "rec", frames=2)
    camchain = recording / "camchain.yaml"
    camchain.write_text(camchain.read_text().replace("300.0", ".nan", 1))
    with pytest.raises(
        RectifyError, match=rf"{camchain}: cam0\.intrinsics: camera parameters must be finite"
    ):
        _ingest(recording, tmp_path / "out")


def test_crop_too_large_says_by_how_much(tmp_path: Path) -> None:
    recording = make_recording(tmp_path / "rec", frames=2)
    calibration = f"Kalibr camchain {recording / 'camchain.yaml'}"
    with pytest.raises(CropError, match=r"need 330x160: 1[0-9] px too narrow") as caught:
        ingest_recording(recording, tmp_path / "out", size=(330, 160))
    assert str(caught.value).endswith(f"(with {calibration})")
    assert not (tmp_path / "out" / "rec").exists()  # no empty folder to trip dataset-build
    with pytest.raises(RectifyError, match=r"^\S*rec: ") as caught:  # named, with the calibration
        ingest_recording(
            recording,
            tmp_path / "out",
            size=(240, 160),
            estimation=EstimationParams(min_inliers=10**6),
        )
    assert str(caught.value).endswith(f"(with {calibration})")
    assert str(caught.value).count(str(recording)) == 2  # once as the recording, once in its path
    assert not (tmp_path / "out" / "rec").exists()
    # a rerun that fails says the folder still holds the earlier run's pairs (dataset-build
    # went on with them, unsaid)
    ingest_recording(recording, tmp_path / "out", size=(240, 160))
    with pytest.raises(CropError) as caught:
        ingest_recording(recording, tmp_path / "out", size=(330, 160))
    assert str(caught.value).endswith("still holds an earlier run's pairs, left as they were")


def test_blank_frames_do_not_sway_the_side_check(tmp_path: Path) -> None:
    recording = make_recording(tmp_path / "rec", frames=8, drops=60)
    for path in frame_files(recording, "cam0")[:6]:  # the clean camera: lens cap, exposure fault
        write_image(path, np.zeros_like(read_image(path)))
    _, _, report = _ingest(recording, tmp_path / "out")
    side = report.side_check
    # a black frame has less detail than any other: counted, these pairs said cam0 (clean)
    # was the obstructed camera
    assert side["blank_pairs_left_out"] == 6 and side["num_frames"] == 2
    assert side["inferred"] == "cam1" and not side["mismatch"]


def test_side_mismatch_is_flagged(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    recording = make_recording(tmp_path / "rec", frames=3, drops=60)
    with caplog.at_level(logging.WARNING):
        _, _, report = _ingest(recording, tmp_path / "out", obstructed="cam0")
    side = report.side_check
    assert side["declared"] == "cam0" and side["inferred"] == "cam1" and side["mismatch"]
    assert any("fine detail is lower on cam1, but cam0 is declared" in m for m in caplog.messages)


def test_cli_success_and_one_line_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recording = make_recording(tmp_path / "rec", frames=3)
    out = tmp_path / "out"
    assert main(["capture-ingest", str(recording), "--out", str(out), "--size", CROP]) == 0
    assert "rec: kept 3 of 3 cam1 frames" in capsys.readouterr().out
    for path in frame_files(recording, "cam1"):
        path.write_bytes(b"garbage")
    code = main(["capture-ingest", str(recording), "--out", str(out), "--size", CROP])
    error = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(error) == 1
    assert error[0].startswith("lenspair capture-ingest: error: ")
    assert "no usable frame pair to register: cannot read input frame: " in error[0]
    with pytest.raises(SystemExit):
        main(["capture-ingest", str(recording), "--out", str(out), "--size", "big"])


def test_nothing_usable_fails_after_writing_the_records(tmp_path: Path) -> None:
    recording = make_recording(tmp_path / "rec", frames=3)
    out = tmp_path / "out"
    _ingest(recording, out)
    strict = VerifyParams(max_photometric_residual=0.0)  # no pair can pass
    with pytest.raises(CaptureError, match=r"no usable pairs: all 3 cam1 frames rejected"):
        _ingest(recording, out, verify=strict)
    records = read_pairs(out / "rec" / "pairs.jsonl")
    assert [r.status for r in records] == ["rejected"] * 3
    assert all(r.reason and r.reason.startswith("photometric residual") for r in records)
    assert not list((out / "rec" / "input").glob("*.png"))  # no stale outputs stay behind
    assert json.loads((out / "rec" / "report.json").read_text())["counts"]["kept"] == 0
    # nor the earlier run's qa.png, which showed pairs whose files were removed
    assert not (out / "rec" / "qa.png").exists()


def test_a_namesake_recording_is_refused_not_merged(tmp_path: Path) -> None:
    first = make_recording(tmp_path / "a" / "rec", frames=3)
    second = make_recording(tmp_path / "b" / "rec", frames=3, obstructed="cam0")
    out = tmp_path / "out"
    _, _, report = _ingest(first, out)
    assert Path(report.source) == first.resolve()  # absolute, whatever the working folder
    pairs_before = (out / "rec" / "pairs.jsonl").read_bytes()
    with pytest.raises(CaptureError, match=r"holds the ingest of .*a/rec.*same name"):
        _ingest(second, out)
    assert (out / "rec" / "pairs.jsonl").read_bytes() == pairs_before  # untouched
    _ingest(first, out)  # the same recording again: a rerun, accepted
    _ingest(first / "mav0", out)  # the same recording by its mav0 folder, too
    # a run stopped while its report was set aside (ingest_report.set_report_aside):
    # the guard read report.json only, and the namesake was let in
    set_report_aside(out / "rec")
    with pytest.raises(CaptureError, match=r"holds the ingest of .*a/rec.*same name"):
        _ingest(second, out)


def test_a_moved_recording_resumes_its_ingest(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    recording = make_recording(tmp_path / "a" / "rec", frames=3)
    out_dir, _, _ = _ingest(recording, tmp_path / "out")
    stamps = {p: p.stat().st_mtime_ns for p in (out_dir / "input").iterdir()}
    moved = tmp_path / "b" / "rec"
    moved.parent.mkdir()
    recording.rename(moved)  # times kept, as mv keeps them
    with caplog.at_level(logging.WARNING):
        _, _, report = _ingest(moved, tmp_path / "out")
    assert Path(report.source) == moved.resolve()
    assert {p: p.stat().st_mtime_ns for p in (out_dir / "input").iterdir()} == stamps  # resumed
    assert not any("processed again" in m for m in caplog.messages)


def test_a_recording_given_as_dot_from_inside_mav0_finds_its_rig_and_calibration(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    recording = make_recording(tmp_path / "rec", frames=3)
    _, _, absolute = _ingest(recording / "mav0", tmp_path / "a")
    monkeypatch.chdir(recording / "mav0")
    # "." has "." for parent: rig.yaml was not found beside mav0 (an error, or with
    # --obstructed no anomaly labels and another calibration), "rec" named it right
    _, _, dot = _ingest(Path("."), tmp_path / "b")
    assert dot.anomaly == absolute.anomaly == ("rain",)
    assert dot.calibration_source == absolute.calibration_source
    monkeypatch.chdir(recording / "mav0" / "cam0")
    _, _, up = _ingest(Path(".."), tmp_path / "c")
    assert up.anomaly == ("rain",) and up.calibration_source == absolute.calibration_source


def test_a_rerun_from_another_working_folder_resumes_every_frame(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    recording = make_recording(tmp_path / "rec", frames=4)
    monkeypatch.chdir(tmp_path)
    out_dir, _, _ = _ingest(Path("rec"), tmp_path / "out")
    files = {p: p.read_bytes() for p in out_dir.rglob("*") if p.is_file()}
    stamps = {p: p.stat().st_mtime_ns for p in (out_dir / "input").iterdir()}
    monkeypatch.chdir(recording / "mav0")
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        _ingest(Path("..") / ".." / "rec", tmp_path / "out")  # the same recording
    # every frame was done again ("the ... input frames differ"), the homography too
    assert not any("processed again" in m for m in caplog.messages)
    assert {p: p.stat().st_mtime_ns for p in (out_dir / "input").iterdir()} == stamps
    after = {p: p.read_bytes() for p in out_dir.rglob("*") if p.is_file()}
    assert after.keys() == files.keys()
    changed = [p.name for p in files if files[p] != after[p]]
    assert set(changed) <= {"report.json"}, changed  # its timings


def test_a_frame_key_holds_its_place_size_and_time_not_its_path(tmp_path: Path) -> None:
    import os

    from lenspair.capture.ingest_frames import FrameTask
    from lenspair.capture.recording_types import FrameRef

    files = [tmp_path / "cam1.png", tmp_path / "cam0.png"]
    for file in files:
        file.write_bytes(b"x" * 100)

    def key(folder: Path) -> str:
        frames = (
            FrameRef("cam1", 5, folder / "cam1.png"),
            FrameRef("cam0", 5, folder / "cam0.png"),
        )
        return FrameTask(*frames, "state").key

    before = key(tmp_path)
    (tmp_path / "sub").mkdir()
    assert key(tmp_path / "sub" / "..") == before  # another spelling: it did every frame again
    moved = tmp_path / "moved"
    moved.mkdir()
    for file in files:
        file.rename(moved / file.name)
    os.chmod(moved / "cam1.png", 0o444)  # protecting raw data keeps the work done
    assert key(moved) == before
    (moved / "cam1.png").chmod(0o644)
    (moved / "cam1.png").write_bytes(b"y" * 101)  # replaced: redone
    assert key(moved) != before


def test_a_camera_recorded_twice_is_said(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    # cam1's files holding cam0's images: every pair kept, nothing said
    recording = make_recording(tmp_path / "rec", frames=3)
    cam0 = sorted((recording / "mav0" / "cam0" / "data").glob("*.png"))
    cam1 = sorted((recording / "mav0" / "cam1" / "data").glob("*.png"))
    with caplog.at_level(logging.WARNING):
        _ingest(recording, tmp_path / "first")
    assert not any("byte for byte the same" in m for m in caplog.messages)
    for left, right in zip(cam0, cam1, strict=True):
        right.write_bytes(left.read_bytes())
    # identical views may not register at all: it is said either way, first
    with caplog.at_level(logging.WARNING), contextlib.suppress(CaptureError, RectifyError):
        _ingest(recording, tmp_path / "out")
    assert any("byte for byte the same in all 3 pairs" in m for m in caplog.messages)


def test_an_out_that_makes_the_ingest_the_recording_itself_is_refused(tmp_path: Path) -> None:
    # --out = the recording's parent made OUT/<rec> the recording itself: input/ and
    # target/ were written into it, and files of the user's there were deleted
    recording = make_recording(tmp_path / "rec", frames=3)
    mask = recording / "mask"
    mask.mkdir()
    (mask / "12345.png").write_bytes(b"the user's own file")
    files = sorted(p for p in recording.rglob("*"))
    with pytest.raises(CaptureError, match=r"which is the recording .*rec itself; "):
        _ingest(recording, tmp_path)
    assert sorted(p for p in recording.rglob("*")) == files  # nothing written, nothing removed
    assert (mask / "12345.png").read_bytes() == b"the user's own file"
    _ingest(recording, recording / "processed")  # a fresh folder inside it holds nothing of theirs
    assert (mask / "12345.png").read_bytes() == b"the user's own file"


def test_a_euroc_recording_calibrated_only_by_its_sensor_yaml_files(tmp_path: Path) -> None:
    # Real EuRoC recordings ship mav0/camN/sensor.yaml (intrinsics, T_BS) and no
    # camchain: they were "no calibration" unless converted to Kalibr by hand.
    from lenspair.simulate.euroc import write_sensor_yaml
    from tests.capture.ingest_helpers import rig

    truth = rig()
    body_from = {"cam0": np.eye(4), "cam1": np.linalg.inv(truth.T_cam1_cam0)}
    body = np.array([[0, 0, 1, 0.1], [-1, 0, 0, 0.02], [0, -1, 0, 0.0], [0, 0, 0, 1.0]])
    recording = make_recording(tmp_path / "euroc", frames=3, camchain=False)
    for camera in ("cam0", "cam1"):
        sensor = recording / "mav0" / camera / "sensor.yaml"
        write_sensor_yaml(sensor, truth.camera(camera), body @ body_from[camera], 20.0, camera)
    out_dir, records, report = _ingest(recording, tmp_path / "out")
    assert "EuRoC sensor.yaml" in report.calibration_source
    found = report.calibration  # the rig it used: the truth, up to float rounding
    np.testing.assert_allclose(np.asarray(found["cam1"]["T_cn_cnm1"]), truth.T_cam1_cam0, atol=1e-9)
    reference = make_recording(tmp_path / "kalibr", frames=3)
    _, expected, _ = _ingest(reference, tmp_path / "out2")
    assert [r.status for r in records] == [r.status for r in expected] == ["kept"] * 3
    images = sorted((tmp_path / "out2" / "kalibr").glob("*/*.png"))
    assert len(images) == 6  # input/ and target/ of 3 pairs: the same pixels
    for image in images:
        mine = out_dir / image.parent.name / image.name
        np.testing.assert_array_equal(read_image(mine), read_image(image))


def test_twelve_bit_values_in_16_bit_frames_are_scaled_not_judged_black(tmp_path: Path) -> None:
    # Mono12 cameras published as mono16 (values 0..4095): the side check called
    # every pair blank, registration found no corners, dataset-build called the
    # pairs blurred. The same scene at full 16-bit range is the reference.
    full = make_recording(tmp_path / "full", frames=3, dtype=np.uint16)
    low = make_recording(tmp_path / "low", frames=3, dtype=np.uint16)
    for camera in ("cam0", "cam1"):
        for path in frame_files(low, camera):
            write_image(path, read_image(path) >> 4)
    out_full, expected, report_full = _ingest(full, tmp_path / "out")
    out_low, records, report_low = _ingest(low, tmp_path / "out")
    assert (report_full.significant_bits, report_low.significant_bits) == (None, 12)
    assert report_low.significant_bits_per_camera == {"cam0": 12, "cam1": 12}
    assert [r.status for r in records] == [r.status for r in expected] == ["kept"] * 3
    images = sorted(out_full.glob("*/*.png"))
    assert len(images) == 6
    for image in images:
        reference = read_image(image).astype(np.int32)
        scaled = read_image(out_low / image.parent.name / image.name).astype(np.int32)
        assert np.abs(scaled - reference).max() <= 32  # the 4 low bits the camera lacked


@pytest.mark.parametrize("depths", [(16, 12), (10, 12)])
def test_cameras_of_different_bit_depths_are_each_scaled_by_their_own(
    tmp_path: Path, depths: tuple[int, int], caplog: pytest.LogCaptureFixture
) -> None:
    # Both cameras' frames were pooled into one depth: a true 16-bit cam0 beside a
    # 12-bit cam1 left cam1 unscaled (10 beside 12 scaled cam0 as 12-bit), so target
    # and input came out 4-16x apart in brightness, every pair kept.
    full = make_recording(tmp_path / "full", frames=3, dtype=np.uint16)
    mixed = make_recording(tmp_path / "mixed", frames=3, dtype=np.uint16)
    for camera, bits in zip(("cam0", "cam1"), depths, strict=True):
        for path in frame_files(mixed, camera):
            write_image(path, read_image(path) >> (16 - bits))
    out_full, expected, _ = _ingest(full, tmp_path / "out")
    with caplog.at_level(logging.WARNING):
        out_mixed, records, report = _ingest(mixed, tmp_path / "out")
    assert [r.status for r in records] == [r.status for r in expected] == ["kept"] * 3
    images = sorted(out_full.glob("*/*.png"))
    assert len(images) == 6
    for image in images:
        reference = read_image(image).astype(np.int32)
        scaled = read_image(out_mixed / image.parent.name / image.name).astype(np.int32)
        assert np.abs(scaled - reference).max() <= 1 << (16 - min(depths))  # the lacking bits
    assert report.significant_bits_per_camera == {"cam0": depths[0], "cam1": depths[1]}
    assert report.significant_bits is None  # no one depth of the recording
    for camera, bits in zip(("cam0", "cam1"), depths, strict=True):
        said = f"{camera}'s 16-bit frames hold {bits}-bit values"
        assert any(said in m for m in caplog.messages) == (bits < 16)
    assert read_report(out_mixed / "report.json") == report


def test_two_cameras_of_one_depth_either_side_of_a_depth_s_top_are_scaled_alike(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # two 12-bit cameras in a dim recording, cam1 exposed 5 % more: cam0 peaking at 1000
    # read as 10-bit, cam1 at 1050 as 12-bit, and the target came out 3.8x the input's
    # brightness (every pair kept, dataset-build called them all hard)
    dim = make_recording(tmp_path / "dim", frames=3, dtype=np.uint16)
    peak = max(int(read_image(path).max()) for path in frame_files(dim, "cam0"))
    for camera, top in (("cam0", 1000), ("cam1", 1050)):
        for path in frame_files(dim, camera):
            write_image(path, np.rint(read_image(path) / peak * top).astype(np.uint16))
    with caplog.at_level(logging.WARNING):
        out_dir, records, report = _ingest(dim, tmp_path / "out")
    assert report.significant_bits_per_camera == {"cam0": 12, "cam1": 12}
    assert [r.status for r in records] == ["kept"] * 3
    said = "cam0's 16-bit frames peak below 1024, as 10-bit values would"
    assert any(said in m and "both are taken as 12-bit" in m for m in caplog.messages)
    for name in sorted(path.name for path in (out_dir / "input").glob("*.png")):
        source = read_image(out_dir / "input" / name).astype(np.float64).mean()
        target = read_image(out_dir / "target" / name).astype(np.float64).mean()
        assert 0.8 < source / target < 1.25  # the cameras' own 5 %, not 4x


def test_reports_of_before_per_camera_fields_are_read(tmp_path: Path) -> None:
    # report.json gained significant_bits_per_camera and topics: older ones still load
    out_dir, _, report = _ingest(make_recording(tmp_path / "rec", frames=2), tmp_path / "out")
    assert report.significant_bits_per_camera == {"cam0": 16, "cam1": 16}
    assert report.topics == {}  # a folder: no topics
    data = json.loads((out_dir / "report.json").read_text())
    del data["significant_bits_per_camera"], data["topics"]
    (out_dir / "report.json").write_text(json.dumps(data))
    from lenspair.dataset.sources import load_source

    for older in (read_report(out_dir / "report.json"), load_source(out_dir).report):
        assert (older.significant_bits_per_camera, older.topics) == ({}, {})
        assert older.significant_bits == report.significant_bits


@given(
    values=st.lists(st.integers(0, 65535), min_size=1, max_size=50),
    bits=st.sampled_from([10, 12, 16]),
)
def test_widening_keeps_order_black_and_full_scale(values: list[int], bits: int) -> None:
    top = (1 << bits) - 1
    image = np.array([0, top, *(v & top for v in values)], np.uint16)
    assert significant_bits([image]) == bits
    assert significant_bits([image.astype(np.uint8)]) == 16  # 8-bit frames: as they are
    wide = widen(image, bits).astype(np.int64)
    assert wide[0] == 0 and wide[1] == 65535  # black stays black, full scale stays full
    order = np.argsort(image, kind="stable")
    assert np.all(np.diff(wide[order]) >= 0)  # no value overtakes another
    if bits == 16:
        np.testing.assert_array_equal(wide, image)
    every = np.arange(1 << bits, dtype=np.uint16)  # restore writes the camera's words back
    np.testing.assert_array_equal(narrow(widen(every, bits), bits), every)


def test_a_frame_the_bit_depth_sample_missed_is_rejected_not_clipped(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from lenspair.capture import ingest_registration

    # pairs 0 and 3 of 4 are sampled
    monkeypatch.setattr(ingest_registration, "BIT_DEPTH_FRAMES", 2)
    low = make_recording(tmp_path / "low", frames=4, dtype=np.uint16)
    for camera in ("cam0", "cam1"):
        for path in frame_files(low, camera):
            write_image(path, read_image(path) >> 4)
    bright = frame_files(low, "cam1")[1]  # one 16-bit value the sample does not see
    image = read_image(bright)
    image[0, 0] = 60000
    write_image(bright, image)
    _, records, report = _ingest(low, tmp_path / "out")
    assert report.significant_bits == 12
    assert [r.status for r in records] == ["kept", "rejected", "kept", "kept"]
    assert records[1].reason is not None
    assert records[1].reason.startswith("values above cam1's 12 bits (60000 > 4095 in ")
    assert report.rejection_reasons == {"values above cam1's 12 bits": 1}


def test_a_bag_timed_by_its_log_time_says_so_in_report_json(tmp_path: Path) -> None:
    # the README says the fallback is "said in the report": it was in the log only
    from tests.capture.ingest_helpers import rig
    from tests.capture.test_rosbag import IMAGE, _raw_fields, _write_bag

    euroc = make_recording(tmp_path / "euroc", frames=3)
    messages = []
    for camera in ("cam0", "cam1"):
        for path in frame_files(euroc, camera):
            fields = {**_raw_fields(read_image(path), "mono8"), "_log_ns": int(path.stem)}
            messages.append((f"/{camera}/image_raw", IMAGE, 0, fields))  # stamps never set
    messages.sort(key=lambda message: message[3]["_log_ns"])
    folder = tmp_path / "bags"
    folder.mkdir()
    (folder / "rig.yaml").write_text("obstructed: cam1\n")
    from lenspair.rectify.rig import write_kalibr

    write_kalibr(folder / "camchain.yaml", rig())
    bag = _write_bag(folder / "run", "ros1", messages)
    _, records, report = _ingest(bag, tmp_path / "out")
    assert [r.status for r in records] == ["kept"] * 3
    (said,) = report.recording_problems
    assert said.startswith(f"{bag}: every header.stamp of /cam0/image_raw 0 ns")
    assert report.counts["recording_problems"] == 1


def test_stale_outputs_are_removed_with_one_line_not_one_per_file(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # a rerun with the other side obstructed logged a line per file: tens of thousands on
    # a long recording, burying the warning that said why
    for kind, frames in (("input", (1, 2, 3)), ("target", (1, 2))):
        for t in frames:
            write_image(tmp_path / kind / f"{t}.png", np.zeros((4, 4), np.uint8))
    write_image(tmp_path / "input" / "mine.png", np.zeros((4, 4), np.uint8))
    with caplog.at_level(logging.INFO, logger="lenspair.capture.journal"):
        remove_stale_outputs(tmp_path, [], own_frames={1, 2, 3})
    removed = [r.getMessage() for r in caplog.records if ": removed " in r.getMessage()]
    assert removed == [f"{tmp_path}: removed 3 from input/, 2 from target/, written by an "
                       "earlier run and not kept now"]  # fmt: skip
    assert sorted(p.name for p in tmp_path.rglob("*.png")) == ["mine.png"]
