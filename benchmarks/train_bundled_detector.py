"""Retrain the bundled anomaly detector (``calib_samples/detector.pt``) in one command.

    python -m benchmarks.train_bundled_detector --work WORK --checkpoint detector.pt \\
        --markdown detector.md [--device auto|cpu|cuda] [--minutes 6] [--steps 200000] \\
        [--workers 16] [--batch-size 64] [--per-kind 16] [--frames 12] \\
        [--synthetic 4000] [--hard 6000] [--seed 0] [--latency-runs 20]

Run it from a folder that is not the repository root (there the root's
``lenspair/`` folder shadows the installed package), with ``benchmarks``
importable (``PYTHONPATH=/path/to/repo``). What it does, each stage resuming
what a killed run finished in ``WORK``:

1. renders ``--per-kind`` simulated recordings of each kind (clean, rain,
   dust, dirt; :mod:`lenspair.model.detection.simset`) of ``--frames``
   frames under ``WORK/sims``, ``--workers`` recordings side by side;
2. holds the last two recordings of each kind out (never ingested, never
   trained on: scored as "test recordings");
3. ingests the others (``capture-ingest``, one process per recording) into
   ``WORK/ingested`` and builds the dataset ``WORK/DS`` (``dataset-build``,
   split by recording);
4. trains on the dataset's train split, the simulated recordings of that
   split, ``--synthetic`` synthetic frames over the built-in textures and
   ``--hard`` hard cases over the clean views of the training recordings
   (:mod:`lenspair.model.detection.hard_cases`), on ``--device`` for
   ``--steps`` steps or ``--minutes`` minutes, whichever ends first;
5. scores the dataset's val and test splits and the held-out recordings,
   runs the hard cases of issue #14 (:mod:`benchmarks.detector_issue_checks`)
   and, with ``--latency-runs N > 0``, :mod:`benchmarks.bench_detector`
   (CPU, 1 thread);
6. copies the checkpoint to ``--checkpoint``, writes ``--markdown`` (the
   text of ``docs/results/detector.md``, with this exact command) and, beside
   it, the same figures as JSON (``detector.json``: command, training,
   scores, hard cases, latency), from which
   ``python -m benchmarks.readme_results --detector-only`` writes the
   README's detector figures.
"""

import argparse
import json
import shlex
import shutil
import sys
import time
from dataclasses import asdict
from functools import partial
from pathlib import Path

import torch

from benchmarks import bench_detector
from benchmarks.detector_issue_checks import checks_markdown, issue_checks
from lenspair.capture.ingest import ingest_recording
from lenspair.commands.argtypes import positive_int
from lenspair.core.device import resolve_device
from lenspair.core.fsutil import atomic_write_json, remove_path
from lenspair.dataset.build import build_dataset
from lenspair.dataset.config import load_dataset_config
from lenspair.dataset.manifest import read_manifest
from lenspair.model.detection.parallel import process_map
from lenspair.model.detection.run import DETECTOR_FILE, DetectorSources, run_training
from lenspair.model.detection.score import DetectionScores, scores_markdown
from lenspair.model.detection.simset import simulate_kind_set
from lenspair.model.detection.train import DetectorTraining, load_detector
from lenspair.model.networks.detector import DetectorSpec

HELD_OUT = 2
"""Recordings of each kind never ingested nor trained on."""


def _ingest(recording: Path, out: Path) -> str:
    """Ingest one recording (in a worker process); returns its folder under ``out``."""
    if not (out / recording.name / "report.json").is_file():
        ingest_recording(recording, out)
    return str(out / recording.name)


def _held_out(paths: list[Path]) -> tuple[list[Path], list[Path]]:
    """``(others, held_out)``: the last :data:`HELD_OUT` recordings of each kind held out."""
    kinds: dict[str, list[Path]] = {}
    for path in paths:
        kinds.setdefault(path.name.rsplit("_", 1)[0], []).append(path)
    held = [p for group in kinds.values() for p in group[-HELD_OUT:]]
    return [p for p in paths if p not in held], held


def prepare_data(
    work: Path, per_kind: int, frames: int, seed: int, workers: int
) -> tuple[Path, list[Path], list[Path]]:
    """Stages 1-3: ``(dataset, train recordings, held-out recordings)``."""
    started = time.perf_counter()
    paths = simulate_kind_set(work / "sims", per_kind, frames, seed, workers)
    print(f"simulated {len(paths)} recordings in {time.perf_counter() - started:.0f} s")
    others, held = _held_out(paths)
    started = time.perf_counter()
    ingested_root = work / "ingested"
    ingest = partial(_ingest, out=ingested_root)
    ingested = [Path(folder) for folder in process_map(ingest, others, workers)]
    print(f"ingested {len(ingested)} recordings in {time.perf_counter() - started:.0f} s")
    dataset = work / "DS"
    build_dataset(ingested, dataset, load_dataset_config(None), overwrite=True, workers=workers)
    train_ids = {
        row.recording for row in read_manifest(dataset / "manifest.jsonl") if row.split == "train"
    }
    train = [path for path in others if path.name in train_ids]
    return dataset, train, held


