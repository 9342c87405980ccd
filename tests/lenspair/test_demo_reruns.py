"""Reruns of ``lenspair demo``: outputs changed by hand, two demos at once, stops and quoting."""

import argparse
import os
from pathlib import Path

import pytest

import lenspair.demo
import lenspair.demo_stages
from lenspair.cli import INTERRUPTED, main
from lenspair.commands.demo import interrupt_hint
from lenspair.core.folderlock import lock_file
from lenspair.demo import QUICK, run_demo
from lenspair.demo_stages import Stage, run_stage, run_stages
from lenspair.errors import DemoError
from tests.lenspair.demo_fakes import FakeCli, three_stages


def _stages(out: Path) -> list[Stage]:
    return three_stages(out, out / "rec")


def test_an_output_changed_by_hand_runs_its_stage_and_all_after_again(tmp_path: Path) -> None:
    """`cp runs/pretrain/checkpoints/best.pt runs/finetune/checkpoints/best.pt`, then a rerun:
    every stage was reused and the report showed the old figures."""
    stages = _stages(tmp_path)
    cli = FakeCli({s.argv[0]: s.output for s in stages})
    run_stages(tmp_path, stages, cli)
    assert all(t["reused"] for t in run_stages(tmp_path, stages, cli).values())

    (tmp_path / "ing" / "done").write_text("copied over by hand")
    (tmp_path / "ing" / "extra").write_text("added by hand")
    again = run_stages(tmp_path, stages, cli)
    assert cli.calls[3:] == ["ingest", "train"]
    assert again["simulate"]["reused"] and not again["ingest"]["reused"]
    assert not (tmp_path / "ing" / "extra").exists()  # not resumed: it was finished, then edited
    assert all(t["reused"] for t in run_stages(tmp_path, stages, cli).values())

    # the same size, only touched: still another file
    done = tmp_path / "run" / "done"
    status = done.stat()
    os.utime(done, ns=(status.st_atime_ns, status.st_mtime_ns + 1_000_000_000))
    assert not run_stages(tmp_path, stages, cli)["train"]["reused"]


def test_the_output_digest_sees_paths_sizes_and_times_and_reads_no_file(tmp_path: Path) -> None:
    folder = tmp_path / "run"
    (folder / "checkpoints").mkdir(parents=True)
    (folder / "checkpoints" / "best.pt").write_bytes(b"weights")
    before = lenspair.demo_stages.output_digest(folder)
    assert lenspair.demo_stages.output_digest(folder) == before
    (folder / "checkpoints" / "best.pt").rename(folder / "checkpoints" / "last.pt")
    assert lenspair.demo_stages.output_digest(folder) != before
    assert lenspair.demo_stages.output_digest(
        tmp_path / "missing"
    ) == lenspair.demo_stages.output_digest(tmp_path / "empty")
    # the lock a later stage's reader makes in it (train in DS) is no change of the output:
    # the whole demo ran again on every rerun
    after = lenspair.demo_stages.output_digest(folder)
    (folder / ".lenspair-dataset.lock").touch()
    assert lenspair.demo_stages.output_digest(folder) == after


def _fake_demo(monkeypatch: pytest.MonkeyPatch, out: Path, cli: object) -> list[Stage]:
    stages = _stages(out)
    monkeypatch.setattr(lenspair.demo, "plan", lambda out, budget: stages)
    monkeypatch.setattr(lenspair.demo, "cli_main", cli)
    monkeypatch.setattr(lenspair.demo, "write_report", lambda out, t, c: out / "report.md")
    return stages


def test_a_second_demo_into_the_same_folder_is_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Two demos into one OUT ran side by side; the second resumed the first's tradeoff."""
    out = tmp_path / "demo"
    cli = FakeCli({s.argv[0]: s.output for s in _stages(out)})
    _fake_demo(monkeypatch, out, cli)
    (out / ".stages").mkdir(parents=True)
    held = lock_file(out / ".stages" / ".lock", "the first demo")
    assert held is not None
    try:
        with pytest.raises(DemoError, match=r"^another demo is writing to .*demo$"):
            run_demo(out, QUICK)
        capsys.readouterr()
        assert main(["demo", "--out", str(out)]) != 0
        (line,) = capsys.readouterr().err.strip().splitlines()
        assert line == f"lenspair demo: error: another demo is writing to {out}"
        assert cli.calls == []
    finally:
        os.close(held)
    run_demo(out, QUICK)  # the first one done, the folder is free again
    assert cli.calls == ["simulate", "ingest", "train"]


