import itertools
import json
import logging
import multiprocessing
import os
import shutil
import stat
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from lenspair.capture.ingested import read_pairs, read_report, write_pairs, write_report
from lenspair.cli import Terminated, main
from lenspair.core.fsutil import sha256_file
from lenspair.core.imageio import read_image
from lenspair.core.imagewrite import write_image
from lenspair.dataset import build as build_module
from lenspair.dataset import output as output_module
from lenspair.dataset.build import build_dataset
from lenspair.dataset.card import read_card
from lenspair.dataset.config import CurationConfig, DatasetConfig, SplitConfig
from lenspair.dataset.errors import DatasetError
from lenspair.dataset.manifest import read_manifest
from lenspair.dataset.verify import verify_dataset
from lenspair.model.detection.data import dataset_samples
from lenspair.model.errors import ModelError
from lenspair.model.networks.detector import DetectorSpec
from tests.dataset.dataset_synth import DT_NS, T0_NS, RecordingFactory
from tests.processes import dead_pid

SEGMENTS = DatasetConfig(split=SplitConfig(segment_frames=10, segment_gap_frames=2))


def _three(recording: RecordingFactory) -> list[Path]:
    return [
        recording("rec_a", n=30, still=(3, 4), blurred=(6,), clean=(12,), rejected=(9,)),
        recording("rec_b", n=30, obstructed="cam0", seed=1, strength=0.9, masked=True),
        recording("rec_c", n=30, seed=2, strength=0.15),
    ]


def _tree(root: Path) -> dict[str, str]:
    return {
        str(p.relative_to(root)): sha256_file(p) for p in sorted(root.rglob("*")) if p.is_file()
    }


def test_build_layout_manifest_card_and_rules(recording: RecordingFactory, tmp_path: Path) -> None:
    sources = _three(recording)
    result = build_dataset(sources, tmp_path / "DS", SEGMENTS)
    ds = result.out
    rows = read_manifest(ds / "manifest.jsonl")
    assert len(rows) == len(result.rows) > 40
    for row in rows:
        assert Path(row.files["input"]).name == Path(row.files["target"]).name
        assert row.files["input"] == f"{row.split}/input/{row.recording}_{row.t_ns}.png"
        assert (row.obstructed, row.clean) in {("cam1", "cam0"), ("cam0", "cam1")}
        assert ("mask" in row.files) == (row.recording == "rec_b")
        assert sha256_file(ds / row.files["target"]) == row.sha256["target"]
    by_recording = {r.recording: r.difficulty for r in rows if r.difficulty != "clean"}
    assert by_recording == {"rec_a": "medium", "rec_b": "hard", "rec_c": "easy"}
    card = read_card(ds / "dataset.json")
    removed = {rule.rule: rule.removed for rule in card.curation}
    assert removed["ingest_rejected"] == 1
    assert removed["sharpness"] == 1
    assert removed["duplicate"] == 2
    assert sum(removed.values()) + card.counts["all"].pairs == card.pairs_in == 90
    assert card.ingest_reasons == {"too few matches": 1}
    assert card.tagged_clean == sum(1 for r in rows if r.difficulty == "clean") == 1
    assert {s.recording: s.clean for s in card.sources} == {
        "rec_a": "cam0",
        "rec_b": "cam1",
        "rec_c": "cam0",
    }
    assert card.sources[0].calibration_source.endswith("rec_a/camchain.yaml")
    for split in ("train", "val", "test"):
        assert (
            card.counts[split].clean_side["cam0"] > 0 and card.counts[split].clean_side["cam1"] > 0
        )
        assert read_image(ds / f"contact_{split}.png").shape[2] == 3
    assert "rain" in card.counts["all"].clean_side_by_anomaly
    assert (ds / "config.yaml").read_text().startswith("curation:")
    assert verify_dataset(ds).ok
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp folder left


def test_no_group_straddles_two_splits(recording: RecordingFactory, tmp_path: Path) -> None:
    result = build_dataset(_three(recording), tmp_path / "DS", SEGMENTS)
    assert result.card.grouping.mode == "segment"
    split_of: dict[str, str] = {}
    for row in result.rows:
        assert split_of.setdefault(row.group, row.split) == row.split
    by_recording: dict[str, list[tuple[int, str]]] = {}
    for row in result.rows:
        index = (row.t_ns - 1_700_000_000_000_000_000) // 50_000_000
        by_recording.setdefault(row.recording, []).append((index, row.split))
    for frames in by_recording.values():
        frames.sort()
        for (a, split_a), (b, split_b) in itertools.pairwise(frames):
            assert split_a == split_b or b - a > 2


def test_one_recording_given_twice_under_two_names_is_said(
    recording: RecordingFactory, tmp_path: Path
) -> None:
    import shutil

    first = recording("rec_a", n=30)
    twin = first.parent / "rec_twin"
    shutil.copytree(first, twin)  # the same frames, byte for byte, under another name
    report = json.loads((twin / "report.json").read_text())
    (twin / "report.json").write_text(json.dumps({**report, "recording_id": "rec_twin"}))
    result = build_dataset([first, twin], tmp_path / "DS", SEGMENTS)
    splits_of: dict[str, set[str]] = {}
    for row in result.rows:
        splits_of.setdefault(row.sha256["input"], set()).add(row.split)
    leaks = sum(1 for found in splits_of.values() if len(found) > 1)
    assert leaks > 0  # the twins' segments hash to other splits: the case to say
    (warning,) = [w for w in result.card.grouping.warnings if "byte-identical" in w]
    assert warning.startswith(f"{leaks} input image(s)")
    clean = build_dataset([first], tmp_path / "DS1", SEGMENTS)
    assert not any("byte-identical" in w for w in clean.card.grouping.warnings)


