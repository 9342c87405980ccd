"""The ``train-detector`` run folder: refused early, written whole, one writer at a time."""

import errno
import os
from pathlib import Path

import pytest

import lenspair.model.detection.run as detector_run
from lenspair.core import fsutil
from lenspair.core.folderlock import lock_file
from lenspair.model.detection.run import RUN_FILES, DetectorSources, run_training
from lenspair.model.detection.train import DetectorTraining, load_detector
from lenspair.model.errors import ModelError
from lenspair.model.networks.detector import DetectorSpec
from tests.file_limits import file_size_limit, refuse_writes

SPEC = DetectorSpec(widths=(4, 8, 8), context_dilations=(2,), input_size=(48, 64))
SOURCES = DetectorSources(synthetic=8)
SETTINGS = DetectorTraining(steps=1, batch_size=2)

pytestmark = pytest.mark.usefixtures("one_thread")


def _run(out: Path) -> None:
    run_training(out, SOURCES, SPEC, SETTINGS)


def test_a_read_only_out_is_refused_before_the_data_is_gathered(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # an existing read-only folder was found only when detector.pt was written, after training
    out = tmp_path / "run"
    out.mkdir()
    refuse_writes(monkeypatch, out, errno.EROFS)
    gathered: list[object] = []
    monkeypatch.setattr(detector_run, "gather", lambda *a, **k: gathered.append(a))
    with pytest.raises(OSError) as caught:
        _run(out)
    assert caught.value.errno == errno.EROFS and "run" in str(caught.value.filename)
    assert gathered == []


def test_a_full_disk_leaves_none_of_the_run_and_the_same_command_runs_again(
    tmp_path: Path,
) -> None:
    # the texts fit, detector.pt does not: scores and run.json were left, and the rerun
    # was refused as "already holds a detector run"
    out = tmp_path / "run"
    with file_size_limit(8192), pytest.raises(OSError) as caught:
        _run(out)
    assert caught.value.errno == errno.EFBIG
    assert caught.value.filename == str(out / "detector.pt")
    assert not any((out / name).exists() for name in RUN_FILES)
    assert [p.name for p in out.iterdir() if not p.name.startswith(".")] == []
    _run(out)
    assert all((out / name).is_file() for name in RUN_FILES)
    assert load_detector(out / "detector.pt").spec == SPEC


def test_a_disk_full_at_a_later_file_leaves_none_of_the_others(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # written one after another, detector.pt and two reports were left beside the failure,
    # and the same command was then refused: "already holds a detector run"
    real_sync = fsutil._sync
    synced: list[Path] = []

    def full_at_the_third_file(path: Path) -> None:
        synced.append(Path(path))
        if len(synced) == 3:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        real_sync(path)

    monkeypatch.setattr(fsutil, "_sync", full_at_the_third_file)
    out = tmp_path / "run"
    with pytest.raises(OSError) as caught:
        _run(out)
    assert caught.value.errno == errno.ENOSPC
    assert Path(caught.value.filename).name in RUN_FILES  # named, not its temporary
    assert [p.name for p in out.iterdir() if not p.name.startswith(".")] == []
    monkeypatch.setattr(fsutil, "_sync", real_sync)
    _run(out)


def test_a_second_run_into_the_same_folder_is_refused_while_the_first_trains(
    tmp_path: Path,
) -> None:
    # both trained to the end and the last one's files replaced the first's
    out = tmp_path / "run"
    out.mkdir()
    held = lock_file(out / detector_run.LOCK_FILE, "train-detector")
    assert held is not None
    try:
        with pytest.raises(ModelError, match=r"another train-detector is writing it"):
            _run(out)
    finally:
        os.close(held)
    assert not any((out / name).exists() for name in RUN_FILES)
    _run(out)  # free once the first has ended
    with pytest.raises(ModelError, match=r"already holds a detector run"):
        _run(out)
