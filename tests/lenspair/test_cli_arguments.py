"""Argument errors of the command line: who is blamed, and output paths refused up front."""

import argparse
import os
from pathlib import Path

import pytest

from lenspair.cli import main
from lenspair.commands.argtypes import out_file, out_folder


def _refused(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """The one stderr line of ``lenspair ARGV``, which must exit with code 2."""
    with pytest.raises(SystemExit) as exited:
        main(argv)
    assert exited.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    return lines[0]


def test_an_unknown_option_of_a_command_names_the_command(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["capture-ingest", str(tmp_path), "--out", str(tmp_path / "ing"), "--threads", "2"]
    assert _refused(argv, capsys) == (
        "lenspair capture-ingest: error: unrecognized arguments: --threads 2; "
        "see 'lenspair capture-ingest --help'"
    )


def test_an_unknown_option_before_the_command_names_lenspair(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["--bogus", "capture-ingest", str(tmp_path), "--out", str(tmp_path / "ing")]
    assert _refused(argv, capsys) == (
        "lenspair: error: unrecognized arguments: --bogus; see 'lenspair --help'"
    )


@pytest.fixture
def dangling(tmp_path: Path) -> Path:
    """A symbolic link to a folder on a disk that is not mounted."""
    link = tmp_path / "dangling"
    link.symlink_to(tmp_path / "unmounted" / "run")
    return link


@pytest.mark.parametrize(
    "argv",
    [
        ["simulate", "rain", "--frames", "2", "--out", "LINK"],
        ["eval", "best.pt", "--out", "LINK"],
        ["train", "--synthetic", "clear", "--out", "LINK/run"],
    ],
    ids=["simulate", "eval", "inside-a-link"],
)
def test_a_dangling_link_as_out_is_refused_before_any_work(
    argv: list[str], dangling: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    line = _refused([a.replace("LINK", str(dangling)) for a in argv], capsys)
    assert f"lenspair {argv[0]}: error: argument --out: " in line
    assert f"a symbolic link to {dangling.parent / 'unmounted' / 'run'}, which does not " in line


def test_the_file_types_refuse_a_dangling_link_too(dangling: Path) -> None:
    with pytest.raises(argparse.ArgumentTypeError, match=r"symbolic link to .*not mounted"):
        out_file(str(dangling))
    with pytest.raises(argparse.ArgumentTypeError, match="dangling' is a symbolic link"):
        out_file(str(dangling / "model.onnx"))
    assert out_folder(str(dangling.parent / "new")) == dangling.parent / "new"


def test_capture_ingest_refuses_a_device_without_a_detector(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # --device places only --detector's network: without one it was ignored, exit 0
    argv = ["capture-ingest", str(tmp_path / "rec"), "--out", str(tmp_path / "ing")]
    assert main([*argv, "--device", "cpu"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "--device cpu places the side check's detector: give --detector MODEL" in line
    assert not (tmp_path / "ing").exists()


@pytest.mark.parametrize(
    ("argv", "denied"),
    [
        (["capture-ingest", "REC", "--out", "OUT"], "REC"),
        (["eval", "CK", "--data", "REC", "--out", "OUT"], "CK"),
        (["restore", "CK", "REC", "--out", "OUT"], "REC"),
        (["capture-ingest", "REC", "--detector", "CK", "--out", "OUT"], "CK"),
    ],
    ids=["recording", "checkpoint", "restore-input", "detector"],
)
def test_an_input_this_user_may_not_read_is_refused_as_such(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    argv: list[str],
    denied: str,
) -> None:
    # a chmod 000 recording was "noperm/metadata.yaml: Permission denied", exit 1 (the code of
    # a refused write), naming a probe file the recording never had; a checkpoint was "not a
    # readable torch file", as if damaged. Tests run as root, whom nothing is denied: the
    # permission check is what answers no here
    paths = {"REC": tmp_path / "rec", "CK": tmp_path / "ck.pt", "OUT": tmp_path / "out"}
    paths["REC"].mkdir()
    paths["CK"].write_bytes(b"weights")
    refused = paths[denied]
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: Path(p) != refused and real_access(p, mode))
    line = _refused([str(paths.get(a, a)) for a in argv], capsys)
    kind = "folder" if refused.is_dir() else "file"
    assert f"'{refused}': permission denied (this user may not read the {kind})" in line
    assert line.startswith(f"lenspair {argv[0]}: error: argument ")
    assert not paths["OUT"].exists()


def test_a_file_name_ending_in_a_slash_is_refused(tmp_path: Path) -> None:
    # Path drops the slash: realism --json DIR/ wrote a file named DIR
    with pytest.raises(argparse.ArgumentTypeError, match="names a folder"):
        out_file(f"{tmp_path / 'new'}/")
    assert not (tmp_path / "new").exists()
    assert out_file(str(tmp_path / "new.json")) == tmp_path / "new.json"
