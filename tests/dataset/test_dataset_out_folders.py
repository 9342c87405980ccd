"""dataset-build's output folder: a mount point, and an earlier output among the sources."""

import os
from pathlib import Path

import pytest

from lenspair.cli import main
from lenspair.dataset import build as build_module
from lenspair.dataset import preflight
from lenspair.dataset.errors import DatasetError
from tests.dataset.dataset_synth import RecordingFactory


def test_a_mount_point_out_is_refused_before_any_pair_is_measured(
    recording: RecordingFactory,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """It measured and copied every pair beside the mount point (on the parent's disk), then
    failed renaming the mount point away with EBUSY and a traceback, leaving nothing."""
    source = recording("rec_a", n=6)
    out = tmp_path / "mounted"
    out.mkdir()  # a Docker bind mount (-v host/DS:/DS) or a freshly mounted disk: empty
    real_ismount = os.path.ismount
    monkeypatch.setattr(os.path, "ismount", lambda path: Path(path) == out or real_ismount(path))

    def measured(*args: object) -> None:
        raise AssertionError("a pair was measured before the refusal")

    monkeypatch.setattr(build_module, "measure_record", measured)
    assert main(["dataset-build", str(source), "--out", str(out)]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line == (
        f"lenspair dataset-build: error: {out}: a mount point, which a build cannot replace (it "
        "renames the finished dataset into place): give a folder inside it, e.g. --out "
        f"{out / 'dataset'}"
    )
    assert list(out.iterdir()) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ingested", "mounted"]


def test_a_dataset_caught_by_the_sources_glob_is_named_as_a_dataset(
    recording: RecordingFactory, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``dataset-build ingested/* --out DS2`` with an earlier dataset in ``ingested/`` said
    "missing pairs.jsonl (... capture-ingest was stopped before it finished: run it again)"."""
    sources = [recording("rec_a", n=6), recording("rec_b", n=6, obstructed="cam0", seed=1)]
    earlier = tmp_path / "ingested" / "DS"
    assert main(["dataset-build", *map(str, sources), "--out", str(earlier)]) == 0
    capsys.readouterr()
    globbed = sorted((tmp_path / "ingested").iterdir())  # what the shell makes of ingested/*
    assert earlier in globbed
    out = tmp_path / "DS2"
    assert main(["dataset-build", *map(str, globbed), "--out", str(out)]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(
        f"lenspair dataset-build: error: {earlier}: a dataset built by dataset-build, not an "
        "ingested recording: leave it out of the sources"
    )
    assert "pairs.jsonl" not in line and "run it again" not in line
    assert not out.exists()


def test_a_bind_mount_is_found_in_the_mount_table(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """os.path.ismount misses a bind mount within one file system (the same device as its
    parent): the process's mount table names it, a space written as an octal escape."""
    mounted = tmp_path / "host data" / "DS"
    mounted.mkdir(parents=True)
    escaped = str(mounted).replace(" ", "\\040")
    table = tmp_path / "mountinfo"
    table.write_text(
        "22 1 8:1 / / rw,relatime shared:1 - ext4 /dev/sda1 rw\n"
        f"95 22 8:1 /srv/ds {escaped} rw,relatime shared:1 - ext4 /dev/sda1 rw\n"
    )
    monkeypatch.setattr(preflight, "MOUNT_TABLE", table)
    with pytest.raises(DatasetError, match="a mount point"):
        preflight.check_out(mounted)
    preflight.check_out(mounted.parent)  # its parent is no mount point
    monkeypatch.setattr(preflight, "MOUNT_TABLE", tmp_path / "absent")  # not Linux
    preflight.check_out(mounted)