def test_recording_mode_keeps_recordings_whole(recording: RecordingFactory, tmp_path: Path) -> None:
    config = DatasetConfig(split=SplitConfig(group_by="recording"))
    result = build_dataset(_three(recording), tmp_path / "DS", config)
    splits: dict[str, str] = {}
    for row in result.rows:
        assert splits.setdefault(row.recording, row.split) == row.split
    assert result.card.curation[-1].removed == 0  # no split_gap in recording mode


def test_same_inputs_and_seed_give_identical_bytes(
    recording: RecordingFactory, tmp_path: Path
) -> None:
    sources = _three(recording)
    first = build_dataset(sources, tmp_path / "one", SEGMENTS, workers=1).out
    second = build_dataset(sources, tmp_path / "two", SEGMENTS, workers=3).out
    assert _tree(first) == _tree(second)
    # the same recordings in another order: the same dataset (a rerun was refused as
    # "a different dataset" because the card listed them in the order given)
    reversed_order = build_dataset(sources[::-1], tmp_path / "rev", SEGMENTS).out
    assert _tree(reversed_order) == _tree(first)
    assert len(_tree(first)) > 100
    other = DatasetConfig(split=SplitConfig(segment_frames=10, segment_gap_frames=2, seed=1))
    third = build_dataset(sources, tmp_path / "three", other).out
    assert _tree(third) != _tree(first)


def test_dataset_images_are_independent_of_their_sources(
    recording: RecordingFactory, tmp_path: Path
) -> None:
    source = recording("rec_a", n=4)
    config = DatasetConfig(split=SplitConfig(fractions=(1.0, 0.0, 0.0)))
    first = build_dataset([source], tmp_path / "DS", config).out
    second = build_dataset([source], tmp_path / "DS2", config).out
    name = f"{read_pairs(source / 'pairs.jsonl')[0].t_ns}"
    original = source / "input" / f"{name}.png"
    before = original.read_bytes()
    edited = first / "train" / "input" / f"rec_a_{name}.png"
    assert edited.stat().st_nlink == 1
    with edited.open("r+b") as handle:  # edit in place, as an image editor would
        handle.seek(len(before) - 1)
        handle.write(bytes([before[-1] ^ 1]))
    assert original.read_bytes() == before
    assert (second / "train" / "input" / f"rec_a_{name}.png").read_bytes() == before
    assert verify_dataset(second).ok
    assert read_card(first / "dataset.json").image_files == "copy"


