"""Stage reuse of ``lenspair demo``: what is finished is reused, what changed runs again."""

from pathlib import Path

import pytest

from lenspair.core.samples import sample_path
from lenspair.demo import QUICK, board_arguments, run_demo
from lenspair.demo_stages import Stage, run_stages
from lenspair.errors import DemoError
from lenspair.rectify.boards import parse_board_spec
from lenspair.rectify.calib_types import MODELS
from lenspair.simulate.spec import load_scene
from tests.lenspair.demo_fakes import FakeCli, three_stages


def _stages(tmp_path: Path, spec: Path) -> list[Stage]:
    return three_stages(tmp_path, spec)


def test_rerun_reuses_and_an_edited_input_reruns_its_stage_and_all_after(tmp_path: Path) -> None:
    spec = tmp_path / "scene.yaml"
    spec.write_text("frames: 10\n")
    stages = _stages(tmp_path, spec)
    cli = FakeCli({s.argv[0]: s.output for s in stages})
    first = run_stages(tmp_path, stages, cli)
    assert cli.calls == ["simulate", "ingest", "train"]
    assert not any(t["reused"] for t in first.values())

    second = run_stages(tmp_path, stages, cli)
    assert cli.calls == ["simulate", "ingest", "train"]  # nothing ran again
    assert all(t["reused"] for t in second.values())

    # a stale file in the resumable stage's output must not survive a changed input
    (tmp_path / "ing" / "stale").write_text("from the old recording")
    spec.write_text("frames: 12\n")
    third = run_stages(tmp_path, stages, cli)
    assert cli.calls[3:] == ["simulate", "ingest", "train"]
    assert not any(t["reused"] for t in third.values())
    assert not (tmp_path / "ing" / "stale").exists()


def test_an_unfinished_resumable_stage_resumes_and_later_stages_run(tmp_path: Path) -> None:
    spec = tmp_path / "scene.yaml"
    spec.write_text("frames: 10\n")
    stages = _stages(tmp_path, spec)
    cli = FakeCli({s.argv[0]: s.output for s in stages})
    run_stages(tmp_path, stages, cli)
    (tmp_path / ".stages" / "ingest.json").unlink()  # as if interrupted during ingest
    (tmp_path / "ing" / "partial").write_text("pairs so far")
    timings = run_stages(tmp_path, stages, cli)
    assert cli.calls[3:] == ["ingest", "train"]
    assert timings["simulate"]["reused"] and not timings["ingest"]["reused"]
    assert (tmp_path / "ing" / "partial").is_file()  # resumed, not wiped


def test_the_stages_that_resume_their_own_work_keep_it_after_a_stop(tmp_path: Path) -> None:
    # Ctrl-C in the tradeoff: the rerun deleted its finished variants and trained them again,
    # while the demo's hint promised to resume; capture-ingest and tradeoff both reuse what
    # they finished (and replace what changed), so their outputs are kept for them
    from lenspair.demo import plan

    resumable = {stage.argv[0] for stage in plan(tmp_path, QUICK) if stage.resumable}
    assert resumable == {"capture-ingest", "tradeoff"}


def test_a_stage_stopped_while_it_ran_again_is_not_reused_nor_are_those_after(
    tmp_path: Path,
) -> None:
    # a finished demo; then ingest's output removed and the rerun killed in train: the old
    # markers of train (and of any stage after it) stayed beside a partial output, and the
    # next rerun reused them ("train: reused", the report said "No tradeoff.")
    spec = tmp_path / "scene.yaml"
    spec.write_text("frames: 10\n")
    stages = _stages(tmp_path, spec)
    cli = FakeCli({s.argv[0]: s.output for s in stages})
    run_stages(tmp_path, stages, cli)
    (tmp_path / ".stages" / "ingest.json").unlink()

    def killed_in_train(argv: list[str]) -> int:
        if argv[0] == "train":
            raise SystemExit("killed")  # as kill -9 ends the process, no code returned
        return cli(argv)

    with pytest.raises(SystemExit):
        run_stages(tmp_path, stages, killed_in_train)
    assert not (tmp_path / ".stages" / "train.json").exists()
    timings = run_stages(tmp_path, stages, cli)
    assert timings["ingest"]["reused"] and not timings["train"]["reused"]
    assert cli.calls[-1] == "train"
    # killed after ingest ran again but before train started: train read the old ingest
    (tmp_path / ".stages" / "ingest.json").unlink()

    def killed_before_train(argv: list[str]) -> int:
        code = cli(argv)
        if argv[0] == "ingest":
            raise SystemExit("killed")  # ingest done, its marker not yet written
        return code

    with pytest.raises(SystemExit):
        run_stages(tmp_path, stages, killed_before_train)
    assert not (tmp_path / ".stages" / "train.json").exists()
    timings = run_stages(tmp_path, stages, cli)
    assert not timings["train"]["reused"]


