"""The split gap in built datasets: counted in surviving frames, never emptying train."""

import itertools
import json
from pathlib import Path

import pytest

from lenspair.cli import main
from lenspair.dataset import splits as splits_module
from lenspair.dataset.build import build_dataset
from lenspair.dataset.config import DatasetConfig, SplitConfig
from lenspair.dataset.errors import DatasetError
from lenspair.dataset.manifest import read_manifest
from tests.dataset.dataset_synth import DT_NS, T0_NS, RecordingFactory


def _index(t_ns: int) -> int:
    return (t_ns - T0_NS) // DT_NS


def test_a_gap_that_drops_trains_only_pairs_moves_a_group_that_keeps_some(
    recording: RecordingFactory, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Train's one segment (two pairs) lay before a border to test: the gap dropped both
    and the build ended with exit 0 and "train 0 pairs"."""
    source = recording("r", n=10, rejected=(0, 1, 2))
    config = tmp_path / "seg.yaml"
    config.write_text(
        "split: {group_by: segment, segment_frames: 5, segment_gap_frames: 2, seed: 4}\n"
    )
    out = tmp_path / "DS"
    assert main(["dataset-build", str(source), "--out", str(out), "--config", str(config)]) == 0
    printed = capsys.readouterr().out
    rows = read_manifest(out / "manifest.jsonl")
    assert any(row.split == "train" for row in rows), printed
    assert "dropped every pair of train; moved r#s00001 from test to train" in printed


def test_the_gap_is_counted_in_frames_that_survived_curation(
    recording: RecordingFactory, tmp_path: Path
) -> None:
    """Frames 2-6 repeat frame 1 (a robot standing still) and are removed as duplicates;
    the gap of lines 3-4 removed nothing more, so frame 1 (train) and frame 7 (val), five
    pixels apart, straddled a border."""
    source = recording("still", n=15, still=(2, 3, 4, 5, 6))
    gap, borders = 2, 0
    for seed in range(6):
        split = SplitConfig(
            fractions=(0.5, 0.25, 0.25),
            group_by="segment",
            segment_frames=5,
            segment_gap_frames=gap,
            seed=seed,
        )
        out = tmp_path / f"DS{seed}"
        result = build_dataset([source], out, DatasetConfig(split=split))
        removed = [json.loads(line) for line in (out / "removed.jsonl").read_text().splitlines()]
        # what survived curation, in time order: a split, or dropped by the gap
        survivors = sorted(
            [(_index(row.t_ns), row.split) for row in result.rows]
            + [(_index(r["t_ns"]), "gap") for r in removed if r["rule"] == "split_gap"]
        )
        kept = [n for n, (_, where) in enumerate(survivors) if where != "gap"]
        for a, b in itertools.pairwise(kept):
            if survivors[a][1] != survivors[b][1]:  # a border: `gap` survivors dropped between
                borders += 1
                assert b - a - 1 >= gap, (seed, survivors)
    assert borders  # some seeds put the segments into two splits


def test_a_gap_leaving_train_empty_is_refused_not_written(
    recording: RecordingFactory, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The last check after the gap: should a plan ever leave train without pairs, the
    build says so and what to change instead of writing a dataset with nothing to train on."""
    source = recording("r", n=10)
    split = SplitConfig(group_by="segment", segment_frames=5, segment_gap_frames=2)

    def every_train_pair(items, plan, config):  # type: ignore[no-untyped-def]
        return {
            item
            for item in items
            if plan.assignment[splits_module.group_id(item.recording, item.index, plan.mode, 5)]
            == "train"
        }

    monkeypatch.setattr(splits_module, "gap_items", every_train_pair)
    out = tmp_path / "DS"
    with pytest.raises(DatasetError, match=r"^split: the gap of segment_gap_frames 2 .* left "
                       r"train without pairs .*smaller split\.segment_gap_frames"):  # fmt: skip
        build_dataset([source], out, DatasetConfig(split=split))
    assert not out.exists()
