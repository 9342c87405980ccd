"""Argument errors of the command line: who is blamed, and output paths refused up front."""

import argparse
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
