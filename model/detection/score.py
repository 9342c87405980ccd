"""Scoring a detector the way soiling-detection papers do.

Per frame: accuracy and F1 of the obstructed/clean answer (obstructed is the
positive class), a confusion matrix of the kind (rows: truth, columns: the
detector's answer, both over :data:`KINDS`; positives of unknown kind are left
out of it), and the tile IoU of the map: covered tiles predicted (map > 0.5)
against covered tiles in truth, summed over all valid tiles of all frames
(``|P & T| / |P | T|``; frames without any covered tile in truth or
prediction add nothing).
"""

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lenspair.model.detection.data import UNKNOWN_KIND, DetectorSample
from lenspair.model.detection.judge import Judgement
from lenspair.model.networks.detector import KINDS


@dataclass(frozen=True)
class DetectionScores:
    """Scores of one evaluation set.

    Attributes:
        frames: frames scored.
        positives: obstructed frames in truth.
        accuracy: share of frames whose obstructed/clean answer is right.
        precision: of frames called obstructed, the share that are.
        recall: of obstructed frames, the share called obstructed.
        f1: harmonic mean of precision and recall (0 when both are 0).
        tile_iou: the module docstring's tile IoU (NaN when no tile is covered anywhere).
        confusion: ``confusion[truth][answer]`` frame counts over :data:`KINDS`.
    """

    frames: int
    positives: int
    accuracy: float
    precision: float
    recall: float
    f1: float
    tile_iou: float
    confusion: list[list[int]]


def score(samples: Sequence[DetectorSample], verdict: Judgement) -> DetectionScores:
    """Score a :class:`Judgement` against the samples it was computed on (same order)."""
    truth = np.array([s.obstructed for s in samples], dtype=bool)
    called = verdict.obstructed
    if truth.shape != called.shape:
        raise ValueError(f"{len(truth)} samples but {len(called)} judgements")
    true_positive = int(np.sum(truth & called))
    precision = true_positive / max(1, int(called.sum()))
    recall = true_positive / max(1, int(truth.sum()))
    f1 = 2 * precision * recall / (precision + recall) if precision + recall else 0.0
    confusion = np.zeros((len(KINDS), len(KINDS)), dtype=int)
    for sample, answer in zip(samples, verdict.kinds, strict=True):
        if sample.kind != UNKNOWN_KIND:
            confusion[sample.kind, KINDS.index(answer)] += 1
    intersection = union = 0
    for sample, tile_map in zip(samples, verdict.maps, strict=True):
        predicted = (tile_map > 0.5) & sample.valid
        covered = (sample.tiles > 0.5) & sample.valid
        intersection += int(np.sum(predicted & covered))
        union += int(np.sum(predicted | covered))
    return DetectionScores(
        frames=len(samples),
        positives=int(truth.sum()),
        accuracy=float(np.mean(truth == called)) if len(truth) else float("nan"),
        precision=precision,
        recall=recall,
        f1=f1,
        tile_iou=intersection / union if union else float("nan"),
        confusion=confusion.tolist(),
    )


def scores_markdown(name: str, scores: DetectionScores) -> str:
    """A Markdown summary: one line of figures and the confusion matrix."""
    lines = [
        f"**{name}**: {scores.frames} frames ({scores.positives} obstructed); "
        f"accuracy {scores.accuracy:.3f}, F1 {scores.f1:.3f} "
        f"(precision {scores.precision:.3f}, recall {scores.recall:.3f}), "
        f"tile IoU {scores.tile_iou:.3f}",
        "",
        "| truth \\ answer | " + " | ".join(KINDS) + " |",
        "|---|" + "---|" * len(KINDS),
    ]
    for kind, row in zip(KINDS, scores.confusion, strict=True):
        lines.append(f"| {kind} | " + " | ".join(str(v) for v in row) + " |")
    return "\n".join(lines) + "\n"
