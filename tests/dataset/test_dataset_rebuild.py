"""Rebuilding into an existing dataset: identical reruns accepted, refusals taken early."""

from pathlib import Path

import pytest

from lenspair.cli import main
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
