"""benchmarks.table2 builds the demo's dataset with the split it is asked for."""

from pathlib import Path

import pytest

from benchmarks import table2
from lenspair.demo import Stage


@pytest.mark.parametrize(("splits", "expected"), [(None, "0.7,0.15,0.15"), ("0.6,0.15,0.25", None)])
def test_dataset_stages_stop_at_dataset_build_with_the_splits_asked(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, splits: str | None, expected: str | None
) -> None:
    ran: list[Stage] = []
    monkeypatch.setattr(table2, "run_stages", lambda out, stages, cli: ran.extend(stages))
    dataset = table2._dataset(tmp_path, frames=24, splits=splits)
    assert ran[-1].name == "dataset-build" and dataset == ran[-1].output
    argv = ran[-1].argv
    assert argv[argv.index("--splits") + 1] == (expected or splits)
    assert "segment_frames: 2" in (tmp_path / "demo" / "dataset_config.yaml").read_text()


def test_training_time_is_read_from_the_runs_themselves(tmp_path: Path) -> None:
    # a rerun that scored reused runs said "0.9 min wall clock in all" for an hour of training
    from lenspair.model.training.run_files import write_metrics_rows

    rows = [
        {"epoch": "1", "step": "10", "seconds": "12.5"},
        {"epoch": "2", "step": "20", "seconds": "30.0"},
    ]
    (tmp_path / "run").mkdir()
    write_metrics_rows(tmp_path / "run" / "metrics.csv", rows)  # type: ignore[arg-type]
    assert table2._training_seconds(tmp_path / "run") == 30.0
    assert table2._training_seconds(tmp_path / "never_trained") == 0.0


def test_data_only_builds_the_dataset_and_trains_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # `make tradeoff-seeds` trains on Table 2's dataset without Table 2's hour of training
    ran: list[Stage] = []
    monkeypatch.setattr(table2, "run_stages", lambda out, stages, cli: ran.extend(stages))
    monkeypatch.setattr(table2, "_parallel", lambda *args: pytest.fail("trained"))
    argv = ["--out", str(tmp_path), "--frames", "24", "--splits", "0.6,0.15,0.25", "--data-only"]
    assert table2.main(argv) == 0
    assert capsys.readouterr().out.strip() == str(ran[-1].output)
    assert ran[-1].name == "dataset-build"