def test_ctrl_c_in_a_stage_stops_the_demo_as_interrupted_not_failed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import lenspair.demo
    from lenspair.cli import INTERRUPTED, main

    spec = tmp_path / "scene.yaml"
    spec.write_text("frames: 10\n")
    stages = _stages(tmp_path, spec)
    cli = FakeCli({s.argv[0]: s.output for s in stages})

    def stopped_in_ingest(argv: list[str]) -> int:
        return INTERRUPTED if argv[0] == "ingest" else cli(argv)

    with pytest.raises(KeyboardInterrupt):  # was DemoError "stage ingest failed (exit code 130)"
        run_stages(tmp_path, stages, stopped_in_ingest)
    assert cli.calls == ["simulate"] and not (tmp_path / ".stages" / "ingest.json").exists()
    monkeypatch.setattr(lenspair.demo, "plan", lambda out, budget: stages)
    monkeypatch.setattr(lenspair.demo, "cli_main", stopped_in_ingest)
    capsys.readouterr()
    assert main(["demo", "--out", str(tmp_path / "demo")]) == INTERRUPTED
    said = capsys.readouterr().err.strip().splitlines()[-1]
    assert said.startswith("lenspair demo: interrupted; rerun lenspair demo --out")
    assert "failed" not in said


@pytest.mark.parametrize("given", ["w/rev-readme/demo", "ABSOLUTE", "my demo"])
def test_the_report_quotes_out_as_given(
    given: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # `--out /tmp/w/rev-readme/demo` was reported as "lenspair demo --out demo --quick"
    import lenspair.demo

    out = str(tmp_path / "w" / "demo") if given == "ABSOLUTE" else given
    commands: list[str] = []

    def report(out: Path, timings: object, command: str) -> Path:
        commands.append(command)
        return out / "report.md"

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(lenspair.demo, "run_stages", lambda out, stages, cli: {})
    monkeypatch.setattr(lenspair.demo, "write_report", report)
    run_demo(Path(out), QUICK)
    quoted = "'my demo'" if given == "my demo" else out
    assert commands == [f"lenspair demo --out {quoted} --quick"]


@pytest.mark.parametrize("scene", ["chessboard.yaml", "charuco.yaml"])
def test_demo_calibrates_with_the_board_the_simulator_drew(scene: str) -> None:
    flag_board, board, flag_model, model = board_arguments(scene)
    spec = load_scene(sample_path(scene))
    assert spec.board is not None and (flag_board, flag_model) == ("--board", "--model")
    assert parse_board_spec(board) == spec.board.target
    assert MODELS[model] == spec.rig.cam0.distortion_model


def test_a_scene_without_a_board_is_a_demo_error() -> None:
    with pytest.raises(DemoError, match=r"rain\.yaml: the sample scene has no board"):
        board_arguments("rain.yaml")


@pytest.mark.parametrize(
    ("first", "second"),
    [
        # bf16 emulated on the second machine (another CPU, or ONEDNN_MAX_CPU_ISA)
        ((("bf16", "fp32"), 1.8), (("fp32",), 1.8)),
        # the same flags, but a CPU whose bf16 runs slower than fp32 (AMX hidden)
        ((("bf16", "fp32"), 1.8), (("bf16", "fp32"), 0.6)),
    ],
)
def test_a_machine_where_auto_trains_at_another_precision_reruns_the_training_stages(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    first: tuple[tuple[str, ...], float],
    second: tuple[tuple[str, ...], float],
) -> None:
    from lenspair.model import precision

    def machine(native: tuple[str, ...], bf16_speed: float) -> None:
        monkeypatch.setattr(precision, "native_precisions", lambda hardware: native)
        monkeypatch.setattr(precision, "measure_bf16_speed", lambda task: bf16_speed)

    spec = tmp_path / "scene.yaml"
    spec.write_text("frames: 10\n")
    stages = _stages(tmp_path, spec)
    cli = FakeCli({s.argv[0]: s.output for s in stages})
    machine(*first)
    run_stages(tmp_path, stages, cli)
    # auto trains at fp32 on the second machine: the bf16 results must not be reused;
    # the recording may be
    machine(*second)
    again = run_stages(tmp_path, stages, cli)
    assert cli.calls == ["simulate", "ingest", "train", "train"]
    assert again["simulate"]["reused"] and again["ingest"]["reused"]
    assert not again["train"]["reused"]
    assert run_stages(tmp_path, stages, cli)["train"]["reused"]  # the same machine: reused


def test_a_folder_of_the_users_own_is_refused_never_emptied(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`--out myproj` deleted the project's own eval/ and recordings/ (a stage removes its
    output before it runs) without a word."""
    import lenspair.demo

    ran: list[Path] = []
    monkeypatch.setattr(lenspair.demo, "run_stages", lambda out, s, cli: ran.append(out) or {})
    monkeypatch.setattr(lenspair.demo, "write_report", lambda out, t, c: out / "report.md")
    project = tmp_path / "myproj"
    (project / "eval").mkdir(parents=True)
    (project / "eval" / "results.txt").write_text("precious")
    with pytest.raises(DemoError, match=r"holds files and no earlier demo \(no \.stages/\)"):
        run_demo(project, QUICK)
    assert (project / "eval" / "results.txt").read_text() == "precious" and not ran
    # a new, an empty, or an earlier demo's folder is the demo's to write
    (tmp_path / "empty").mkdir()
    (project / ".stages").mkdir()
    for out in (tmp_path / "new", tmp_path / "empty", project):
        run_demo(out, QUICK)
    assert ran == [tmp_path / "new", tmp_path / "empty", project]


def test_a_stage_that_runs_again_takes_the_old_report_with_it(tmp_path: Path) -> None:
    """Stopped after its first stage ran again, a rerun left the earlier report.md beside
    outputs already replaced, every stage in it marked reused."""
    spec = tmp_path / "scene.yaml"
    spec.write_text("frames: 10\n")
    stages = _stages(tmp_path, spec)
    cli = FakeCli({s.argv[0]: s.output for s in stages})
    run_stages(tmp_path, stages, cli)
    for name in ("report.md", "report.html", "timings.json"):
        (tmp_path / name).write_text("the earlier run's")
    run_stages(tmp_path, stages, cli)  # all reused: the report stays
    assert (tmp_path / "report.md").read_text() == "the earlier run's"
    spec.write_text("frames: 12\n")
    run_stages(tmp_path, stages, cli)
    assert not any((tmp_path / n).exists() for n in ("report.md", "report.html", "timings.json"))
    # a damaged marker (a full disk, an edit) reads as an unfinished stage, not a traceback
    (tmp_path / ".stages" / "train.json").write_text("")
    again = run_stages(tmp_path, stages, cli)
    assert again["train"]["reused"] is False and cli.calls[-1] == "train"


def test_a_rerun_report_says_which_time_is_this_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A rerun of 1.6 s reported "Total 1.5 min": the reused stages' seconds were the
    earlier run's, added up as this run's."""
    from lenspair import demo_report

    monkeypatch.setattr(demo_report, "finetune_runtime", lambda out: None)
    timings = {
        "simulate": {"seconds": 60.0, "reused": True},
        "train": {"seconds": 30.0, "reused": False},
    }
    (text,) = [b.text for b in demo_report.machine_blocks(tmp_path, timings)]  # type: ignore[attr-defined]
    assert "Total 1.5 min of stage time on " in text
    assert "1 of 2 stages were reused from an earlier run (their seconds are that run's)" in text
    assert text.endswith("this run spent 0.5 min.")
    fresh = {k: {**v, "reused": False} for k, v in timings.items()}
    (text,) = [b.text for b in demo_report.machine_blocks(tmp_path, fresh)]  # type: ignore[attr-defined]
    assert text.startswith("Total 1.5 min on ") and "reused" not in text