def test_hard_links_are_opt_in_read_only_and_on_the_card(
    recording: RecordingFactory, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    source = recording("rec_a", n=4)
    out = tmp_path / "DS"
    code = main(["dataset-build", str(source), "--out", str(out), "--link", "hard",
                 "--splits", "1,0,0"])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    name = f"{read_pairs(source / 'pairs.jsonl')[0].t_ns}"
    linked = out / "train" / "input" / f"rec_a_{name}.png"
    assert os.path.samefile(linked, source / "input" / f"{name}.png")
    assert linked.stat().st_mode & 0o222 == 0
    card = read_card(out / "dataset.json")
    assert card.image_files == "hard-link" and "read-only" in card.image_files_note
    assert verify_dataset(out).ok


def test_rerun_removes_leftovers_of_killed_builds_of_the_same_output_only(
    recording: RecordingFactory, tmp_path: Path
) -> None:
    source = recording("rec_a", n=4)
    dead = dead_pid()
    killed = tmp_path / f".DS.{dead}.abc12345.building"
    (killed / "train").mkdir(parents=True)
    (killed / "train" / "x.png").write_bytes(b"half")
    trash = tmp_path / f".DS.{dead}.zz123456.old"
    trash.mkdir()
    other_output = tmp_path / f".OTHER.{dead}.abc12345.building"
    other_output.mkdir()
    running = tmp_path / f".DS.{os.getppid()}.abc12345.building"  # a live process's build
    running.mkdir()
    users = tmp_path / ".DS.notes.building"
    users.mkdir()
    config = DatasetConfig(split=SplitConfig(fractions=(1.0, 0.0, 0.0)))
    build_dataset([source], tmp_path / "DS", config)
    assert not killed.exists() and not trash.exists()
    assert other_output.exists() and running.exists() and users.exists()


def test_missing_image_is_skipped_counted_and_warned(
    recording: RecordingFactory, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    source = recording("rec_a", n=6)
    records = read_pairs(source / "pairs.jsonl")
    (source / records[2].files["target"]).unlink()
    config = DatasetConfig(split=SplitConfig(fractions=(1.0, 0.0, 0.0)))
    with caplog.at_level(logging.WARNING):
        result = build_dataset([source], tmp_path / "DS", config)
    removed = {rule.rule: rule.removed for rule in result.card.curation}
    assert removed["missing_file"] == 1
    assert len(result.rows) == 5
    assert f"{records[2].t_ns}.png: file missing" in caplog.text
    lines = [
        json.loads(line) for line in (tmp_path / "DS" / "removed.jsonl").read_text().splitlines()
    ]
    assert lines == [
        {
            "recording": "rec_a",
            "t_ns": records[2].t_ns,
            "rule": "missing_file",
            "reason": f"{source / records[2].files['target']}: file missing (named in pairs.jsonl)",
        }
    ]


def test_an_image_that_cannot_be_read_is_not_called_missing(
    recording: RecordingFactory, tmp_path: Path
) -> None:
    """Every OSError read as "file missing": a folder in an image's place (or no permission,
    a failing disk) sent the user looking for a file that is there."""
    source = recording("rec_a", n=6)
    records = read_pairs(source / "pairs.jsonl")
    target = source / records[2].files["target"]
    target.unlink()
    target.mkdir()
    config = DatasetConfig(split=SplitConfig(fractions=(1.0, 0.0, 0.0)))
    result = build_dataset([source], tmp_path / "DS", config)
    removed = {rule.rule: rule.removed for rule in result.card.curation}
    assert removed["missing_file"] == 0 and removed["bad_image"] == 1 and len(result.rows) == 5
    line = json.loads((tmp_path / "DS" / "removed.jsonl").read_text())
    assert line["reason"].startswith(f"{target}: cannot be read (Is a directory")


def test_checksum_mismatch_rejects_the_pair(recording: RecordingFactory, tmp_path: Path) -> None:
    source = recording("rec_a", n=5)
    records = read_pairs(source / "pairs.jsonl")
    (source / records[1].files["input"]).write_bytes(
        (source / records[3].files["input"]).read_bytes()
    )
    config = DatasetConfig(split=SplitConfig(fractions=(1.0, 0.0, 0.0)))
    result = build_dataset([source], tmp_path / "DS", config)
    removed = {rule.rule: rule.removed for rule in result.card.curation}
    assert removed["checksum"] == 1 and len(result.rows) == 4


def test_corrupt_image_is_a_bad_image(recording: RecordingFactory, tmp_path: Path) -> None:
    source = recording("rec_a", n=4)
    records = read_pairs(source / "pairs.jsonl")
    (source / records[0].files["input"]).write_bytes(b"not a png")
    write_pairs(
        source / "pairs.jsonl",
        [r if i else type(r)(**{**r.__dict__, "sha256": {}}) for i, r in enumerate(records)],
    )
    config = DatasetConfig(split=SplitConfig(fractions=(1.0, 0.0, 0.0)))
    result = build_dataset([source], tmp_path / "DS", config)
    assert {r.rule: r.removed for r in result.card.curation}["bad_image"] == 1


def test_a_nul_in_a_file_name_is_a_bad_image_named_by_its_line(
    recording: RecordingFactory, tmp_path: Path
) -> None:
    # "ValueError: embedded null byte" ended the build in a traceback
    source = recording("rec_a", n=4)
    records = read_pairs(source / "pairs.jsonl")
    records[1] = replace(records[1], files={**records[1].files, "input": "input/\x00x.png"})
    write_pairs(source / "pairs.jsonl", records)
    config = DatasetConfig(split=SplitConfig(fractions=(1.0, 0.0, 0.0)))
    result = build_dataset([source], tmp_path / "DS", config)
    assert {r.rule: r.removed for r in result.card.curation}["bad_image"] == 1
    (line,) = (tmp_path / "DS" / "removed.jsonl").read_text().splitlines()
    reason = json.loads(line)["reason"]
    assert reason.startswith(f"{source / 'pairs.jsonl'}:2: files.input: not a file name")


@pytest.mark.parametrize("outside", ["../other/input/{t}.png", "{root}/other/input/{t}.png"])
def test_a_file_outside_the_recording_is_a_bad_image_named_by_its_line(
    recording: RecordingFactory,
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
    outside: str,
) -> None:
    """files.input "../other/input/x.png" was joined to the recording folder unchecked:
    another recording's image (its sha256 right) was copied into the dataset."""
    source = recording("rec_a", n=4)
    other = recording("other", n=4, seed=3)
    theirs = read_pairs(other / "pairs.jsonl")[1]
    records = read_pairs(source / "pairs.jsonl")
    relative = outside.format(t=theirs.t_ns, root=source.parent)
    files = {**records[2].files, "input": relative}
    sha256 = {**records[2].sha256, "input": theirs.sha256["input"]}
    records[2] = replace(records[2], files=files, sha256=sha256)
    write_pairs(source / "pairs.jsonl", records)
    config = DatasetConfig(split=SplitConfig(fractions=(1.0, 0.0, 0.0)))
    with caplog.at_level(logging.WARNING):
        result = build_dataset([source], tmp_path / "DS", config)
    assert {r.rule: r.removed for r in result.card.curation}["bad_image"] == 1
    assert records[2].t_ns not in {row.t_ns for row in result.rows} and len(result.rows) == 3
    said = f"{source / 'pairs.jsonl'}:3: files.input {relative!r} points outside the recording"
    (line,) = (tmp_path / "DS" / "removed.jsonl").read_text().splitlines()
    assert json.loads(line) == {
        "recording": "rec_a",
        "t_ns": records[2].t_ns,
        "rule": "bad_image",
        "reason": f"{said} folder",
    }
    assert f"pair skipped (bad_image): {said}" in caplog.text


@pytest.mark.parametrize("missing", ["pairs.jsonl", "report.json"])
def test_missing_contract_file_is_an_error_naming_the_folder(
    recording: RecordingFactory, tmp_path: Path, missing: str
) -> None:
    source = recording("rec_a", n=2)
    (source / missing).unlink()
    with pytest.raises(DatasetError, match=rf"rec_a: missing {missing}"):
        build_dataset([source], tmp_path / "DS", DatasetConfig())


def test_capture_ingest_s_out_given_as_a_source_points_to_its_recordings(
    recording: RecordingFactory, tmp_path: Path
) -> None:
    # it said "missing pairs.jsonl ... capture-ingest was stopped: run it again"
    source = recording("rec_a", n=2)
    recording("rec_b", n=2)
    with pytest.raises(DatasetError, match=r"holds ingested recordings \(rec_a, rec_b\), not one"):
        build_dataset([source.parent], tmp_path / "DS", DatasetConfig())


def test_bad_sources_are_errors(recording: RecordingFactory, tmp_path: Path) -> None:
    source = recording("rec_a", n=2)
    with pytest.raises(DatasetError, match="not a folder"):
        build_dataset([tmp_path / "nope"], tmp_path / "DS", DatasetConfig())
    with pytest.raises(DatasetError, match="rec_a: given twice"):  # not "also that of itself"
        build_dataset([source, source], tmp_path / "DS", DatasetConfig())
    namesake = tmp_path / "elsewhere" / "rec_a"
    shutil.copytree(source, namesake)
    with pytest.raises(DatasetError, match="also that of"):
        build_dataset([source, namesake], tmp_path / "DS", DatasetConfig())
    with pytest.raises(DatasetError, match="overlaps"):
        build_dataset([source], source / "DS", DatasetConfig())
    report = json.loads((source / "report.json").read_text())
    (source / "report.json").write_text(json.dumps(report | {"obstructed": "cam2"}))
    with pytest.raises(DatasetError, match=r"report\.json: obstructed must be cam0 or cam1"):
        build_dataset([source], tmp_path / "DS", DatasetConfig())


def test_existing_output_rules(recording: RecordingFactory, tmp_path: Path) -> None:
    source = recording("rec_a", n=6)
    config = DatasetConfig(split=SplitConfig(fractions=(1.0, 0.0, 0.0)))
    out = tmp_path / "DS"
    build_dataset([source], out, config)
    build_dataset([source], out, config)  # the same dataset again: fine
    other = DatasetConfig(config.curation, SplitConfig(fractions=(1.0, 0.0, 0.0), seed=3))
    with pytest.raises(DatasetError, match=r"DS: holds a different dataset \(dataset.json"):
        build_dataset([source], out, other)
    assert read_card(out / "dataset.json").seed == 0  # untouched
    build_dataset([source], out, other, overwrite=True)
    assert read_card(out / "dataset.json").seed == 3
    stranger = tmp_path / "photos"
    stranger.mkdir()
    (stranger / "holiday.jpg").write_bytes(b"x")
    with pytest.raises(DatasetError, match="photos: not empty and not a lenspair dataset"):
        build_dataset([source], stranger, config, overwrite=True)
    (tmp_path / "empty").mkdir()
    build_dataset([source], tmp_path / "empty", config)
    assert (tmp_path / "empty" / "manifest.jsonl").is_file()
    # another tool's dataset.json (COCO, Hugging Face) does not make a folder ours:
    # --overwrite would have deleted its images
    coco = tmp_path / "coco"
    (coco / "photos").mkdir(parents=True)
    (coco / "photos" / "a.jpg").write_bytes(b"x")
    (coco / "dataset.json").write_text('{"images": []}')
    with pytest.raises(DatasetError, match=r"coco: its dataset\.json is not a lenspair dataset"):
        build_dataset([source], coco, config, overwrite=True)
    assert (coco / "photos" / "a.jpg").read_bytes() == b"x"


def _dataset_with_notes(
    recording: RecordingFactory, tmp_path: Path
) -> tuple[Path, Path, DatasetConfig]:
    """``(source, DS, config)``: a built dataset the user wrote NOTES.md into."""
    source = recording("rec_a", n=6)
    config = DatasetConfig(split=SplitConfig(fractions=(1.0, 0.0, 0.0)))
    out = tmp_path / "DS"
    build_dataset([source], out, config)
    (out / "NOTES.md").write_text("collected on the roof")
    return source, out, config


def test_a_rebuild_keeps_the_users_own_files(
    recording: RecordingFactory, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    source, out, config = _dataset_with_notes(recording, tmp_path)
    (out / "eval_best").mkdir()
    (out / "eval_best" / "metrics.json").write_text("{}")
    with caplog.at_level("WARNING"):
        build_dataset([source], out, config)  # an unchanged rerun deleted both, silently
    assert (out / "NOTES.md").read_text() == "collected on the roof"
    assert (out / "eval_best" / "metrics.json").read_text() == "{}"
    assert any("kept NOTES.md, eval_best" in r.getMessage() for r in caplog.records)
    other = DatasetConfig(config.curation, SplitConfig(fractions=(1.0, 0.0, 0.0), seed=3))
    build_dataset([source], out, other, overwrite=True)  # replaced: still kept
    assert (out / "NOTES.md").is_file() and read_card(out / "dataset.json").seed == 3
    assert verify_dataset(out).ok  # the user's files are not the dataset's problems


def test_a_rebuild_keeps_the_users_files_inside_split_folders(
    recording: RecordingFactory, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # An evaluation saved in train/restored/ made an identical rebuild "a different
    # dataset (file lists differ)", and --overwrite then deleted it without a word.
    source, out, config = _dataset_with_notes(recording, tmp_path)
    (out / "train" / "restored").mkdir()
    (out / "train" / "restored" / "r.txt").write_text("mine")
    with caplog.at_level("WARNING"):
        build_dataset([source], out, config)  # unchanged: accepted, no --overwrite needed
    assert (out / "train" / "restored" / "r.txt").read_text() == "mine"
    assert verify_dataset(out).ok  # not in an image folder: no loader takes it
    other = DatasetConfig(config.curation, SplitConfig(fractions=(1.0, 0.0, 0.0), seed=3))
    build_dataset([source], out, other, overwrite=True)
    assert (out / "train" / "restored" / "r.txt").read_text() == "mine"
    assert read_card(out / "dataset.json").seed == 3
    assert any("kept NOTES.md, train/restored, not" in r.getMessage() for r in caplog.records)
    stray = out / "train" / "input" / "extra.png"  # an image folder: a loader would take it
    stray.write_bytes(b"x")
    assert any(str(stray) in p and "not listed" in p for p in verify_dataset(out).problems)
    with pytest.raises(DatasetError, match="file lists differ"):  # not the user's to keep
        build_dataset([source], out, other)
    (out / "manifest.jsonl").write_text("not json\n")  # and with no manifest to read
    build_dataset([source], out, other, overwrite=True)
    assert not stray.exists() and verify_dataset(out).ok  # dropped: readers would fail on it
    assert (out / "train" / "restored" / "r.txt").read_text() == "mine"


def test_a_rebuild_keeps_a_link_to_a_folder_and_an_empty_folder_in_a_split(
    recording: RecordingFactory, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """os.walk lists both as folders, not files: a rebuild dropped them without a word."""
    source, out, config = _dataset_with_notes(recording, tmp_path)
    (tmp_path / "evals" / "run1").mkdir(parents=True)
    (tmp_path / "evals" / "run1" / "metrics.md").write_text("mine")
    (out / "train" / "restored").symlink_to(Path("..", "..", "evals", "run1"))
    (out / "train" / "notes").mkdir()
    other = DatasetConfig(config.curation, SplitConfig(fractions=(1.0, 0.0, 0.0), seed=3))
    with caplog.at_level("WARNING"):
        build_dataset([source], out, other, overwrite=True)
    assert (out / "train" / "restored").is_symlink()
    assert (out / "train" / "restored" / "metrics.md").read_text() == "mine"
    assert (out / "train" / "notes").is_dir() and read_card(out / "dataset.json").seed == 3
    assert any("train/notes, train/restored" in r.getMessage() for r in caplog.records)
    assert verify_dataset(out).ok


def test_failed_build_leaves_nothing_half_written(
    recording: RecordingFactory, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    source = recording("rec_a", n=4)

    def explode(*_: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(output_module, "write_card", explode)
    with pytest.raises(OSError, match="No space"):
        build_dataset([source], tmp_path / "DS", DatasetConfig())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ingested"]


def test_exclude_clean_and_thresholds_from_cli(recording: RecordingFactory, tmp_path: Path) -> None:
    source = recording("rec_a", n=8, clean=(1, 2, 3, 4, 5))
    out = tmp_path / "DS"
    args = [str(source), "--out", str(out), "--splits", "1,0,0", "--seed", "4"]
    assert main(["dataset-build", *args, "--exclude-clean"]) == 0
    card = read_card(out / "dataset.json")
    assert {r.rule: r.removed for r in card.curation}["clean"] == 5
    assert card.config.curation.clean_pairs == "exclude" and card.seed == 4
    # thresholds that remove every pair: refused, the old dataset kept (an empty one
    # was written, exit 0, and train found out)
    assert main(["dataset-build", *args, "--min-sharpness", "1e9", "--overwrite"]) == 2
    assert read_card(out / "dataset.json").counts["all"].pairs == 3
    assert main(["dataset-build", "--verify", str(out)]) == 0


def test_cli_errors_are_one_line(
    recording: RecordingFactory, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    source = recording("rec_a", n=2)
    assert main(["dataset-build", str(source), "--out", str(tmp_path / "DS"), "--splits", "1"]) == 2
    assert "expected three comma-separated fractions" in capsys.readouterr().err
    assert main(["dataset-build", "--out", str(tmp_path / "DS")]) == 2
    assert "give ingested recording folders" in capsys.readouterr().err
    config = tmp_path / "bad.yaml"
    config.write_text("curation:\n  max_residual: 1\n")
    code = main(
        ["dataset-build", str(source), "--out", str(tmp_path / "DS"), "--config", str(config)]
    )
    err = capsys.readouterr().err
    assert code == 2 and "bad.yaml: curation.max_residual: unknown key" in err
    assert len(err.strip().splitlines()) == 1


def test_thresholds_reach_the_card(recording: RecordingFactory, tmp_path: Path) -> None:
    config = DatasetConfig(CurationConfig(max_residual_px=0.5), SplitConfig(fractions=(1, 0, 0)))
    result = build_dataset([recording("rec_a", n=3)], tmp_path / "DS", config)
    assert result.card.config.curation.max_residual_px == 0.5
    strict = DatasetConfig(CurationConfig(max_residual_px=0.1), SplitConfig(fractions=(1, 0, 0)))
    with pytest.raises(DatasetError, match=r"no pair survived curation: 3 pairs in, .*residual 3"):
        build_dataset([recording("rec_b", n=3)], tmp_path / "DS2", strict)
    assert not (tmp_path / "DS2").exists()


def test_a_recording_whose_side_check_disagrees_is_refused_unless_accepted(
    recording: RecordingFactory,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
) -> None:
    good = recording("rec_a", n=6)
    swapped = recording("rec_b", n=6, obstructed="cam0")
    report = read_report(swapped / "report.json")
    said = "images suggest cam1 is obstructed, but cam0 is declared (detector: ...)"
    side_check = {"mismatch": True, "message": said, "confidence": 0.9, "method": "detector"}
    write_report(swapped / "report.json", replace(report, side_check=side_check))
    args = ["dataset-build", str(good), str(swapped), "--out"]
    # it was built as declared: input the clean view, target the rainy one
    assert main([*args, str(tmp_path / "DS")]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "rec_b: images suggest cam1 is obstructed" in line and "--accept-side-mismatch" in line
    assert not (tmp_path / "DS").exists()
    assert main([*args, str(tmp_path / "DS"), "--accept-side-mismatch"]) == 0
    assert read_card(tmp_path / "DS" / "dataset.json").pairs_in == 12
    # a weak vote only warns; so does the fine-detail check, however sure: on heavy
    # rain it named the clean camera with confidence 0.52 (drops add detail)
    weak = {**side_check, "confidence": 0.3}
    detail = {**side_check, "method": "detail"}
    unnamed = {k: v for k, v in side_check.items() if k != "method"}  # older reports: detail
    for number, check in enumerate((weak, detail, unnamed)):
        write_report(swapped / "report.json", replace(report, side_check=check))
        caplog.clear()
        with caplog.at_level("WARNING"):
            assert main([*args, str(tmp_path / f"DS{number + 2}")]) == 0
        assert any("building as declared, although" in r.getMessage() for r in caplog.records)


@pytest.mark.parametrize(
    ("key", "value", "said"),
    [
        ("mismatched", True, "expected 'mismatch' true or false, got None"),
        ("method", "detector-v2", "expected 'method' one of detail, detector, got 'detector-v2'"),
        ("confidence", "0.9", "expected 'confidence' in [0, 1], got '0.9'"),
    ],
)
def test_a_side_check_it_cannot_read_is_refused_not_taken_for_no_mismatch(
    recording: RecordingFactory,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    key: str,
    value: object,
    said: str,
) -> None:
    # the check is the only guard against a dataset with input and target swapped: a
    # misspelt 'mismatch' or another method's name had read as "no mismatch", and a
    # detector's sure verdict under another method name only as a warning
    swapped = recording("rec_b", n=6, obstructed="cam0")
    path = swapped / "report.json"
    data = json.loads(path.read_text())
    check = {"mismatch": True, "message": "cam1 looks obstructed", "method": "detector"}
    check["confidence"] = 0.9
    if key == "mismatched":
        del check["mismatch"]
    check[key] = value
    data["side_check"] = check
    path.write_text(json.dumps(data))
    assert main(["dataset-build", str(swapped), "--out", str(tmp_path / "DS")]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert str(path) in line and said in line
    assert not (tmp_path / "DS").exists()


@pytest.mark.parametrize(
    "damaged", ["pairs.jsonl", "report.json", "manifest.jsonl", "dataset.json"]
)
def test_bytes_that_are_not_utf8_are_one_line_naming_the_file(
    recording: RecordingFactory, tmp_path: Path, capsys: pytest.CaptureFixture[str], damaged: str
) -> None:
    source = recording("rec_a", n=6)
    out = tmp_path / "DS"
    assert main(["dataset-build", str(source), "--out", str(out)]) == 0
    capsys.readouterr()
    target = (source if damaged in ("pairs.jsonl", "report.json") else out) / damaged
    target.write_bytes(target.read_bytes() + b"\xff\xfe\x00bad\n")  # a traceback, exit 1
    argv = ["--verify", str(out)] if target.parent == out else [str(source), "--out", str(out)]
    code = main(["dataset-build", *argv])
    printed = capsys.readouterr()
    if argv[0] == "--verify":  # a problem of the dataset: listed, exit 1
        assert code == 1
        lines = [line for line in printed.out.splitlines() if "not UTF-8" in line]
    else:  # a problem of the input: one line, exit 2
        lines = printed.err.strip().splitlines()
        assert code == 2
    assert len(lines) == 1 and str(target) in lines[0] and "not UTF-8" in lines[0], printed
    if damaged.endswith(".jsonl"):  # the line is named too
        assert f"{target}:{len(target.read_bytes().splitlines())}: not UTF-8" in lines[0]


def test_a_rebuild_with_one_more_recording_keeps_the_grouping(
    recording: RecordingFactory, tmp_path: Path
) -> None:
    split = SplitConfig(
        fractions=(0.5, 0.5, 0.0), min_groups_per_split=1, segment_frames=2, segment_gap_frames=0
    )
    config = DatasetConfig(split=split)
    out = tmp_path / "DS"
    first = build_dataset([recording("rec_a", n=8)], out, config)
    assert first.card.grouping.mode == "segment"  # one recording: too few to split by
    both = [recording("rec_a", n=8), recording("rec_b", n=8, seed=1)]
    again = build_dataset(both, out, config, overwrite=True)
    assert again.card.grouping.mode == "segment"  # auto alone would now say recording
    assert any("kept grouping by segment" in w for w in again.card.grouping.warnings)
    # its config.yaml says so: built again from it, the same splits come out
    assert again.card.config.split.group_by == "segment"
    assert "group_by: segment" in (out / "config.yaml").read_text()
    fresh = build_dataset(both, tmp_path / "DS2", config)
    assert fresh.card.grouping.mode == "recording"


def test_one_session_cut_into_two_recordings_across_splits_is_said(
    recording: RecordingFactory, tmp_path: Path
) -> None:
    first = recording("sess_0", n=8)
    second = recording("sess_1", n=8, seed=1, t0_ns=T0_NS + 8 * DT_NS)  # the next frame on
    later = recording("other", n=8, seed=2, t0_ns=T0_NS + 10**12)  # another session
    seen = set()
    for seed in range(40):
        split = SplitConfig(fractions=(0.5, 0.5, 0.0), group_by="recording", seed=seed)
        built = build_dataset(
            [first, second, later], tmp_path / f"DS{seed}", DatasetConfig(split=split)
        )
        where = {row.recording: row.split for row in built.rows}
        said = [w for w in built.card.grouping.warnings if "one session cut in two" in w]
        apart = where["sess_0"] != where["sess_1"]
        assert len(said) == apart  # and never for "other"
        if apart:
            assert said[0].startswith("sess_1 starts 50.0 ms after sess_0 ends")
            assert f"in {where['sess_0']} and {where['sess_1']}" in said[0]
        seen.add(apart)
        if seen == {True, False}:
            break
    assert seen == {True, False}


def test_a_rebuild_says_how_many_pairs_changed_split(
    recording: RecordingFactory, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    sources = _three(recording)
    out = tmp_path / "DS"
    first = build_dataset(sources, out, SEGMENTS)
    again = build_dataset(sources, out, SEGMENTS, overwrite=True)  # the same splits
    assert again.changed_splits is None
    reseeded = replace(SEGMENTS, split=replace(SEGMENTS.split, seed=7))
    with caplog.at_level("WARNING"):
        moved = build_dataset(sources, out, reseeded, overwrite=True)
    before = {(r.recording, r.t_ns): r.split for r in first.rows}
    changed = sum(before.get((r.recording, r.t_ns), r.split) != r.split for r in moved.rows)
    assert changed > 0
    said = moved.changed_splits
    assert said is not None and said.startswith(f"{changed} pair(s) changed split")
    assert f"split: {said}" in caplog.text
    # logged, not in the card: the card's bytes depend on the inputs alone
    assert not any("changed split" in w for w in moved.card.grouping.warnings)
    assert "changed split" not in (out / "dataset.json").read_text()


def test_a_rebuild_that_fails_at_the_swap_loses_none_of_the_users_files(
    recording: RecordingFactory, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    source, out, config = _dataset_with_notes(recording, tmp_path)
    real = os.replace

    def busy(src: object, dst: object) -> None:
        if Path(str(src)) == out:  # --out a mount point (a Docker volume): EBUSY
            raise OSError(16, "Device or resource busy", str(src))
        real(src, dst)  # type: ignore[arg-type]

    monkeypatch.setattr(output_module.os, "replace", busy)
    with pytest.raises(OSError, match="busy"):
        build_dataset([source], out, config)
    # moved into the new build first, they went with its clean-up
    assert (out / "NOTES.md").read_text() == "collected on the roof"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["DS", "ingested"]


@pytest.mark.parametrize("stop", [KeyboardInterrupt, Terminated])
def test_a_rebuild_stopped_between_the_swaps_renames_puts_the_old_dataset_back(
    recording: RecordingFactory,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    stop: type[BaseException],
) -> None:
    # the put-back caught OSError alone: a SIGTERM there deleted the set-aside old dataset,
    # the user's files in it, and the new build
    source, out, config = _dataset_with_notes(recording, tmp_path)
    before = sorted(p.relative_to(out) for p in out.rglob("*"))
    other = DatasetConfig(config.curation, SplitConfig(fractions=(1.0, 0.0, 0.0), seed=3))
    real = os.replace

    def stopped(src: object, dst: object) -> None:
        real(src, dst)  # type: ignore[arg-type]
        if Path(str(src)) == out:  # the old dataset was just set aside
            raise stop

    monkeypatch.setattr(output_module.os, "replace", stopped)
    with pytest.raises(stop):
        build_dataset([source], out, other, overwrite=True)
    assert (out / "NOTES.md").read_text() == "collected on the roof"
    after = [p.relative_to(out) for p in out.rglob("*")]
    # and the lock the rebuild held on it (empty, hidden: its readers share it)
    assert sorted(after) == sorted([*before, Path(output_module.DATASET_LOCK)])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["DS", "ingested"]


def test_a_repeated_timestamp_is_named_by_its_line_in_the_file(
    recording: RecordingFactory, tmp_path: Path
) -> None:
    source = recording("rec_a", n=3)
    lines = (source / "pairs.jsonl").read_text().splitlines()
    # blank lines before the repeat: the message counted records, not the file's lines
    (source / "pairs.jsonl").write_text("\n".join([lines[0], "", "", lines[0], *lines[1:]]) + "\n")
    with pytest.raises(DatasetError, match=r"pairs\.jsonl:4: timestamp \d+ repeats"):
        build_dataset([source], tmp_path / "DS", DatasetConfig())


def _killed_between_the_swaps_renames(source: Path, out: Path, config: DatasetConfig) -> None:
    """Build in a child process that dies (as by kill -9) after the swap's first rename."""
    renames = []
    real = os.replace

    def dying(src: object, dst: object) -> None:
        if Path(str(src)) == out or renames:
            renames.append(src)
        if len(renames) == 2:
            os._exit(9)  # no finally, no clean-up: a kill
        real(src, dst)  # type: ignore[arg-type]

    output_module.os.replace = dying  # type: ignore[assignment]
    build_dataset([source], out, config, overwrite=True)


def test_a_rebuild_killed_during_its_swap_is_put_back_by_the_next(
    recording: RecordingFactory, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    source, out, config = _dataset_with_notes(recording, tmp_path)
    other = DatasetConfig(config.curation, SplitConfig(fractions=(1.0, 0.0, 0.0), seed=3))
    child = multiprocessing.get_context("fork").Process(
        target=_killed_between_the_swaps_renames, args=(source, out, other)
    )
    child.start()
    child.join()
    assert child.exitcode == 9 and not out.exists()  # the old dataset lies set aside
    with caplog.at_level("WARNING"):
        build_dataset([source], out, config)
    assert (out / "NOTES.md").read_text() == "collected on the roof"  # deleted as a leftover
    assert "set aside by an interrupted rebuild" in caplog.text
    assert sorted(p.name for p in tmp_path.iterdir()) == ["DS", "ingested"]


def test_the_detector_says_which_pair_of_a_damaged_dataset_differs_in_size(
    recording: RecordingFactory, tmp_path: Path
) -> None:
    # train-detector on it was a ValueError traceback ("pair: shapes differ")
    _, out, _ = _dataset_with_notes(recording, tmp_path)
    first = sorted((out / "train" / "input").glob("*.png"))[0]
    image = read_image(first)
    write_image(first, np.ascontiguousarray(image[:-1, :-1]))
    with pytest.raises(ModelError, match=rf"{first.name}: .* its target .*dataset-build --verify"):
        dataset_samples(out, "train", DetectorSpec())


def test_the_card_counts_ingest_rejections_by_reason_not_by_frame(tmp_path: Path) -> None:
    # each rejected frame's reason names its own file: the card listed one entry per
    # frame (count 1 each), hundreds on a real recording, instead of one per reason
    from lenspair.capture.ingest import ingest_recording
    from tests.capture.ingest_helpers import frame_files, make_recording

    recording = make_recording(tmp_path / "rec", frames=6)
    for bad in frame_files(recording, "cam1")[1:3]:
        bad.write_bytes(bad.read_bytes()[:300])  # truncated
    ingest_recording(recording, tmp_path / "ing", size=(160, 120))
    config = DatasetConfig(split=SplitConfig(fractions=(1.0, 0.0, 0.0)))
    result = build_dataset([tmp_path / "ing" / "rec"], tmp_path / "DS", config)
    assert result.card.ingest_reasons == {"cannot read input frame": 2}
    assert read_card(tmp_path / "DS" / "dataset.json").ingest_reasons == {
        "cannot read input frame": 2
    }


def test_the_dataset_folder_gets_the_mode_of_a_plain_mkdir(
    recording: RecordingFactory, tmp_path: Path
) -> None:
    """mkdtemp's 0o700 came over with the rename: no other user (a training job's account,
    a container's uid) could open the dataset, and every rebuild set it back."""
    source = recording("rec_a", n=4)
    plain = tmp_path / "plain"
    plain.mkdir()  # mkdir applies the umask to 0o777
    out = tmp_path / "DS"
    for extra in ([], ["--overwrite", "--seed", "3"]):
        argv = ["dataset-build", str(source), "--out", str(out), "--splits", "1,0,0", *extra]
        assert main(argv) == 0
        assert stat.S_IMODE(out.stat().st_mode) == stat.S_IMODE(plain.stat().st_mode)
    shared = tmp_path / "shared"  # a group's folder: what is made in it keeps its group
    shared.mkdir()
    shared.chmod(0o2775)
    argv = ["dataset-build", str(source), "--out", str(shared / "DS"), "--splits", "1,0,0"]
    assert main(argv) == 0
    assert (shared / "DS").stat().st_mode & stat.S_ISGID
    assert (shared / "DS" / "train").stat().st_mode & stat.S_ISGID


def test_what_the_output_file_system_refuses_is_found_before_measuring(
    recording: RecordingFactory, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A recording id near 255 bytes, and --link hard across file systems, failed after
    every pair was measured, naming the build's temporary folder."""
    source = recording("rec_a", n=4)
    report = read_report(source / "report.json")
    write_report(source / "report.json", replace(report, recording_id="d" * 240))
    measured: list[object] = []
    real = build_module.measure_record
    monkeypatch.setattr(build_module, "measure_record", lambda *a: measured.append(a) or real(*a))
    out = tmp_path / "DS"
    config = DatasetConfig(split=SplitConfig(fractions=(1, 0, 0)))
    with pytest.raises(DatasetError, match=r"rec_a: its dataset file names .* over the 255 "):
        build_dataset([source], out, config)
    records = read_pairs(source / "pairs.jsonl")  # lines without files: the default layout
    write_pairs(source / "pairs.jsonl", [replace(r, files={}, sha256={}) for r in records])
    with pytest.raises(DatasetError, match=r"rec_a: its dataset file names .* over the 255 "):
        build_dataset([source], out, config)
    write_pairs(source / "pairs.jsonl", records)
    write_report(source / "report.json", report)
    shm = Path("/dev/shm")
    if not shm.is_dir() or shm.stat().st_dev == tmp_path.stat().st_dev:
        pytest.skip("no second file system here")
    elsewhere = Path(tempfile.mkdtemp(dir=shm)) / "DS"
    try:
        with pytest.raises(DatasetError, match=r"--link hard: .* different file systems"):
            build_dataset([source], elsewhere, DatasetConfig(), link="hard")
    finally:
        shutil.rmtree(elsewhere.parent)
    assert not measured and not out.exists()


def test_link_hard_with_an_image_folder_on_another_file_system_is_refused_before_measuring(
    recording: RecordingFactory, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # input/ a link to another disk: the recording's own folder passed the check, and the
    # build failed at the first link after measuring, naming its temporary folder
    shm = Path("/dev/shm")
    if not shm.is_dir() or shm.stat().st_dev == tmp_path.stat().st_dev:
        pytest.skip("no second file system here")
    source = recording("rec_a", n=4)
    elsewhere = Path(tempfile.mkdtemp(dir=shm))
    try:
        shutil.move(source / "input", elsewhere / "input")
        (source / "input").symlink_to(elsewhere / "input")
        measured: list[object] = []
        monkeypatch.setattr(build_module, "measure_record", lambda *a: measured.append(a))
        said = rf"^--link hard: {source / 'input'} and \S+ are on different file systems"
        with pytest.raises(DatasetError, match=said):
            build_dataset([source], tmp_path / "DS", DatasetConfig(), link="hard")
        assert not measured and not (tmp_path / "DS").exists()
    finally:
        shutil.rmtree(elsewhere)


def test_a_build_into_the_current_folder_or_one_above_it_is_refused(
    recording: RecordingFactory, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # the rename left the shell in a deleted folder, where --verify . found no dataset
    source = recording("rec_a", n=4)
    config = DatasetConfig(split=SplitConfig(fractions=(1.0, 0.0, 0.0)))
    out = tmp_path / "DS"
    build_dataset([source], out, config)
    for here in (out, out / "train"):
        monkeypatch.chdir(here)
        with pytest.raises(DatasetError, match=rf"^{out}: the current folder"):
            build_dataset([source], Path(".") if here == out else Path(".."), config)
    assert verify_dataset(out).ok
    empty = tmp_path / "empty"
    empty.mkdir()
    monkeypatch.chdir(empty)
    with pytest.raises(DatasetError, match="run it from outside"):
        build_dataset([source], Path("."), config)
