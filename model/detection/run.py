"""The ``train-detector`` run: gather samples, train, score held-out data, write files.

Output folder ``RUN``: ``detector.pt`` (checkpoint), ``scores.json`` and
``scores.md`` (per held-out set: accuracy, F1, kind confusion matrix, tile
IoU, see :mod:`lenspair.model.detection.score`), ``run.json`` (settings,
sources, sample counts, training summary).
"""

import json
import logging
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from lenspair.core.config import to_plain
from lenspair.core.folderlock import holding
from lenspair.core.fsutil import atomic_write_files, check_writable, json_text
from lenspair.core.pixels import from_float
from lenspair.model.detection.data import DetectorSample
from lenspair.model.detection.judge import judge
from lenspair.model.detection.score import DetectionScores, score, scores_markdown
from lenspair.model.detection.sources import DetectorSources, gather
from lenspair.model.detection.train import DetectorTraining, detector_bytes, train_detector
from lenspair.model.errors import ModelError
from lenspair.model.networks.detector import AnomalyDetector, DetectorSpec

log = logging.getLogger(__name__)

__all__ = ["DETECTOR_FILE", "DetectorSources", "gather", "run_training", "score_sets"]

DETECTOR_FILE = "detector.pt"

RUN_FILES = (DETECTOR_FILE, "run.json", "scores.json", "scores.md")
"""What a run writes into its folder; a folder holding any of them is refused."""

LOCK_FILE = ".lock"
"""The file a run locks in its folder while it trains there (:func:`_one_writer`)."""


def score_sets(
    network: AnomalyDetector, sets: dict[str, list[DetectorSample]]
) -> dict[str, DetectionScores]:
    """Judge and score each named set (images passed as 16-bit, the judge's input).

    The images are on the full 16-bit scale (``bits=16``): a set of dark
    samples must not be taken for 10- or 12-bit values and brightened.
    """
    results = {}
    for name, samples in sets.items():
        images = [from_float(s.image, np.uint16) for s in samples]
        results[name] = score(samples, judge(network, images, bits=16))
    return results


MORE_OF = {
    "obstructed": "a larger --synthetic (three frames in four get rain, dust or dirt), a "
    "dataset DS or --recordings",
    "clean": "a larger --synthetic (every fourth frame is left clean) or a dataset DS (its "
    "target views are clean)",
}
"""Where ``train-detector`` finds more frames of each class, for :func:`check_both_classes`."""


def check_both_classes(train: list[DetectorSample]) -> None:
    """Refuse a training set without clean or without obstructed frames.

    Trained on one class, the detector learns to answer it for every frame,
    and such a detector.pt was written without a word (``--synthetic 1``: one
    clean frame).

    Raises:
        ModelError: naming how many frames of each class there are and what adds the missing one.
    """
    obstructed = sum(sample.obstructed for sample in train)
    clean = len(train) - obstructed
    if obstructed and clean:
        return
    missing = "obstructed" if not obstructed else "clean"
    raise ModelError(
        f"the training set holds {clean} clean and {obstructed} obstructed frames; the "
        f"detector needs both to learn to tell them apart: add {missing} frames with "
        f"{MORE_OF[missing]}"
    )


def run_training(
    out: Path,
    sources: DetectorSources,
    spec: DetectorSpec,
    settings: DetectorTraining,
    *,
    device: torch.device | str = "cpu",
    workers: int = 1,
) -> dict[str, DetectionScores]:
    """Gather, train, score and write ``out/`` (module docstring); returns the scores.

    Args:
        out: the run folder (refused if it holds any of :data:`RUN_FILES`).
        sources: where the samples come from.
        spec: the architecture.
        settings: training settings.
        device: where to train and score (resolved by the caller).
        workers: processes gathering samples (:func:`gather`).

    Raises:
        ModelError: ``out`` holds an earlier run, or another run is writing
            it; no usable samples, or no clean or no obstructed one
            (:func:`check_both_classes`).
        OSError: ``out`` cannot be written (said before the training), or a
            full disk while writing (none of the run's files is left).
    """
    out = Path(out)
    _check_free(out)
    check_writable(out / DETECTOR_FILE)  # a read-only --out is said now, not after the training
    train, held_out = gather(sources, spec, settings.seed, workers)
    check_both_classes(train)
    out.mkdir(parents=True, exist_ok=True)  # after the inputs are found good: none left empty
    with _one_writer(out):
        _check_free(out)  # another run may have finished here while this one gathered
        return _train_and_write(out, train, held_out, spec, settings, device, workers, sources)


def _check_free(out: Path) -> None:
    """Refuse a folder holding any of a run's files: a detector is never replaced unasked."""
    held = [name for name in RUN_FILES if (out / name).exists()]
    if held:  # a detector can be half an hour of CPU
        raise ModelError(
            f"{out} already holds a detector run ({', '.join(held)}); choose another --out, "
            "or move them aside to train again there"
        )


@contextmanager
def _one_writer(out: Path) -> Iterator[None]:
    """Hold ``out``'s lock while training into it: a second run there is refused at once.

    Two runs with one ``--out`` both trained to the end and the last one's
    files replaced the first's. The lock is ``flock`` on :data:`LOCK_FILE`
    (:func:`~lenspair.core.folderlock.holding`), released however the
    process ends.
    """
    taken = ModelError(
        f"{out}: another train-detector is writing it; run this one when that one has "
        "finished, or with another --out"
    )
    with holding(out / LOCK_FILE, "train-detector", taken):
        yield


def _train_and_write(
    out: Path,
    train: list[DetectorSample],
    held_out: dict[str, list[DetectorSample]],
    spec: DetectorSpec,
    settings: DetectorTraining,
    device: torch.device | str,
    workers: int,
    sources: DetectorSources,
) -> dict[str, DetectionScores]:
    """Train on ``train``, score ``held_out``, and write the run's files: all of them or none."""
    counts = {"train": len(train), "train_obstructed": sum(s.obstructed for s in train)}
    log.info("training on %d frames (%d obstructed)", counts["train"], counts["train_obstructed"])
    network, summary = train_detector(train, spec, settings, device)
    scores = score_sets(network, held_out)
    run = {
        "spec": asdict(spec),
        "settings": asdict(settings),
        "device": str(device),
        "workers": workers,
        "sources": to_plain(sources),
        "counts": counts | {name: len(s) for name, s in held_out.items()},
        "training": asdict(summary),
    }
    run_json = json.dumps(run, default=str)  # the file's, and the checkpoint's record
    text = "".join(scores_markdown(name, s) + "\n" for name, s in scores.items())
    # the detector last: a folder holding it holds the whole run (a full disk or a
    # file-size limit leaves none of them, and the same command can be run again)
    files = {
        out / "scores.json": json_text({name: asdict(s) for name, s in scores.items()}),
        out / "run.json": json_text(json.loads(run_json)),
        out / "scores.md": text or "no held-out data scored\n",
    }
    atomic_write_files(
        {path: content.encode("utf-8") for path, content in files.items()}
        | {out / DETECTOR_FILE: detector_bytes(network, {"run": run_json})}
    )
    return scores
