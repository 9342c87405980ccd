"""Resuming an interrupted ingest: deleted outputs, a cut journal, an exception, kill -9."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lenspair.capture import ingest as ingest_module
from lenspair.capture import ingest_frames
from lenspair.capture.ingest import ingest_recording
from lenspair.capture.ingest_report import STALE_REPORT
from lenspair.capture.ingested import read_pairs
from lenspair.capture.journal import JOURNAL_FILE
from lenspair.dataset.build import build_dataset
from lenspair.dataset.config import DatasetConfig
from lenspair.dataset.errors import DatasetError
from tests.capture.ingest_helpers import simulate, tree_bytes
from tests.file_limits import run_with_file_limit
from tests.processes import descendants, wait_gone


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, bytes]]:
    """A simulated rain recording (4 frames) and the files of an uninterrupted ingest."""
    root = tmp_path_factory.mktemp("resume")
    recording = simulate("rain", root / "rain", frames=4)
    ingest_recording(recording, root / "out")
    return recording, tree_bytes(root / "out" / "rain")


def _same_as(reference: dict[str, bytes], out_dir: Path) -> None:
    files = tree_bytes(out_dir)
    assert files.keys() == reference.keys()
    for name, content in reference.items():
        if name == "report.json":  # rewritten by the resumed run: only its timings differ
            ours, theirs = json.loads(files[name]), json.loads(content)
            del ours["timings_s"], theirs["timings_s"]
            assert ours == theirs
        else:
            assert files[name] == content, name


def test_resume_after_deleting_outputs_and_cutting_the_journal(
    reference: tuple[Path, dict[str, bytes]], tmp_path: Path
) -> None:
    recording, files = reference
    out_dir = tmp_path / "rain"
    for name, content in files.items():
        (out_dir / name).parent.mkdir(parents=True, exist_ok=True)
        (out_dir / name).write_bytes(content)
    inputs = sorted((out_dir / "input").glob("*.png"))
    inputs[0].unlink()
    (out_dir / "target" / inputs[-1].name).write_bytes(b"damaged")
    (out_dir / "pairs.jsonl").unlink()
    (out_dir / "report.json").unlink()
    journal = out_dir / JOURNAL_FILE
    journal.write_bytes(journal.read_bytes()[: len(journal.read_bytes()) // 2])  # cut mid-line
    ingest_recording(recording, tmp_path)
    _same_as(files, out_dir)


def test_resume_after_an_exception_mid_run(
    reference: tuple[Path, dict[str, bytes]], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    recording, files = reference
    real = ingest_frames.process
    calls = []

    def crash_on_second(task: ingest_frames.FrameTask) -> object:
        calls.append(task)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(task)

    monkeypatch.setattr(ingest_frames, "process", crash_on_second)
    with pytest.raises(KeyboardInterrupt):
        ingest_recording(recording, tmp_path)
    monkeypatch.setattr(ingest_frames, "process", real)
    assert not (tmp_path / "rain" / "pairs.jsonl").exists()
    assert len((tmp_path / "rain" / JOURNAL_FILE).read_text().splitlines()) == 1
    ingest_recording(recording, tmp_path)
    _same_as(files, tmp_path / "rain")


def test_resume_after_kill_9(reference: tuple[Path, dict[str, bytes]], tmp_path: Path) -> None:
    recording, files = reference
    journal = tmp_path / "rain" / JOURNAL_FILE
    command = [sys.executable, "-m", "lenspair", "capture-ingest", str(recording)]
    process = subprocess.Popen(
        [*command, "--out", str(tmp_path)],
        env={**os.environ, "LENSPAIR_QUIET": "1"},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 120
    while process.poll() is None and time.monotonic() < deadline:
        if journal.is_file() and journal.read_text():
            break  # at least one frame is done: kill it in the middle of the rest
        time.sleep(0.02)
    process.send_signal(signal.SIGKILL)
    process.wait()
    ingest_recording(recording, tmp_path)
    _same_as(files, tmp_path / "rain")
    shutil.rmtree(tmp_path / "rain")


def test_workers_end_when_the_parent_is_killed(
    reference: tuple[Path, dict[str, bytes]], tmp_path: Path
) -> None:
    recording, _ = reference
    journal = tmp_path / "rain" / JOURNAL_FILE
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "lenspair",
            "capture-ingest",
            str(recording),
            "--out",
            str(tmp_path),
            "--workers",
            "2",
        ],
        env={**os.environ, "LENSPAIR_QUIET": "1"},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 120
    children: set[int] = set()
    while process.poll() is None and time.monotonic() < deadline:
        children |= descendants(process.pid)
        if len(children) >= 3 and journal.is_file() and journal.read_text():
            break  # the tracker and both workers run, and frames are being written
        time.sleep(0.02)
    assert process.poll() is None, "ingest finished before it could be killed"
    process.send_signal(signal.SIGKILL)
    process.wait()
    assert wait_gone(children, timeout=10) == set()
    written = {p.name for p in (tmp_path / "rain" / "input").glob("*.png")}
    time.sleep(0.5)
    assert {p.name for p in (tmp_path / "rain" / "input").glob("*.png")} == written


def test_a_users_file_in_the_output_is_kept_and_reported(
    reference: tuple[Path, dict[str, bytes]], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    recording, _ = reference
    ingest_recording(recording, tmp_path)
    mine = tmp_path / "rain" / "input" / "my_notes.png"
    mine.write_bytes(b"a user's own file")
    kept = sorted((tmp_path / "rain" / "input").glob("1*.png"))
    ingest_recording(recording, tmp_path)
    assert mine.read_bytes() == b"a user's own file"
    assert any(
        "my_notes.png" in r.getMessage() and r.levelname == "WARNING" for r in caplog.records
    )
    assert sorted((tmp_path / "rain" / "input").glob("1*.png")) == kept


def test_rerun_with_the_other_side_declared_replaces_the_first_runs_pairs(
    reference: tuple[Path, dict[str, bytes]], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    recording, files = reference  # rig.yaml: cam1 obstructed
    ingest_recording(recording, tmp_path, obstructed="cam0")  # the wrong side, first
    first = len(read_pairs(tmp_path / "rain" / "pairs.jsonl"))
    caplog.clear()
    ingest_recording(recording, tmp_path)  # corrected: as an ingest straight away
    _same_as(files, tmp_path / "rain")  # no pair of the wrong-side run is left
    assert not any("not written by capture-ingest" in r.getMessage() for r in caplog.records)
    # and the swap is said, as --help promises of a rerun with another side: the journal
    # is keyed by the obstructed camera's stamps, so no frame read as "processed again"
    said = [r.getMessage() for r in caplog.records if "are replaced" in r.getMessage()]
    assert len(said) == 1, said
    count, reason = said[0].removeprefix(f"{tmp_path / 'rain'}: ").split(" finished frames ")
    assert 0 < int(count) <= first  # the frames the first run finished
    assert reason == "are replaced: the obstructed side differs (was cam0, now cam1)"


def test_a_rerun_stopped_after_its_pairs_leaves_no_report_to_misread(
    reference: tuple[Path, dict[str, bytes]], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    recording, files = reference  # rig.yaml: cam1 obstructed
    ingest_recording(recording, tmp_path, obstructed="cam0")  # the wrong side, first
    out_dir = tmp_path / "rain"

    def killed(*args: object) -> None:
        raise KeyboardInterrupt  # after pairs.jsonl, before report.json

    monkeypatch.setattr(ingest_module, "write_qa_sheet", killed)
    with pytest.raises(KeyboardInterrupt):
        ingest_recording(recording, tmp_path)  # corrected, then stopped
    # the new pairs beside the old report said cam0, and dataset-build built the
    # pairs the wrong way round; now there is no report until the run finishes
    assert (out_dir / "pairs.jsonl").is_file() and not (out_dir / "report.json").exists()
    with pytest.raises(DatasetError, match="stopped before it finished: run it again"):
        build_dataset([out_dir], tmp_path / "ds", DatasetConfig())
    monkeypatch.undo()
    ingest_recording(recording, tmp_path)
    _same_as(files, out_dir)
    assert not (out_dir / STALE_REPORT).exists()


def test_an_unchanged_rerun_keeps_the_reports_bytes(
    reference: tuple[Path, dict[str, bytes]], tmp_path: Path
) -> None:
    recording, _ = reference
    ingest_recording(recording, tmp_path)
    before = (tmp_path / "rain" / "report.json").read_bytes()
    ingest_recording(recording, tmp_path)  # set aside and put back: the same timings
    assert (tmp_path / "rain" / "report.json").read_bytes() == before
    assert not (tmp_path / "rain" / STALE_REPORT).exists()


def test_a_full_disk_leaves_no_frame_behind_and_a_rerun_repairs_everything(
    reference: tuple[Path, dict[str, bytes]], tmp_path: Path
) -> None:
    recording, files = reference
    pngs = sorted(len(content) for name, content in files.items() if name.endswith(".png"))
    limit = pngs[len(pngs) // 2]  # half the images cannot be written whole
    failed = run_with_file_limit(["capture-ingest", str(recording), "--out", str(tmp_path)], limit)
    assert failed.returncode == 1, failed.stderr
    (line,) = failed.stderr.strip().splitlines()  # one line naming the image, no traceback
    assert line.startswith("lenspair capture-ingest: error: ") and ".png" in line
    out_dir = tmp_path / "rain"
    for image in out_dir.rglob("*.png"):  # nothing incomplete under a final name
        assert image.stat().st_size == len(files[image.relative_to(out_dir).as_posix()])
    ingest_recording(recording, tmp_path)
    _same_as(files, out_dir)


@pytest.mark.parametrize("listed", [True, False])
def test_a_frame_deleted_from_the_recording_takes_its_outputs_along(
    reference: tuple[Path, dict[str, bytes]],
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
    listed: bool,
) -> None:
    recording, _ = reference
    copy = tmp_path / "rain"
    shutil.copytree(recording, copy)
    if not listed:  # timestamps from the file names: a deleted file leaves no trace
        for csv in copy.rglob("data.csv"):
            csv.unlink()
    out = tmp_path / "out"
    ingest_recording(copy, out)
    victim = next(r for r in read_pairs(out / "rain" / "pairs.jsonl") if r.status == "kept")
    for relative in victim.files.values():
        assert (out / "rain" / relative).is_file()
    obstructed = copy / "mav0" / "cam1" / "data" / f"{victim.t_ns}.png"  # rig.yaml: cam1
    obstructed.unlink()
    ingest_recording(copy, out)
    lines = [r for r in read_pairs(out / "rain" / "pairs.jsonl") if r.t_ns == victim.t_ns]
    # listed in data.csv: rejected as missing; otherwise no longer a frame of the recording
    assert [r.status for r in lines] == (["rejected"] if listed else [])
    for relative in victim.files.values():  # gone, as from a clean ingest of what is left
        assert not (out / "rain" / relative).exists()
    assert "not written by capture-ingest" not in caplog.text


def test_a_rerun_with_other_thresholds_says_it_processes_finished_frames_again(
    reference: tuple[Path, dict[str, bytes]], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # a rerun with other settings (another --calib, thresholds) replaced finished
    # outputs without a word, though --help said they were left untouched
    from lenspair.rectify.registration import VerifyParams

    recording, _ = reference
    ingest_recording(recording, tmp_path)
    kept = len(list((tmp_path / "rain" / "input").glob("*.png")))
    caplog.clear()
    ingest_recording(recording, tmp_path, verify=VerifyParams(min_correlation=0.5))
    [said] = [r.getMessage() for r in caplog.records if "processed again" in r.getMessage()]
    assert said.endswith(
        f": {kept} finished frames are processed again: the thresholds differ "
        "(min_correlation was 0.6, now 0.5)"
    )
    caplog.clear()
    ingest_recording(recording, tmp_path, verify=VerifyParams(min_correlation=0.5))
    assert not any("processed again" in r.getMessage() for r in caplog.records)  # unchanged


def _processed_again(caplog: pytest.LogCaptureFixture) -> str:
    """What the one "processed again" warning says after the count."""
    [said] = [r.getMessage() for r in caplog.records if "processed again" in r.getMessage()]
    caplog.clear()
    return said.split(" finished frames are processed again: ", 1)[1]


def test_a_rerun_names_the_calibration_or_size_that_differs(
    reference: tuple[Path, dict[str, bytes]], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # "the calibration, obstructed side, --size, --time-offset, thresholds or input
    # frames differ" left the user to guess which one
    recording, _ = reference
    first, second = tmp_path / "first.yaml", tmp_path / "second.yaml"
    for calibration in (first, second):
        shutil.copy(recording / "camchain.yaml", calibration)
    out = tmp_path / "out"
    ingest_recording(recording, out, calibration=(first,))
    ingest_recording(recording, out, calibration=(second,))  # the same numbers: nothing redone
    assert not any("processed again" in r.getMessage() for r in caplog.records)
    text = second.read_text()
    second.write_text(text.replace("[351.6, 351.1,", "[352.6, 351.1,"))  # cam1's focal length
    ingest_recording(recording, out, calibration=(second,))
    assert _processed_again(caplog) == (
        f"the calibration differs (Kalibr camchain {second} changed since: cam1.intrinsics "
        "was [351.6, 351.1, 357.9, 271.2], now [352.6, 351.1, 357.9, 271.2])"
    )
    ingest_recording(recording, out, calibration=(first,))
    assert _processed_again(caplog) == (
        f"the calibration differs (was Kalibr camchain {second}, now Kalibr camchain {first})"
    )
    ingest_recording(recording, out, calibration=(first,), size=(320, 240))
    assert _processed_again(caplog) == "--size differs (was 540x360, now 320x240)"


def test_a_rerun_says_which_input_frame_changed_or_that_it_cannot_tell(
    reference: tuple[Path, dict[str, bytes]], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    from lenspair.rectify.registration import VerifyParams

    recording, _ = reference
    copy = tmp_path / "rain"
    shutil.copytree(recording, copy)
    out = tmp_path / "out"
    ingest_recording(copy, out)
    frame = sorted((copy / "mav0" / "cam1" / "data").glob("*.png"))[-1]  # rig.yaml: cam1
    os.utime(frame, ns=(frame.stat().st_atime_ns, frame.stat().st_mtime_ns + 10**9))
    ingest_recording(copy, out)
    assert _processed_again(caplog) == "their input frames differ"
    journal = out / "rain" / JOURNAL_FILE
    lines = [json.loads(line) for line in journal.read_text().splitlines()]
    assert "settings" in lines[0] and all("settings" not in line for line in lines[1:])
    for line in lines:  # as an earlier version wrote it: no settings named
        line.pop("settings", None), line.pop("made_with")
    journal.write_text("".join(json.dumps(line) + "\n" for line in lines))
    ingest_recording(copy, out, verify=VerifyParams(min_correlation=0.5))
    assert _processed_again(caplog) == (
        "the calibration, obstructed side, --size, --time-offset, thresholds or input frames "
        "differ from the run that wrote them"
    )


@pytest.mark.parametrize(
    ("change", "said"),
    [
        ({"obstructed": "cam0"}, "the obstructed side differs (was cam1, now cam0)"),
        ({"time_offset_ns": 2_500_000}, "--time-offset differs (was 0 ms, now 2.5 ms)"),
        ({"version": "9.9"}, "the lenspair version differs (was 1.0, now 9.9)"),
        (
            {"crop": [1, 0, 540, 360]},
            "the homography or crop differs (registered again: other frames sampled, or "
            "other estimation thresholds)",
        ),
        (  # the first that differs, in the order of the old message
            {"calibration": {"cam0": {"intrinsics": [2.0]}}, "verify": {"min_correlation": 0.5}},
            "the calibration differs (Kalibr camchain c.yaml changed since: cam0.intrinsics was "
            "[1.0], now [2.0])",
        ),
        ({}, None),
    ],
)
def test_the_first_setting_that_differs_is_named(
    change: dict[str, object], said: str | None
) -> None:
    from lenspair.capture.journal import changed_setting

    before = {
        "obstructed": "cam1",
        "calibration": {"cam0": {"intrinsics": [1.0]}},
        "calibration_source": "Kalibr camchain c.yaml",
        "size": [540, 360],
        "time_offset_ns": 0,
        "verify": {"min_correlation": 0.6},
        "version": "1.0",
        "crop": [0, 0, 540, 360],
    }
    assert changed_setting(before, {**before, **change}) == said
