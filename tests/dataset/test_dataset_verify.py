import json
import shutil
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


def test_input_and_target_listed_the_other_way_round_are_caught(ds: Path) -> None:
    # each file is where a file of its pair belongs, with the right hash: only the kind
    # in its path tells that the network would have been trained to add the anomaly
    manifest = ds / "manifest.jsonl"
    lines = manifest.read_text().splitlines()
    row = json.loads(lines[0])
    row["files"] = {"input": row["files"]["target"], "target": row["files"]["input"]}
    row["sha256"] = {"input": row["sha256"]["target"], "target": row["sha256"]["input"]}
    manifest.write_text("\n".join([json.dumps(row), *lines[1:]]) + "\n")
    problems = verify_dataset(ds).problems
    name, split = row["name"], row["split"]
    assert any(
        p.startswith(f"{manifest}:1: ") and f"is not at {split}/input/{name}.*" in p
        for p in problems
    )
    assert any(f"is not at {split}/target/{name}.*" in p for p in problems)


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


@pytest.mark.parametrize(
    ("name", "said"),
    [
        ("removed.jsonl", "missing (every build writes it: each pair curation removed, and why)"),
        ("config.yaml", "missing (every build writes its resolved configuration)"),
    ],
)
def test_a_deleted_record_file_is_caught(
    ds: Path, capsys: pytest.CaptureFixture[str], name: str, said: str
) -> None:
    """--verify said OK without removed.jsonl or config.yaml."""
    (ds / name).unlink()
    assert verify_dataset(ds).problems == (f"{ds / name}: {said}",)
    assert main(["dataset-build", "--verify", str(ds)]) == 1
    assert f"{ds / name}: missing" in capsys.readouterr().out


def test_edited_card_pairs_in_seed_and_rule_counts_are_caught(ds: Path) -> None:
    """Only the card's counts, tagged_clean and in_dataset were compared: these said OK."""
    card_file = ds / "dataset.json"
    card = json.loads(card_file.read_text())
    pairs_in, rule = card["pairs_in"], card["curation"][0]
    card["pairs_in"] = 5
    card["seed"] = 9
    rule["removed"] = 77
    card_file.write_text(json.dumps(card))
    kept = len(read_manifest(ds / "manifest.jsonl"))
    removed = len((ds / "removed.jsonl").read_text().splitlines())
    assert kept + removed == pairs_in
    where = ds / "dataset.json"
    assert set(verify_dataset(ds).problems) == {
        f"{where}: pairs_in: card says 5, manifest.jsonl ({kept} pairs) and removed.jsonl "
        f"({removed}) give {pairs_in}",
        f"{where}: curation.{rule['rule']}.removed: card says 77, removed.jsonl gives 0",
        f"{where}: seed: card says 9, its config.split.seed 0",
    }


def test_removed_jsonl_and_config_yaml_are_compared_with_the_card(ds: Path) -> None:
    """A line dropped from removed.jsonl, and another seed in config.yaml, said OK."""
    removed_file = ds / "removed.jsonl"
    lines = removed_file.read_text().splitlines()
    gone = json.loads(lines[0])
    removed_file.write_text("\n".join(lines[1:]) + "\n")
    config = ds / "config.yaml"
    config.write_text(config.read_text().replace("seed: 0", "seed: 4"))
    kept = len(read_manifest(ds / "manifest.jsonl"))
    by_rule = sum(json.loads(line)["rule"] == gone["rule"] for line in lines)
    where = ds / "dataset.json"
    assert set(verify_dataset(ds).problems) == {
        f"{where}: pairs_in: card says {kept + len(lines)}, manifest.jsonl ({kept} pairs) and "
        f"removed.jsonl ({len(lines) - 1}) give {kept + len(lines) - 1}",
        f"{where}: curation.{gone['rule']}.removed: card says {by_rule}, removed.jsonl gives "
        f"{by_rule - 1}",
        f"{config}: split.seed: 4, but dataset.json's config says 0",
    }
    removed_file.write_text("{}\n")
    assert any(p.startswith(f"{removed_file}:1: ") for p in verify_dataset(ds).problems)


def test_image_folders_outside_the_splits_are_listed(ds: Path) -> None:
    """The help says unlisted files in an input/, target/ or mask/ folder are reported; one
    outside train/, val/ and test/ (a reader of the splits takes DS/extra for one) was not."""
    shutil.copytree(ds / "train", ds / "extra")
    (ds / "extra" / "input" / ".DS_Store").write_bytes(b"")  # hidden: read by no loader
    (ds / "notes").mkdir()
    (ds / "notes" / "todo.txt").write_text("the user's")  # not an image folder: the user's
    (ds / "mask").mkdir()
    (ds / "mask" / "m.png").write_bytes(b"x")  # DS itself read as a paired folder
    stray = sorted(p for p in (ds / "extra").rglob("*") if p.is_file() and p.name[0] != ".")
    stray = sorted([*stray, ds / "mask" / "m.png"])
    assert stray and all(p.parent.name in ("input", "target", "mask") for p in stray)
    suffix = ": not listed in manifest.jsonl (an image folder outside train/, val/, test/)"
    assert verify_dataset(ds).problems == tuple(f"{p}{suffix}" for p in stray)
