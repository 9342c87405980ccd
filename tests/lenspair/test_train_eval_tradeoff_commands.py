"""Help texts and option checks of ``lenspair train``, ``eval``, ``tradeoff`` and ``restore``."""

import re
from pathlib import Path

import pytest
import torch

from lenspair.cli import main
from lenspair.model.precision import Hardware, choose_precision


def _help(command: str, capsys: pytest.CaptureFixture[str]) -> str:
    with pytest.raises(SystemExit) as exited:
        main([command, "--help"])
    assert exited.value.code == 0
    return " ".join(capsys.readouterr().out.split())  # one line: wrapping aside


def test_help_says_what_auto_picks_on_cuda(capsys: pytest.CaptureFixture[str]) -> None:
    h100 = Hardware("cuda", "NVIDIA H100", cuda_capability=(9, 0))
    for task in ("train", "infer"):
        decision = choose_precision("auto", torch.device("cuda"), task, lambda _: h100)
        assert decision.precision == "fp32"  # what the help texts below must say
    for command in ("train", "eval", "tradeoff", "export", "restore"):
        text = _help(command, capsys)
        # every sentence or clause that says what auto does on CUDA says fp32
        for clause in re.split(r"(?<=[.;])\s+", text):
            if re.search(r"\bauto\b", clause) and "CUDA" in clause:
                assert "fp32 on CUDA" in clause, (command, clause)
        if command in ("train", "eval", "restore"):  # the ones that explain auto
            assert "fp32 on CUDA" in text, command


@pytest.mark.parametrize("option", ["--crop-size", "--batch-size"])
@pytest.mark.parametrize("value", ["0", "-1"])
def test_tradeoff_rejects_a_crop_or_batch_below_one(
    option: str, value: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["tradeoff", str(tmp_path / "missing"), "--out", str(tmp_path / "out")]
    with pytest.raises(SystemExit) as exited:
        main([*argv, option, value])
    assert exited.value.code == 2
    [line] = capsys.readouterr().err.strip().splitlines()
    assert option in line and value in line
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("option", ["--batch-size", "--crop-size", "--max-steps", "--epochs"])
def test_train_names_the_option_of_a_count_below_one(
    option: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # "error: batch_size: expected >= 1, got 0" named the config key, not the option
    argv = ["train", str(tmp_path / "ds"), "--out", str(tmp_path / "run"), option, "0"]
    with pytest.raises(SystemExit) as exited:
        main(argv)
    assert exited.value.code == 2
    assert f"argument {option}: expected a positive integer, got '0'" in capsys.readouterr().err


def test_tradeoff_refuses_a_variant_named_twice(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # G,G trained and scored G twice: two rows, one "dominated" by its own copy
    argv = ["tradeoff", str(tmp_path / "ds"), "--out", str(tmp_path / "out")]
    assert main([*argv, "--variants", "G,GEA,G"]) == 2
    [line] = capsys.readouterr().err.strip().splitlines()
    assert line.endswith("--variants: G named twice")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("command", "hint"),
    [
        ("restore", "--resume"),
        ("eval", "nothing was written; rerun to evaluate again"),  # it said "rerun to resume"
        ("detect", "nothing was written; rerun to judge the frames again"),
        ("export", "files without m.onnx.export.json are unfinished"),
        ("simulate", "renders the recording again"),  # neither resumes: not "rerun to resume"
        ("calibrate", "nothing was written"),  # was said of both
    ],
)
def test_ctrl_c_says_how_to_continue(
    command: str, hint: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import importlib

    from lenspair import cli

    def interrupted(args: object) -> int:
        raise KeyboardInterrupt

    monkeypatch.setattr(importlib.import_module(cli.COMMANDS[command][0]), "run", interrupted)
    argv = {
        "restore": ["restore", "m.pt", "in", "--out", "o"],
        "eval": ["eval", "m.pt"],
        "detect": ["detect", "d.pt", "in"],
        "export": ["export", "m.pt", "--onnx", "m.onnx"],
        "simulate": ["simulate", "rain", "--out", "o"],
        "calibrate": [
            "calibrate",
            "rec",
            "--board",
            "chessboard:9x6:0.06",
            "--out",
            "c.yaml",
            "--model",
            "pinhole-equi",
        ],
    }[command]
    assert cli.main(argv) == 130
    assert hint in capsys.readouterr().err


def test_ctrl_c_while_the_command_loads_is_one_line(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # the first fraction of a second goes to importing numpy, OpenCV and torch
    from lenspair import cli

    def interrupted(name: str) -> object:
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "_load", interrupted)
    assert cli.main(["capture-ingest", "rec", "--out", "o"]) == 130
    assert capsys.readouterr().err == "lenspair capture-ingest: interrupted\n"


def test_ctrl_c_before_train_saved_anything_does_not_advise_resume(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import importlib

    from lenspair import cli

    def interrupted(args: object) -> int:
        raise KeyboardInterrupt

    monkeypatch.setattr(importlib.import_module(cli.COMMANDS["train"][0]), "run", interrupted)
    run = tmp_path / "run"
    argv = ["train", "DS", "--out", str(run)]
    assert cli.main(argv) == 130
    err = capsys.readouterr().err
    assert "--resume" not in err and "rerun the same command" in err  # --resume said "no run"
    run.mkdir()
    (run / "config.yaml").write_text("model: {}\n")  # a run has begun: --resume continues it
    assert cli.main(argv) == 130
    assert "rerun with --resume to continue" in capsys.readouterr().err


def test_the_cli_module_runs_as_a_script() -> None:
    """``python -m lenspair.cli`` (as ``torchrun -m`` runs it) did nothing and exited 0."""
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "-m", "lenspair.cli", "no-such-command"], capture_output=True, text=True
    )
    assert done.returncode == 2 and "no-such-command" in done.stderr


def test_lenspair_help_lists_the_exit_codes_commands_return(
    capsys: pytest.CaptureFixture[str],
) -> None:
    # only capture-ingest's help named any; dataset-build --verify's 1 clashed with the
    # README's "1: a file system refusal" unsaid
    from lenspair.cli import INTERRUPTED, TERMINATED

    with pytest.raises(SystemExit):
        main(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    for said in (
        "0 done",
        "2 a user error",
        "1 the file system refused a write",
        "or dataset-build --verify found problems",
        f"{INTERRUPTED} after Ctrl-C",
        f"{TERMINATED} after SIGTERM",
    ):
        assert said in text, said