def document(
    command: str,
    run: dict,  # type: ignore[type-arg]
    scores: dict[str, DetectionScores],
    checks: str,
    latency: str,
) -> str:
    """The Markdown of ``docs/results/detector.md`` for one run."""
    training, settings = run["training"], run["settings"]
    lines = [
        "# The bundled anomaly detector: held-out scores beside latency",
        "",
        "Scored as the soiling-detection literature does: per-frame accuracy and F1",
        "of obstructed/clean (obstructed is the positive class), a per-kind",
        "confusion matrix (rows: truth), and tile IoU of the map (covered tiles,",
        "map > 0.5, against covered tiles in truth over all frames). Held out by",
        "recording, never by frame. The data: simulated recordings of each kind",
        "(`SCENE_KINDS` of `model/detection/simset.py`: clean glass, rain, dust, dirt;",
        "own seed, textures, direction and obstructed camera); the last two of each",
        'kind are never ingested nor trained on ("test recordings"); the others are',
        "ingested and built into a dataset `DS` split by recording; training adds",
        "synthetic anomalies over the simulator's textures and the hard cases of",
        "issue #14 (`model/detection/hard_cases.py`: defocused, dark and bright,",
        "low-texture clean frames; dust darkening the whole frame; light rain).",
        "",
        "Made by one command (`benchmarks/train_bundled_detector.py`):",
        "",
        "```sh",
        command,
        "```",
        "",
        f"Training: {training['steps']} steps of {settings['batch_size']} windows in "
        f"{training['seconds']:.0f} s on `{run['device']}` "
        f"({training['samples']} training frames, {run['counts']['train_obstructed']} "
        f"obstructed); mean loss {training['first_loss']:.3f} over the first 20 steps, "
        f"{training['last_loss']:.3f} over the last 20.",
        "",
    ]
    lines += [scores_markdown(name, result) for name, result in scores.items()]
    lines += [
        "The hard cases of issue #14 (`benchmarks/detector_issue_checks.py`; the same",
        "cases as the tests `tests/model/test_detector_hard_cases.py` and",
        "`tests/capture/test_side_detector_ingest.py`):",
        "",
        checks,
    ]
    if latency:
        lines += [
            "Latency, `python -m benchmarks.bench_detector` (ratios are the figures to",
            "read; absolute times move with the machine's load):",
            "",
            latency,
        ]
    lines += [
        "Train longer, and on your own rig's data, before relying on it.",
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Command line (module docstring); returns the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--work", type=Path, required=True, help="work folder (resumable)")
    parser.add_argument("--checkpoint", type=Path, required=True, help="where to copy detector.pt")
    parser.add_argument("--markdown", type=Path, required=True, help="the scores document")
    parser.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    parser.add_argument("--steps", type=positive_int, default=200_000)
    parser.add_argument("--minutes", type=float, default=None)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--batch-size", type=int, default=64)
    parser.add_argument("--learning-rate", type=float, default=3e-3)
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads (1)")
    parser.add_argument("--per-kind", type=int, default=16, help="recordings per kind (16)")
    parser.add_argument("--frames", type=positive_int, default=12, help="frames per recording (12)")
    parser.add_argument("--synthetic", type=int, default=4000)
    parser.add_argument("--hard", type=int, default=6000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--latency-runs", type=int, default=20, help="0: no latency table")
    args = parser.parse_args(argv)
    if args.per_kind < HELD_OUT + 2 or args.workers < 1 or args.steps < 1:
        parser.error(f"--per-kind >= {HELD_OUT + 2}, --workers >= 1 and --steps >= 1 expected")
    torch.set_num_threads(args.threads)
    device = resolve_device(args.device)
    work = args.work.resolve()
    dataset, train, held = prepare_data(work, args.per_kind, args.frames, args.seed, args.workers)
    sources = DetectorSources(
        datasets=(dataset,),
        recordings=tuple(train),
        test_recordings=tuple(held),
        synthetic=args.synthetic,
        hard=args.hard,
    )
    settings = DetectorTraining(
        steps=args.steps,
        batch_size=args.batch_size,
        learning_rate=args.learning_rate,
        seed=args.seed,
        max_seconds=None if args.minutes is None else 60.0 * args.minutes,
        threads=args.threads,
    )
    out = work / "run"
    remove_path(out)  # a rerun trains again (run_training refuses to replace a run)
    scores = run_training(
        out, sources, DetectorSpec(), settings, device=device, workers=args.workers
    )
    run = json.loads((out / "run.json").read_text())
    network = load_detector(out / DETECTOR_FILE, device)
    cases = issue_checks(network, work / "issue")
    checks = checks_markdown(cases)
    latency, timing = "", None
    if args.latency_runs > 0:
        timing = bench_detector.run(args.latency_runs, 1)
        latency = bench_detector.markdown(timing)
    command = "python -m benchmarks.train_bundled_detector " + shlex.join(
        sys.argv[1:] if argv is None else argv
    )
    args.checkpoint.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(out / DETECTOR_FILE, args.checkpoint)
    args.markdown.parent.mkdir(parents=True, exist_ok=True)
    args.markdown.write_text(document(command, run, scores, checks, latency))
    figures = {
        "command": command,
        "training": run["training"],
        "device": run["device"],
        "scores": {name: asdict(s) for name, s in scores.items()},
        "hard_cases": [asdict(case) for case in cases],
        "latency": timing,
    }
    atomic_write_json(args.markdown.with_suffix(".json"), figures)
    print(args.markdown.read_text())
    print(f"wrote {args.checkpoint} and {args.markdown}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
