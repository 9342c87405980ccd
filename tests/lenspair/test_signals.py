"""SIGTERM (docker stop, systemd, a ROS launch shutting down) ends a command as Ctrl-C does."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lenspair.cli import INTERRUPTED, TERMINATED, Terminated, _sigterm_as_interrupt, main

SAMPLES = Path(__file__).resolve().parents[2] / "calib_samples"


def test_sigterm_is_raised_as_an_interrupt_and_the_handler_is_put_back() -> None:
    before = signal.getsignal(signal.SIGTERM)
    if before is not signal.SIG_DFL:
        pytest.skip("the test runner handles SIGTERM itself")
    with pytest.raises(Terminated), _sigterm_as_interrupt():
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # the handler raises at the next bytecode: never reached
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
    assert issubclass(Terminated, KeyboardInterrupt)  # every Ctrl-C clean-up runs for it


def test_a_command_stopped_by_sigterm_says_so_and_exits_143(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    import lenspair.commands.simulate

    if signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
        pytest.skip("the test runner handles SIGTERM itself")

    def stopped(args: object) -> int:
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)
        return 0

    monkeypatch.setattr(lenspair.commands.simulate, "run", stopped)
    argv = ["simulate", str(SAMPLES / "rain.yaml"), "--out", str(tmp_path / "rec")]
    assert main(argv) == TERMINATED
    said = capsys.readouterr().err.strip().splitlines()[-1]
    assert said.startswith("lenspair simulate: terminated; ")


def test_the_handler_is_left_to_torchrun_with_several_processes(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    if signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
        pytest.skip("the test runner handles SIGTERM itself")
    monkeypatch.setenv("WORLD_SIZE", "2")  # torchrun stops every rank with SIGTERM
    with _sigterm_as_interrupt():
        assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL


def test_sigterm_mid_simulation_ends_the_process_cleanly(tmp_path: Path) -> None:
    out = tmp_path / "rec"
    command = [sys.executable, "-m", "lenspair", "simulate", str(SAMPLES / "rain.yaml")]
    process = subprocess.Popen(
        [*command, "--out", str(out), "--frames", "400"],
        env={**os.environ, "LENSPAIR_QUIET": "1", "OMP_NUM_THREADS": "1"},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    frames = out / "mav0" / "cam0" / "data"
    deadline = time.monotonic() + 120
    while process.poll() is None and time.monotonic() < deadline:
        if frames.is_dir() and any(frames.iterdir()):
            break
        time.sleep(0.05)
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=60)
    # it died on the spot (-15), with no word of how to go on
    assert process.returncode == TERMINATED
    assert stderr.strip().splitlines()[-1].startswith("lenspair simulate: terminated; ")


def test_other_libraries_info_lines_stay_out_of_a_commands_output(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """Every library logged at INFO: torch's "FakeTensor cache stats" came after an
    interrupted run's last line. lenspair's own INFO lines stay; -v shows everything."""
    import logging

    from lenspair.commands import simulate

    def chatty(args: object) -> int:
        logging.getLogger("a_library.module").info("FakeTensor cache stats")
        logging.getLogger("a_library.module").warning("a library's warning")
        logging.getLogger("lenspair.simulate.recording").info("lenspair's own line")
        return 0

    monkeypatch.setattr(simulate, "run", chatty)
    root, package = logging.getLogger(), logging.getLogger("lenspair")
    monkeypatch.setattr(root, "level", root.level)  # put back after the test
    monkeypatch.setattr(package, "level", package.level)
    assert main(["simulate", "rain", "--out", "unused"]) == 0
    said = [r.getMessage() for r in caplog.records]
    assert said == ["a library's warning", "lenspair's own line"]
    caplog.clear()
    assert main(["-v", "simulate", "rain", "--out", "unused"]) == 0
    assert "FakeTensor cache stats" in [r.getMessage() for r in caplog.records]


def test_an_interruption_after_a_bar_starts_its_own_line_in_a_log_file(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # in a log file (not a terminal) the message continued the bar's last line:
    # "...14/38 [00:04<00:09, 2.56frame/s]lenspair restore: terminated; ..."
    import lenspair.commands.simulate as command
    from lenspair.core import progress

    def interrupted(args: object) -> int:
        for _ in progress.progress(range(3), "rendering"):
            pass
        raise KeyboardInterrupt

    monkeypatch.setattr(progress, "_SHOWN", [])
    monkeypatch.setattr(command, "run", interrupted)
    said = "lenspair simulate: interrupted; a rerun renders the recording again from its start\n"
    monkeypatch.setenv("LENSPAIR_QUIET", "1")  # no bar shown, no line to end
    assert main(["simulate", "rain", "--out", "unused"]) == INTERRUPTED
    assert capsys.readouterr().err == said
    monkeypatch.setenv("LENSPAIR_QUIET", "")
    assert main(["simulate", "rain", "--out", "unused"]) == INTERRUPTED
    err = capsys.readouterr().err
    assert "rendering" in err and err.endswith(f"\n{said}")


@pytest.mark.parametrize("failure", ["user error", "full disk"])
def test_an_error_after_a_bar_starts_its_own_line_in_a_log_file(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], failure: str
) -> None:
    # "...| 2/12 [00:02<00:12, 1.25s/frame]lenspair restore: error: rs_full/...png: the file
    # system cut the write short": only an interruption ended the bar's line
    import errno

    import lenspair.commands.simulate as command
    from lenspair.core import progress
    from lenspair.core.errors import ConfigError

    def failing(args: object) -> int:
        for _ in progress.progress(range(3), "rendering"):
            pass
        if failure == "full disk":
            raise OSError(errno.ENOSPC, "No space left on device", "out/frame.png")
        raise ConfigError("out/frame.png: cannot be written")

    monkeypatch.setattr(progress, "_SHOWN", [])
    monkeypatch.setattr(command, "run", failing)
    monkeypatch.setenv("LENSPAIR_QUIET", "")
    assert main(["simulate", "rain", "--out", "unused"]) in (1, 2)
    err = capsys.readouterr().err
    assert "rendering" in err
    last = err.rstrip("\n").split("\n")[-1]
    assert last.startswith("lenspair simulate: error: out/frame.png: ")
