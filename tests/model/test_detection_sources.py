"""Names of the detector's held-out sets: one per dataset split, even for namesake folders."""

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from lenspair.cli import main
from lenspair.core.imagewrite import write_image
from lenspair.dataset.manifest import ManifestRow, SplitName, read_manifest, write_manifest
from lenspair.model.detection import run as detection_run
from lenspair.model.detection.data import UNKNOWN_KIND, DetectorSample, dataset_samples
from lenspair.model.detection.sources import DetectorSources, distinct_names, gather
from lenspair.model.networks.detector import DetectorSpec
from tests.model.train_fixtures import clean_image, obstruct

SPEC = DetectorSpec(input_size=(32, 48))
COUNTS: dict[SplitName, int] = {"train": 2, "val": 1, "test": 1}
SPLITS = ("val", "test")


def _row(
    split: SplitName, name: str, index: int, anomaly: tuple[str, ...] = ("rain",)
) -> ManifestRow:
    """A pair of recording ``rec`` labelled ``anomaly`` (rain)."""
    return ManifestRow(
        split=split, name=name, recording="rec", group="rec", t_ns=index, obstructed="cam1",
        clean="cam0", difficulty="easy", psnr_db=25.0, anomaly_fraction=0.1, sharpness=100.0,
        saturated=0.0, black=0.0, mask_fraction=0.0, anomaly=anomaly,
    )  # fmt: skip


def _dataset(
    root: Path,
    seed: int,
    counts: dict[SplitName, int] = COUNTS,
    anomaly: tuple[str, ...] = ("rain",),
) -> Path:
    """A lenspair dataset of 48x32 pairs labelled ``anomaly``: ``counts`` pairs per split."""
    rng = np.random.default_rng(seed)
    rows = []
    for split, count in counts.items():
        for index in range(count):
            name = f"rec_{index}"
            clean = clean_image(rng)
            write_image(root / split / "input" / f"{name}.png", obstruct(clean, rng))
            write_image(root / split / "target" / f"{name}.png", clean)
            rows.append(_row(split, name, index, anomaly))
    write_manifest(root / "manifest.jsonl", rows)
    return root


def test_distinct_names_are_the_shortest_suffix_that_tells_folders_apart(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    paths = [Path("siteA/x/dataset"), Path("siteB/x/dataset"), Path("siteC/y/dataset")]
    assert distinct_names(paths) == ["siteA/x/dataset", "siteB/x/dataset", "y/dataset"]
    assert distinct_names([Path("siteA/dataset"), Path("other")]) == ["dataset", "other"]
    # "." is named by the folder it is, not by "" (Path(".").name)
    (tmp_path / "here").mkdir()
    monkeypatch.chdir(tmp_path / "here")
    assert distinct_names([Path(".")]) == ["here"]
    # a folder whose whole path ends another's: the root tells them apart
    assert distinct_names([Path("/a/b"), Path("/x/a/b")]) == ["/a/b", "x/a/b"]


def test_namesake_datasets_each_have_their_held_out_sets(tmp_path: Path) -> None:
    first = _dataset(tmp_path / "siteA" / "dataset", seed=1)
    second = _dataset(tmp_path / "siteB" / "dataset", seed=2, counts={**COUNTS, "val": 3})
    train, held_out = gather(DetectorSources(datasets=(first, second)), SPEC, seed=0)
    assert len(train) == 2 * 2 * 2  # two pairs each, both views
    # both named "dataset" once: one dataset's val and test replaced the other's
    assert {name: len(samples) for name, samples in held_out.items()} == {
        "dataset siteA/dataset, split val": 2,
        "dataset siteA/dataset, split test": 2,
        "dataset siteB/dataset, split val": 6,
        "dataset siteB/dataset, split test": 2,
    }


def test_train_detector_scores_namesake_datasets_apart(tmp_path: Path) -> None:
    first = _dataset(tmp_path / "demo" / "dataset", seed=1)
    second = _dataset(tmp_path / "dsB" / "dataset", seed=2)
    out = tmp_path / "run"
    argv = ["train-detector", str(first), str(second), "--out", str(out), "--steps", "1"]
    assert main([*argv, "--batch-size", "2", "--input-size", "48x32"]) == 0
    names = [
        f"dataset {site}/dataset, split {split}" for site in ("demo", "dsB") for split in SPLITS
    ]
    assert sorted(json.loads((out / "scores.json").read_text())) == sorted(names)
    scores = (out / "scores.md").read_text()
    assert all(f"**{name}**" in scores for name in names)


def test_train_detector_refuses_a_training_set_of_one_class(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    # --synthetic 1 renders one clean frame: a detector.pt was trained on it without a word
    out = tmp_path / "run"
    argv = ["train-detector", "--out", str(out), "--steps", "1", "--input-size", "48x32"]
    assert main([*argv, "--synthetic", "1"]) == 2
    error = capsys.readouterr().err.strip()
    assert "the training set holds 1 clean and 0 obstructed frames" in error
    assert "add obstructed frames with a larger --synthetic" in error and "\n" not in error
    assert not out.exists()  # refused before the run folder is made
    # no clean frame at all (every source gives some: dataset targets, synthetic frames)
    rain = DetectorSample(
        np.zeros(SPEC.input_size, np.float32), 1, np.ones(SPEC.grid, np.float32),
        np.ones(SPEC.grid, bool), "r.png", "rec",
    )  # fmt: skip
    monkeypatch.setattr(detection_run, "gather", lambda *args: ([rain, rain], {}))
    assert main([*argv, "--synthetic", "2"]) == 2
    error = capsys.readouterr().err.strip()
    assert "holds 0 clean and 2 obstructed frames" in error and "add clean frames" in error
    assert not out.exists()


def test_pairs_without_anomaly_labels_are_obstructed_unless_tagged_clean(tmp_path: Path) -> None:
    """capture-ingest --obstructed without rig.yaml writes "anomaly": []: the difficulty decides.

    Taken for clean frames, such a dataset was refused ("0 obstructed frames"),
    or, beside other data, taught that rain is clean and scored 0 positives.
    """
    dataset = _dataset(tmp_path / "ds", seed=3, counts={"train": 3, "val": 1}, anomaly=())
    rows = read_manifest(dataset / "manifest.jsonl")
    rows[1] = replace(rows[1], difficulty="clean")  # the views barely differ: two negatives
    write_manifest(dataset / "manifest.jsonl", rows)
    kinds = [sample.kind for sample in dataset_samples(dataset, "train", SPEC)]
    assert kinds == [UNKNOWN_KIND, 0, 0, 0, UNKNOWN_KIND, 0]  # input, target of each pair
    out = tmp_path / "run"
    argv = ["train-detector", str(dataset), "--out", str(out), "--steps", "1"]
    assert main([*argv, "--batch-size", "2", "--input-size", "48x32"]) == 0
    assert json.loads((out / "run.json").read_text())["counts"]["train_obstructed"] == 2
    (scores,) = json.loads((out / "scores.json").read_text()).values()  # the val split
    assert (scores["frames"], scores["positives"]) == (2, 1)
    assert sum(map(sum, scores["confusion"])) == 1  # its kind unknown: only the clean view