def test_the_lock_is_held_for_the_whole_run_and_released_after(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "demo"
    cli = FakeCli({s.argv[0]: s.output for s in _stages(out)})
    free: list[bool] = []

    def probing(argv: list[str]) -> int:
        # flock holds per open file, so a second open in this process stands for a second demo
        probe = lock_file(out / ".stages" / ".lock", "a second demo")
        free.append(probe is not None)
        if probe is not None:
            os.close(probe)
        return cli(argv)

    _fake_demo(monkeypatch, out, probing)
    run_demo(out, QUICK)
    assert free == [False, False, False]
    held = lock_file(out / ".stages" / ".lock", "a test")
    assert held is not None
    os.close(held)


def test_a_demo_stopped_in_its_first_stage_can_be_resumed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Stopped in simulate, before any marker: the rerun said "holds files and no earlier demo"."""
    out = tmp_path / "demo"
    cli = FakeCli({s.argv[0]: s.output for s in _stages(out)})

    def stopped_in_simulate(argv: list[str]) -> int:
        cli(argv)  # some files written, then Ctrl-C
        return INTERRUPTED

    _fake_demo(monkeypatch, out, stopped_in_simulate)
    with pytest.raises(KeyboardInterrupt):
        run_demo(out, QUICK)
    assert (out / ".stages").is_dir() and any(out.iterdir())
    monkeypatch.setattr(lenspair.demo, "cli_main", cli)
    run_demo(out, QUICK)
    assert cli.calls == ["simulate", "simulate", "ingest", "train"]


def test_printed_commands_and_the_hint_are_shell_quoted(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """With OUT "my demo", the printed commands and the resume hint failed when pasted."""
    out = tmp_path / "my demo"
    stage = Stage("simulate", ("simulate", str(out / "rec")), out / "rec")
    run_stage(tmp_path, stage, FakeCli({"simulate": stage.output}))
    said = capsys.readouterr().err
    assert f"[simulate] lenspair simulate '{out / 'rec'}'" in said
    hint = interrupt_hint(argparse.Namespace(out=Path("my demo"), quick=True))
    assert (
        hint == "rerun lenspair demo --out 'my demo' --quick to resume from the stage it stopped in"
    )


def test_a_refused_folder_is_not_announced_as_written_to(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    project = tmp_path / "myproj"
    project.mkdir()
    (project / "notes.txt").write_text("mine")
    assert main(["demo", "--out", str(project)]) != 0
    said = capsys.readouterr()
    assert "writing to" not in said.out
    assert "holds files and no earlier demo" in said.err
    assert not (project / ".stages").exists()


def test_a_stopped_training_stage_resumes_instead_of_starting_over(tmp_path: Path) -> None:
    """Stopped in the fine-tune, the rerun trained from step 0 while train said "--resume"."""
    run = tmp_path / "run"
    train = Stage(
        "train",
        ("train", "DS", "--init", "best.pt", "--out", str(run)),
        run,
        resume_argv=("train", "DS", "--out", str(run), "--resume"),
        resume_file=run / "checkpoints" / "last.pt",
    )
    stages = [*_stages(tmp_path)[:2], train]
    cli = FakeCli({s.argv[0]: s.output for s in stages})
    argvs: list[list[str]] = []

    def stopped_in_train(argv: list[str]) -> int:
        argvs.append(argv)
        if argv[0] != "train":
            return cli(argv)
        (run / "checkpoints").mkdir(parents=True)
        (run / "checkpoints" / "last.pt").write_text("step 3")
        return INTERRUPTED

    with pytest.raises(KeyboardInterrupt):
        run_stages(tmp_path, stages, stopped_in_train)
    assert argvs[-1] == list(train.argv)

    def recording(argv: list[str]) -> int:
        argvs.append(argv)
        return cli(argv)

    timings = run_stages(tmp_path, stages, recording)
    assert argvs[-1] == list(train.resume_argv) and not timings["train"]["reused"]
    assert (run / "checkpoints" / "last.pt").read_text() == "step 3"  # kept, resumed from
    assert run_stages(tmp_path, stages, recording)["train"]["reused"]  # finished as itself

    # stopped again, then an earlier stage's input changed: start over, not resume
    (tmp_path / ".stages" / "train.json").unlink()
    with pytest.raises(KeyboardInterrupt):
        run_stages(tmp_path, stages, stopped_in_train)
    (tmp_path / "ing" / "done").write_text("edited")
    run_stages(tmp_path, stages, recording)
    assert argvs[-1] == list(train.argv)

    # a resume that fails (train refuses a damaged last.pt) is not tried again and again
    (tmp_path / ".stages" / "train.json").unlink()
    with pytest.raises(KeyboardInterrupt):
        run_stages(tmp_path, stages, stopped_in_train)
    with pytest.raises(DemoError, match="stage train failed"):
        run_stages(tmp_path, stages, lambda argv: 2 if "--resume" in argv else cli(argv))
    run_stages(tmp_path, stages, recording)
    assert argvs[-1] == list(train.argv)


def test_the_demo_training_stages_resume_without_init(tmp_path: Path) -> None:
    training = [s for s in lenspair.demo.plan(tmp_path, QUICK) if s.argv[0] == "train"]
    assert [s.name for s in training] == ["pretrain", "finetune"]
    for stage in training:
        assert stage.resume_argv[-1] == "--resume" and "--init" not in stage.resume_argv
        assert stage.resume_file == stage.output / "checkpoints" / "last.pt"
