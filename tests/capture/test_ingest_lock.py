"""One capture-ingest at a time per output folder: the lock, its refusal, a killed holder."""

import logging
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from lenspair.capture import ingest as ingest_module
from lenspair.capture.errors import CaptureError
from lenspair.capture.ingest import ingest_recording
from lenspair.capture.journal import LOCK_FILE, remove_temporaries
from lenspair.cli import main
from lenspair.dataset import build as build_module
from lenspair.dataset.build import build_dataset
from lenspair.dataset.config import DatasetConfig
from lenspair.dataset.errors import DatasetError
from lenspair.dataset.verify import verify_dataset
from tests.capture.ingest_helpers import CROP, make_recording, tree_bytes
from tests.locks import held_lock, is_locked

SIZE = (240, 160)


def test_a_second_run_into_an_output_being_written_is_refused_at_once(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recording = make_recording(tmp_path / "rec", frames=3)
    out = tmp_path / "out"
    ingest_recording(recording, out, size=SIZE)
    out_dir = out / "rec"
    before = tree_bytes(out_dir)
    command = ["capture-ingest", str(recording), "--out", str(out), "--size", "200x120"]
    with held_lock(out_dir / LOCK_FILE):  # a first run, still writing
        capsys.readouterr()
        assert main(command) == 2
        error = capsys.readouterr().err.strip().splitlines()
        with pytest.raises(CaptureError, match="another capture-ingest is writing it"):
            ingest_recording(recording, out, size=SIZE)
    assert len(error) == 1
    assert error[0].startswith(
        f"lenspair capture-ingest: error: {out_dir}: another capture-ingest is writing it"
    )
    assert tree_bytes(out_dir) == before  # nothing removed, nothing written
    assert main(command) == 0  # once that run has ended: a rerun, as usual


def test_a_refused_run_writes_nothing_into_a_new_output(tmp_path: Path) -> None:
    recording = make_recording(tmp_path / "rec", frames=2)
    out_dir = tmp_path / "out" / "rec"
    out_dir.mkdir(parents=True)
    with held_lock(out_dir / LOCK_FILE), pytest.raises(CaptureError, match=str(out_dir)):
        ingest_recording(recording, tmp_path / "out", size=SIZE)
    assert [p.name for p in out_dir.iterdir()] == [LOCK_FILE]


def test_a_killed_run_does_not_block_its_rerun(tmp_path: Path) -> None:
    recording = make_recording(tmp_path / "rec", frames=3)
    out_dir = tmp_path / "out" / "rec"
    out_dir.mkdir(parents=True)
    holder = subprocess.Popen(  # holds the lock as a run does, until it is killed
        [
            sys.executable,
            "-c",
            "import fcntl, os, sys, time\n"
            "d = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT)\n"
            "fcntl.flock(d, fcntl.LOCK_EX)\n"
            "print('held', flush=True)\n"
            "time.sleep(600)\n",
            str(out_dir / LOCK_FILE),
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline() == "held\n"
        with pytest.raises(CaptureError, match="another capture-ingest is writing it"):
            ingest_recording(recording, tmp_path / "out", size=SIZE)
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    report = ingest_recording(recording, tmp_path / "out", size=SIZE)  # not blocked
    assert report.counts["kept"] == 3


def test_the_lock_is_held_for_the_run_and_is_nobodys_stray_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    recording = make_recording(tmp_path / "rec", frames=3)
    out = tmp_path / "out"
    out_dir = out / "rec"
    seen: list[bool] = []
    frame_stage = ingest_module.run_frame_stage

    def watched(*args: Any) -> Any:
        seen.append(is_locked(out_dir / LOCK_FILE))
        remove_temporaries(out_dir)  # the clean-up of killed runs leaves a held lock alone
        seen.append((out_dir / LOCK_FILE).is_file())
        return frame_stage(*args)

    monkeypatch.setattr(ingest_module, "run_frame_stage", watched)
    ingest_recording(recording, out, size=SIZE)
    assert seen == [True, True]
    assert not is_locked(out_dir / LOCK_FILE)  # released at the end
    with caplog.at_level(logging.INFO):
        assert main(["capture-ingest", str(recording), "--out", str(out), "--size", CROP]) == 0
    assert not any(LOCK_FILE in message for message in caplog.messages)  # not stray, not removed
    assert (out_dir / LOCK_FILE).is_file()
    dataset = build_dataset([out_dir], tmp_path / "DS", DatasetConfig())
    assert not any(p.name == LOCK_FILE for p in dataset.out.rglob("*"))


def test_a_recording_being_ingested_is_not_built_from_and_a_build_holds_it_meanwhile(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # a capture-ingest rerun (another --size) during a build gave a dataset of its new images
    # under a manifest of the old ones' hashes, with exit 0
    recording = make_recording(tmp_path / "rec", frames=3)
    out = tmp_path / "out"
    ingest_recording(recording, out, size=SIZE)
    out_dir = out / "rec"
    writing = rf"^{out_dir}: a capture-ingest is writing it"
    with held_lock(out_dir / LOCK_FILE), pytest.raises(DatasetError, match=writing):
        build_dataset([out_dir], tmp_path / "DS", DatasetConfig())  # while one still writes
    assert not (tmp_path / "DS").exists()
    refused: list[str] = []
    real_write_images = build_module.write_images

    def ingest_meanwhile(*args: Any) -> None:
        try:
            ingest_recording(recording, out, size=(200, 120))
        except CaptureError as exc:
            refused.append(str(exc))
        real_write_images(*args)

    monkeypatch.setattr(build_module, "write_images", ingest_meanwhile)
    dataset = build_dataset([out_dir], tmp_path / "DS", DatasetConfig())
    assert len(refused) == 1 and "or a dataset-build is reading it" in refused[0]
    assert verify_dataset(dataset.out).ok
    assert not is_locked(out_dir / LOCK_FILE)  # released at the end
