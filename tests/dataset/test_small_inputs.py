"""Small inputs: a dataset with empty splits still trains and evaluates, as --help says."""

from pathlib import Path

import pytest
import torch

from lenspair.cli import main
from lenspair.core.config import dump_yaml
from lenspair.dataset.card import read_card
from tests.dataset.dataset_synth import RecordingFactory
from tests.model.train_fixtures import tiny_config


@pytest.fixture
def one_thread() -> object:
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.mark.usefixtures("one_thread")
def test_two_short_recordings_train_and_evaluate_with_clear_messages(
    recording: RecordingFactory, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sources = [recording("rec_a", n=6), recording("rec_b", n=6, seed=1)]
    ds = tmp_path / "DS"
    assert main(["dataset-build", *map(str, sources), "--out", str(ds)]) == 0
    counts = read_card(ds / "dataset.json").counts
    empty = [name for name in ("val", "test") if counts[name].pairs == 0]
    assert empty, "the case under test: a split left empty by too few groups"
    built = capsys.readouterr().out
    for name in empty:
        assert f"split {name!r} is empty" in built

    config = tmp_path / "tiny.yaml"
    config.write_text(dump_yaml(tiny_config(max_steps=1)))
    run = tmp_path / "run"
    code = main(["train", str(ds), "--out", str(run), "--config", str(config), "--device", "cpu"])
    assert code == 0, capsys.readouterr().err  # --help: "a deterministic tenth is held out"
    capsys.readouterr()

    checkpoint = str(run / "checkpoints" / "best.pt")
    code = main(
        ["eval", checkpoint, "--data", str(ds), "--split", empty[-1], "--latency-runs", "0"]
    )
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(lines) == 1
    assert repr(empty[-1]) in lines[0] or f"/{empty[-1]}" in lines[0]
