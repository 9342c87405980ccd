"""Rebuilding into an existing dataset: identical reruns accepted, refusals taken early."""

import argparse
import importlib
from pathlib import Path

import pytest

from lenspair.cli import COMMANDS, build_parser, main
from lenspair.commands.dataset_build import BUILD_ONLY
from lenspair.core.fsutil import sha256_file
from lenspair.dataset import output as output_module
from lenspair.dataset.build import build_dataset
from lenspair.dataset.config import DatasetConfig, SplitConfig
from lenspair.dataset.errors import DatasetError
from tests.dataset.dataset_synth import RecordingFactory

SEGMENTS = SplitConfig(group_by="segment", segment_frames=3, segment_gap_frames=1)


def _tree(root: Path) -> dict[str, str]:
    return {
        str(p.relative_to(root)): sha256_file(p) for p in sorted(root.rglob("*")) if p.is_file()
    }


def _two(recording: RecordingFactory) -> list[Path]:
    return [recording("a", n=12), recording("b", n=12, obstructed="cam0", seed=1)]


def test_rerunning_a_rebuild_that_moved_pairs_is_accepted(
    recording: RecordingFactory, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The card noted the pairs that changed split against the dataset replaced, so the
    same command run again was refused: "holds a different dataset (dataset.json differs)"."""
    sources = [str(path) for path in _two(recording)]
    config = tmp_path / "seg.yaml"
    config.write_text("split: {group_by: segment, segment_frames: 3, segment_gap_frames: 1}\n")
    out = tmp_path / "DS"
    command = ["dataset-build", *sources, "--out", str(out), "--config", str(config)]
    assert main(command) == 0
    assert main([*command, "--seed", "3", "--overwrite"]) == 0
    capsys.readouterr()
    assert main([*command, "--seed", "3"]) == 0, capsys.readouterr().err
    # and the files are those of a build into a fresh folder: they depend on the inputs alone
    assert main(["dataset-build", *sources, "--out", str(tmp_path / "fresh"), "--config",
                 str(config), "--seed", "3"]) == 0  # fmt: skip
    assert _tree(out) == _tree(tmp_path / "fresh")


def test_a_refused_rebuild_copies_no_image_and_says_no_split_moved(
    recording: RecordingFactory,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A refused rebuild first logged "N pair(s) changed split against the dataset this
    build replaces" (nothing was replaced), and refused only once every image had been
    copied into the temporary folder (minutes on a large dataset)."""
    sources = _two(recording)
    out = tmp_path / "DS"
    first = build_dataset(sources, out, DatasetConfig(split=SEGMENTS))
    before = _tree(out)
    placed: list[Path] = []
    real = output_module._place_image
    monkeypatch.setattr(
        output_module, "_place_image", lambda s, d, link: placed.append(d) or real(s, d, link)
    )
    reseeded = DatasetConfig(split=SplitConfig(**{**vars(SEGMENTS), "seed": 3}))
    with caplog.at_level("WARNING"), pytest.raises(DatasetError, match="holds a different"):
        build_dataset(sources, out, reseeded)
    assert not placed
    assert "changed split" not in caplog.text
    assert _tree(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["DS", "ingested"]
    # the same rebuild allowed: it copies, and says what moved once it has replaced
    with caplog.at_level("WARNING"):
        moved = build_dataset(sources, out, reseeded, overwrite=True)
    assert placed and moved.changed_splits is not None
    assert moved.changed_splits in caplog.text
    assert {(r.recording, r.t_ns): r.split for r in first.rows} != {
        (r.recording, r.t_ns): r.split for r in moved.rows
    }


def test_another_tools_manifest_is_never_replaced_even_with_overwrite(
    recording: RecordingFactory, tmp_path: Path
) -> None:
    """A folder with a Hugging Face style ``manifest.jsonl`` (no card) was taken for a
    lenspair dataset: refused as "a different dataset", then deleted with --overwrite."""
    other = tmp_path / "other"
    (other / "train" / "input").mkdir(parents=True)
    (other / "train" / "input" / "mine.png").write_bytes(b"the user's")
    (other / "manifest.jsonl").write_text('{"file_name": "train/input/mine.png", "text": "x"}\n')
    for overwrite in (False, True):
        with pytest.raises(DatasetError, match="not a lenspair dataset; refusing to replace"):
            build_dataset([recording("a", n=6)], other, DatasetConfig(), overwrite=overwrite)
    assert (other / "train" / "input" / "mine.png").read_bytes() == b"the user's"


def test_a_dataset_whose_card_is_damaged_can_be_rebuilt(
    recording: RecordingFactory, tmp_path: Path
) -> None:
    """Its manifest still says it is lenspair's (as the readers decide); the card being
    unparsable read as another tool's card, refused even with --overwrite."""
    sources = _two(recording)
    out = tmp_path / "DS"
    build_dataset(sources, out, DatasetConfig(split=SEGMENTS))
    fresh = _tree(out)
    card = out / "dataset.json"
    card.write_bytes(card.read_bytes()[:300])
    with pytest.raises(DatasetError, match="holds a different dataset"):
        build_dataset(sources, out, DatasetConfig(split=SEGMENTS))
    build_dataset(sources, out, DatasetConfig(split=SEGMENTS), overwrite=True)
    assert _tree(out) == fresh


def test_a_hidden_file_in_an_image_folder_is_no_problem_and_no_difference(
    recording: RecordingFactory, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """macOS's Finder leaves ``.DS_Store`` in a folder it shows: --verify failed on it and the
    same rebuild was refused as a different dataset, though no loader reads it."""
    sources = [str(path) for path in _two(recording)]
    out = tmp_path / "DS"
    assert main(["dataset-build", *sources, "--out", str(out)]) == 0
    junk = out / "train" / "input" / ".DS_Store"
    junk.write_bytes(b"\x00\x00\x00\x01Bud1")
    capsys.readouterr()
    assert main(["dataset-build", "--verify", str(out)]) == 0, capsys.readouterr().out
    assert main(["dataset-build", *sources, "--out", str(out)]) == 0, capsys.readouterr().err
    assert junk.read_bytes() == b"\x00\x00\x00\x01Bud1"  # the user's, kept like other such files
    # an unlisted image is still named: a folder-reading loader would take it
    (out / "train" / "input" / "stray.png").write_bytes(b"png")
    capsys.readouterr()
    assert main(["dataset-build", "--verify", str(out)]) == 1
    assert "stray.png: not listed in manifest.jsonl" in capsys.readouterr().out


def test_an_unrelated_dataset_replaced_hands_on_no_grouping(
    recording: RecordingFactory, tmp_path: Path
) -> None:
    """group_by auto kept the grouping of whatever DS held, even a dataset of other
    recordings replaced with --overwrite: the build differed from one into a fresh folder."""
    split = SplitConfig(
        fractions=(0.5, 0.5, 0.0), min_groups_per_split=1, segment_frames=2, segment_gap_frames=0
    )
    config = DatasetConfig(split=split)
    out = tmp_path / "DS"
    assert build_dataset([recording("old", n=8)], out, config).card.grouping.mode == "segment"
    others = [recording("a", n=8), recording("b", n=8, seed=1)]
    replaced = build_dataset(others, out, config, overwrite=True)
    assert replaced.card.grouping.mode == "recording"
    assert not any("kept grouping" in w for w in replaced.card.grouping.warnings)
    build_dataset(others, tmp_path / "fresh", config)
    assert _tree(out) == _tree(tmp_path / "fresh")


def test_a_new_recording_fills_a_side_without_moving_the_earlier_dataset_s_pairs(
    recording: RecordingFactory, tmp_path: Path
) -> None:
    """Two cam0 recordings cannot cover three splits; a third let the side fix-up move the
    earlier d1 from train to val, so a network trained on the first version was validated
    on its own training frames (and into a new folder, without a word)."""
    sources = [recording(f"c{i}", n=3, seed=i) for i in range(6)]
    sources += [recording(f"d{i}", n=3, obstructed="cam0", seed=6 + i) for i in (1, 2)]
    config = DatasetConfig(split=SplitConfig(group_by="recording", seed=0))
    first = build_dataset(sources, tmp_path / "DS_v1", config)
    before = {row.recording: row.split for row in first.rows}
    grown = [*sources, recording("d3", n=3, obstructed="cam0", seed=9)]
    fresh = build_dataset(grown, tmp_path / "fresh", config)  # knows no earlier version
    assert {row.recording: row.split for row in fresh.rows}["d1"] != before["d1"]
    for out, previous in ((tmp_path / "DS_v2", tmp_path / "DS_v1"), (tmp_path / "DS_v1", None)):
        result = build_dataset(grown, out, config, previous=previous, overwrite=True)
        after = {row.recording: row.split for row in result.rows}
        assert {rid: after[rid] for rid in before} == before
        assert result.changed_splits is None
        assert {after[d] for d in ("d1", "d2", "d3")} == {"train", "val", "test"}


def test_previous_must_be_a_dataset(
    recording: RecordingFactory, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sources = [str(path) for path in _two(recording)]
    command = ["dataset-build", *sources, "--out", str(tmp_path / "DS")]
    assert main([*command, "--previous", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"{tmp_path}: not a dataset built by" in err
    verify = ["dataset-build", "--verify", str(tmp_path / "DS"), "--previous", str(tmp_path)]
    assert main(verify) == 2  # --previous means nothing to --verify: refused, not ignored
    assert "--verify takes only the dataset folder" in capsys.readouterr().err
    # nor do a seed, splits or a config: "OK" read as checked against them
    given = (["--seed", "3"], ["--seed", "0"], ["--min-sharpness", "0"], ["--link", "copy"])
    for extra in (*given, ["--splits", "0.5,0.5,0"], ["--config", str(tmp_path)]):
        assert main(["dataset-build", "--verify", str(tmp_path / "DS"), *extra]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and f"(and --workers): {extra[0]} would" in err


@pytest.mark.parametrize("broken", ["dataset.json", "manifest.jsonl"])
def test_a_previous_dataset_whose_card_or_manifest_cannot_be_read_is_refused(
    recording: RecordingFactory, tmp_path: Path, broken: str
) -> None:
    # its splits were dropped without a word: every pair hashed anew, and "28 pair(s)
    # changed split" said as if against that dataset
    sources = _two(recording)
    config = DatasetConfig(split=SplitConfig(fractions=(1.0, 0.0, 0.0)))
    build_dataset(sources, tmp_path / "v1", config)
    (tmp_path / "v1" / broken).write_text("{\n")
    with pytest.raises(DatasetError, match=rf"{broken}"):
        build_dataset(sources, tmp_path / "v2", config, previous=tmp_path / "v1")
    assert not (tmp_path / "v2").exists()


def test_every_build_option_is_refused_by_verify() -> None:
    # BUILD_ONLY is kept by hand: an option added to dataset-build without it would be
    # ignored by --verify, which then says "OK" as if it had checked against it
    parser = build_parser("dataset-build")
    (sub,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    command = sub.choices["dataset-build"]
    options = {
        action.dest: action.option_strings[-1]
        for action in command._actions
        if action.option_strings and action.dest not in ("help", "verbose")
    }
    verify_takes = {"verify", "workers"}
    assert {d: f for d, f in options.items() if d not in verify_takes} == BUILD_ONLY


READERS = {
    "train": ["train", "{DS}", "--out", "{tmp}/run"],
    "tradeoff": ["tradeoff", "{DS}", "--out", "{tmp}/trade"],
    "eval": ["eval", "{ckpt}", "--data", "{DS}/test"],  # a split folder locks its dataset
    "export": ["export", "{ckpt}", "--onnx", "{tmp}/m.onnx", "--int8", "--calibration", "{DS}"],
    "train_detector": ["train-detector", "{DS}", "--out", "{tmp}/detector"],
}
"""Each command reading a dataset, as a user types it (``DATASET_ARGUMENTS``)."""


def test_a_dataset_a_command_reads_is_not_replaced_under_it(
    recording: RecordingFactory, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # `dataset-build --overwrite` swapped DS under a running train: it died blaming a missing
    # pair, or went on over a mix of the two datasets where their file names agreed; eval,
    # export --calibration and train-detector read a dataset for minutes too
    sources = _two(recording)
    out = tmp_path / "DS"
    other = DatasetConfig(split=SplitConfig(seed=3))
    build_dataset(sources, out, DatasetConfig())
    before = _tree(out)
    refused = r"DS: another lenspair command \(train, .*\) is reading it"
    with (
        output_module.reading_datasets([out]),
        output_module.reading_datasets([out, out / "test"]),  # readers share it
        pytest.raises(DatasetError, match=refused),
    ):
        build_dataset(sources, out, other, overwrite=True)
    lock = output_module.DATASET_LOCK
    assert {k: v for k, v in _tree(out).items() if k != lock} == before  # nothing moved
    with (
        output_module.replacing(out),
        pytest.raises(DatasetError, match=r"DS: a dataset-build is replacing it"),
        output_module.reading_datasets([out]),
    ):
        pass
    seen: list[str] = []

    def reading(args: argparse.Namespace) -> int:  # what the command holds while it runs
        with pytest.raises(DatasetError, match=refused):
            build_dataset(sources, out, other, overwrite=True)
        seen.append("refused")
        return 0

    checkpoint = tmp_path / "best.pt"
    checkpoint.write_bytes(b"")
    for name, argv in READERS.items():
        monkeypatch.setattr(importlib.import_module(f"lenspair.commands.{name}"), "run", reading)
        assert main([a.format(DS=out, tmp=tmp_path, ckpt=checkpoint) for a in argv]) == 0, name
    assert seen == ["refused"] * len(READERS)
    build_dataset(sources, out, other, overwrite=True)  # once no command reads it
    assert lock not in _tree(out)  # the rebuilt dataset: its lock is its readers' to make
    assert _tree(out) != before


def test_every_command_naming_a_dataset_declares_it() -> None:
    # a command left out of DATASET_ARGUMENTS would read a dataset without its lock
    for name, (module_name, _) in COMMANDS.items():
        parser = build_parser(name)
        (sub,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        named = {
            action.dest
            for action in sub.choices[name]._actions
            if action.metavar == "DS" or action.dest in ("dataset", "data")
        }
        declared = getattr(importlib.import_module(module_name), "DATASET_ARGUMENTS", ())
        assert named == set(declared), name
    assert set(READERS) < {m.rsplit(".", 1)[1] for m, _ in COMMANDS.values()}
