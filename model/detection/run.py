"""The ``train-detector`` run: gather samples, train, score held-out data, write files.

Output folder ``RUN``: ``detector.pt`` (checkpoint), ``scores.json`` and
``scores.md`` (per held-out set: accuracy, F1, kind confusion matrix, tile
IoU, see :mod:`lenspair.model.detection.score`), ``run.json`` (settings,
sources, sample counts, training summary).
"""

import json
import logging
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from lenspair.core.fsutil import atomic_write_json, atomic_write_text
from lenspair.core.imageio import from_float, read_image
from lenspair.model.detection.data import (
    DetectorSample,
    dataset_samples,
    recording_samples,
    synthetic_samples,
    texture_images,
)
from lenspair.model.detection.judge import judge
from lenspair.model.detection.score import DetectionScores, score, scores_markdown
from lenspair.model.detection.simset import simulate_kind_set, split_by_recording
from lenspair.model.detection.train import DetectorTraining, save_detector, train_detector
from lenspair.model.errors import ModelError
from lenspair.model.networks.detector import AnomalyDetector, DetectorSpec
from lenspair.model.training.synthetic import find_clean_images

log = logging.getLogger(__name__)

DETECTOR_FILE = "detector.pt"


@dataclass(frozen=True)
class DetectorSources:
    """Where the samples come from.

    Attributes:
        datasets: lenspair dataset roots (train split trained on, val and test scored).
        recordings: simulated recordings trained on (``truth/mask/``).
        test_recordings: simulated recordings only scored.
        synthetic: synthetic samples to render (0: none).
        clean_folder: clean images for synthetic samples; None: the built-in textures.
        simulated_set: folder for :func:`simulate_kind_set` (None: not used);
            its held-out recordings are scored.
        set_per_kind: recordings per kind in the simulated set.
        set_frames: frames per simulated recording.
        max_frames: per camera and recording, frames used.
    """

    datasets: tuple[Path, ...] = ()
    recordings: tuple[Path, ...] = ()
    test_recordings: tuple[Path, ...] = ()
    synthetic: int = 0
    clean_folder: Path | None = None
    simulated_set: Path | None = None
    set_per_kind: int = 3
    set_frames: int = 6
    max_frames: int = 12


def _clean_images(folder: Path | None) -> list[np.ndarray]:
    if folder is None:
        return texture_images()
    return [read_image(path) for path in find_clean_images(folder)[:200]]


def gather(
    sources: DetectorSources, spec: DetectorSpec, seed: int
) -> tuple[list[DetectorSample], dict[str, list[DetectorSample]]]:
    """Training samples and named held-out sets from ``sources``.

    Raises:
        ModelError: nothing to train on.
    """
    train: list[DetectorSample] = []
    held_out: dict[str, list[DetectorSample]] = {}
    for root in sources.datasets:
        train += dataset_samples(root, "train", spec)
        for split in ("val", "test"):  # no model selection here: both are held out
            try:
                held_out[f"dataset {Path(root).name}, split {split}"] = dataset_samples(
                    root, split, spec
                )
            except ModelError as exc:
                log.warning("%s: split %s not scored (%s)", root, split, exc)
    recordings = list(sources.recordings)
    test_recordings = list(sources.test_recordings)
    if sources.simulated_set is not None:
        paths = simulate_kind_set(
            sources.simulated_set, sources.set_per_kind, sources.set_frames, seed
        )
        set_train, set_test = split_by_recording(paths)
        recordings += set_train
        held = [s for p in set_test for s in recording_samples(p, spec, sources.max_frames)]
        names = ", ".join(p.name for p in set_test)
        held_out[f"held-out simulated recordings ({names})"] = held
    for path in recordings:
        train += recording_samples(path, spec, sources.max_frames)
    if test_recordings:
        held = [s for p in test_recordings for s in recording_samples(p, spec, sources.max_frames)]
        held_out["test recordings"] = held
    if sources.synthetic:
        rng = np.random.default_rng(seed)
        train += synthetic_samples(
            _clean_images(sources.clean_folder), sources.synthetic, spec, rng
        )
    if not train:
        raise ModelError("train-detector: no training data; give DS/recordings or --synthetic N")
    return train, held_out


def score_sets(
    network: AnomalyDetector, sets: dict[str, list[DetectorSample]]
) -> dict[str, DetectionScores]:
    """Judge and score each named set (images passed as 16-bit, the judge's input)."""
    results = {}
    for name, samples in sets.items():
        images = [from_float(s.image, np.uint16) for s in samples]
        results[name] = score(samples, judge(network, images))
    return results


def run_training(
    out: Path, sources: DetectorSources, spec: DetectorSpec, settings: DetectorTraining
) -> dict[str, DetectionScores]:
    """Gather, train, score and write ``out/`` (module docstring); returns the scores."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    train, held_out = gather(sources, spec, settings.seed)
    counts = {"train": len(train), "train_obstructed": sum(s.obstructed for s in train)}
    log.info("training on %d frames (%d obstructed)", counts["train"], counts["train_obstructed"])
    network, summary = train_detector(train, spec, settings)
    scores = score_sets(network, held_out)
    run = {
        "spec": asdict(spec),
        "settings": asdict(settings),
        "sources": {k: str(v) for k, v in asdict(sources).items()},
        "counts": counts | {name: len(s) for name, s in held_out.items()},
        "training": asdict(summary),
    }
    save_detector(out / DETECTOR_FILE, network, {"run": json.dumps(run, default=str)})
    atomic_write_json(out / "scores.json", {name: asdict(s) for name, s in scores.items()})
    atomic_write_json(out / "run.json", json.loads(json.dumps(run, default=str)))
    text = "".join(scores_markdown(name, s) + "\n" for name, s in scores.items())
    atomic_write_text(out / "scores.md", text or "no held-out data scored\n")
    return scores
