"""dataset-build on a disk that refuses: one line naming the user's path, never a temporary."""

import errno
import os
import re
from pathlib import Path
from typing import Any

import pytest

from lenspair.cli import main
from lenspair.dataset import build as build_module
from lenspair.dataset import preflight as preflight_module
from lenspair.dataset.build import build_dataset
from lenspair.dataset.config import DatasetConfig
from tests.dataset.dataset_synth import RecordingFactory
from tests.file_limits import REFUSALS, refuse_writes, run_with_file_limit
from tests.processes import dead_pid


@pytest.mark.parametrize("code", REFUSALS)
def test_a_read_only_out_is_named_before_any_pair_is_measured(
    recording: RecordingFactory,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    code: int,
) -> None:
    """It named ``.DS.<pid>.<random>.building``, once every pair had been measured."""
    source = recording("rec_a", n=6)
    mounted = tmp_path / "mounted"
    mounted.mkdir()
    refuse_writes(monkeypatch, mounted, code)

    def measured(*args: object) -> None:
        raise AssertionError("a pair was measured before the refusal")

    monkeypatch.setattr(build_module, "measure_record", measured)
    out = mounted / "DS"
    assert main(["dataset-build", str(source), "--out", str(out)]) == 1
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line == f"lenspair dataset-build: error: {out}: {os.strerror(code)}"
    assert list(mounted.iterdir()) == []


@pytest.mark.parametrize("code", REFUSALS)
def test_a_refused_building_folder_is_named_as_the_dataset(
    recording: RecordingFactory, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, code: int
) -> None:
    """Past the early check (a disk remounted read-only mid-run), the same name."""
    source = recording("rec_a", n=6)
    mounted = tmp_path / "mounted"
    mounted.mkdir()
    monkeypatch.setattr(preflight_module, "check_writable", lambda out: None)
    refuse_writes(monkeypatch, mounted, code)
    with pytest.raises(OSError) as caught:
        build_dataset([source], mounted / "DS", DatasetConfig())
    assert (caught.value.errno, caught.value.strerror) == (code, os.strerror(code))
    assert (caught.value.filename, caught.value.filename2) == (str(mounted / "DS"), None)


def test_a_file_too_large_names_its_path_in_the_dataset_and_a_rerun_builds_it(
    recording: RecordingFactory, tmp_path: Path
) -> None:
    """It named ``source -> .DS.<pid>.<random>.building/train/input/<name>.png``."""
    source = recording("rec_a", n=6)
    smallest = min(p.stat().st_size for p in source.rglob("*.png"))
    out = tmp_path / "DS"
    failed = run_with_file_limit(["dataset-build", str(source), "--out", str(out)], smallest // 2)
    assert failed.returncode == 1, failed.stderr
    # one line, no traceback (after the warning that one recording cannot cover 3 splits)
    (line,) = [x for x in failed.stderr.splitlines() if not x.startswith("WARNING ")]
    # the manifest is written first (a rebuild is compared before images are copied)
    image = r"(train|val|test)/(input|target)/rec_a_[0-9]+\.png"
    pattern = rf"{re.escape(str(out))}/(manifest\.jsonl|{image})"
    assert re.fullmatch(rf"lenspair dataset-build: error: {pattern}: File too large", line), line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ingested"]  # nothing half-built
    assert main(["dataset-build", str(source), "--out", str(out)]) == 0
    assert (out / "dataset.json").is_file()


def test_a_killed_build_s_probe_is_a_leftover_of_its_output(
    recording: RecordingFactory, tmp_path: Path
) -> None:
    """The early check's empty temporary is named as the build's: a rerun removes it."""
    source = recording("rec_a", n=6)
    probe = tmp_path / f".DS.{dead_pid()}.abcdefgh.tmp"  # killed between making and removing it
    probe.write_bytes(b"")
    build_dataset([source], tmp_path / "DS", DatasetConfig())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["DS", "ingested"]


@pytest.mark.parametrize("code", [errno.EBUSY, errno.EXDEV])
def test_a_refused_rename_of_out_is_one_line_naming_it(
    recording: RecordingFactory,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    code: int,
) -> None:
    """A mount point the early check cannot see, renamed away in the swap: it was a traceback."""
    source = recording("rec_a", n=6)
    out = tmp_path / "DS"
    out.mkdir()
    real_replace = os.replace

    def replace(src: Any, dst: Any, **kwargs: Any) -> None:
        if Path(src) == out:  # as the kernel refuses to rename a mount point
            raise OSError(code, os.strerror(code), os.fsdecode(src), os.fsdecode(dst))
        real_replace(src, dst, **kwargs)

    monkeypatch.setattr(os, "replace", replace)
    assert main(["dataset-build", str(source), "--out", str(out)]) == 1
    lines = [x for x in capsys.readouterr().err.splitlines() if x.startswith("lenspair")]
    assert lines == [f"lenspair dataset-build: error: {out}: {os.strerror(code)}"]
    assert list(out.iterdir()) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["DS", "ingested"]  # no temporaries
