import json
from pathlib import Path

import pytest

from lenspair.cli import main
from lenspair.dataset.build import build_dataset
from lenspair.dataset.config import DatasetConfig, SplitConfig
from lenspair.dataset.errors import DatasetError
from lenspair.dataset.manifest import read_manifest
from lenspair.dataset.verify import verify_dataset
from tests.dataset.dataset_synth import RecordingFactory


@pytest.fixture
def ds(recording: RecordingFactory, tmp_path: Path) -> Path:
    sources = [
        recording("rec_a", n=12, masked=True),
        recording("rec_b", n=12, obstructed="cam0", seed=1),
    ]
    config = DatasetConfig(split=SplitConfig(segment_frames=4, segment_gap_frames=1))
    return build_dataset(sources, tmp_path / "DS", config).out


def test_intact_dataset_verifies(ds: Path, capsys: pytest.CaptureFixture[str]) -> None:
    result = verify_dataset(ds)
    assert (
        result.ok
        and result.pairs > 10
        and result.files
        == 3 * sum(1 for r in read_manifest(ds / "manifest.jsonl") if r.recording == "rec_a")
        + 2 * sum(1 for r in read_manifest(ds / "manifest.jsonl") if r.recording == "rec_b")
    )
    assert main(["dataset-build", "--verify", str(ds)]) == 0
    assert "OK" in capsys.readouterr().out


def test_missing_changed_and_extra_files_are_listed(
    ds: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rows = read_manifest(ds / "manifest.jsonl")
    missing = ds / rows[0].files["target"]
    missing.unlink()
    changed = ds / rows[1].files["input"]
    data = changed.read_bytes()
    changed.write_bytes(data[:-1] + bytes([data[-1] ^ 1]))
    extra = ds / rows[2].split / "input" / "stray.png"
    extra.write_bytes(b"x")
    problems = verify_dataset(ds).problems
    assert f"{missing}: missing (listed in manifest.jsonl)" in problems
    assert any(p.startswith(f"{changed}: sha256 mismatch") for p in problems)
    assert f"{extra}: not listed in manifest.jsonl" in problems
    assert main(["dataset-build", "--verify", str(ds)]) == 1
    out = capsys.readouterr().out
    assert "3 problem(s)" in out and "stray.png" in out


def test_hand_edited_manifest_and_card_are_caught(ds: Path) -> None:
    manifest = ds / "manifest.jsonl"
    lines = manifest.read_text().splitlines()
    row = json.loads(lines[0])
    row["split"] = "val" if row["split"] != "val" else "test"
    manifest.write_text("\n".join([json.dumps(row), *lines[1:]]) + "\n")
    problems = verify_dataset(ds).problems
    assert any("manifest.jsonl:1:" in p and "is not at" in p for p in problems)
    assert any(p.startswith(f"{ds / 'dataset.json'}: counts.") for p in problems)

    row["difficulty"] = "tricky"
    manifest.write_text("\n".join([json.dumps(row), *lines[1:]]) + "\n")
    problems = verify_dataset(ds).problems
    assert len(problems) == 1 and "manifest.jsonl:1: difficulty: expected one of" in problems[0]


def test_edited_card_counts_are_caught(ds: Path) -> None:
    card_file = ds / "dataset.json"
    card = json.loads(card_file.read_text())
    card["counts"]["train"]["clean_side"]["cam0"] += 1
    card["tagged_clean"] = 99
    card_file.write_text(json.dumps(card))
    problems = verify_dataset(ds).problems
    assert any("counts.train.clean_side.cam0: card says" in p for p in problems)
    assert any("tagged_clean" in p for p in problems)
    card_file.write_text("{")
    assert any("dataset.json: " in p for p in verify_dataset(ds).problems)


def test_not_a_dataset(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="not a folder"):
        verify_dataset(tmp_path / "nope")
    (tmp_path / "x").mkdir()
    with pytest.raises(DatasetError, match="not a dataset"):
        verify_dataset(tmp_path / "x")  # an empty folder is a wrong argument, not a damaged dataset
    (tmp_path / "x" / "dataset.json").write_text("{}")
    assert "manifest.jsonl: file not found" in verify_dataset(tmp_path / "x").problems[0]
