"""The main job end to end on the bundled sample scenes (``lenspair demo``).

Stages, each one a ``lenspair`` subcommand run in-process with the same
arguments a user would type (printed as it runs, so the demo doubles as a
tutorial):

1. ``simulate`` a chessboard session and two anomaly recordings: rain with
   cam1 obstructed and dust with the sides swapped (cam0 obstructed);
2. ``calibrate`` from the board session;
3. ``capture-ingest`` both recordings with that calibration;
4. ``dataset-build`` the two ingested recordings into train/val/test;
5. ``train --synthetic``: pretraining on drops rendered over clean frames;
6. ``train --init``: a short fine-tune on the real (here: simulated) pairs;
7. ``eval`` on the test split, 8. a small ``tradeoff``;

then ``report.md`` and ``report.html`` gather the figures. A stage whose
outputs are complete (a marker in ``OUT/.stages`` with the same arguments)
is reused on a rerun; an unfinished stage is cleaned and run again
(``capture-ingest`` resumes by itself).
"""

import json
import logging
import shutil
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from lenspair.errors import LenspairError
from lenspair.fsutil import atomic_write_json, atomic_write_text

log = logging.getLogger(__name__)

SAMPLES = Path(__file__).resolve().parent.parent / "calib_samples"


class DemoError(LenspairError):
    """A stage of the demo failed (the message names the stage)."""


@dataclass(frozen=True)
class Budget:
    """How much work the demo does; the defaults fit 15 minutes on 2 CPU cores.

    Attributes:
        frames: frames per anomaly recording.
        pretrain_steps: synthetic pretraining steps.
        finetune_steps: fine-tuning steps on the dataset.
        tradeoff_steps: training steps per variant in the tradeoff.
        crop_size: training crop side, pixels.
        batch_size: training batch.
    """

    frames: int = 60
    pretrain_steps: int = 200
    finetune_steps: int = 200
    tradeoff_steps: int = 40
    crop_size: int = 128
    batch_size: int = 4


QUICK = Budget(frames=12, pretrain_steps=4, finetune_steps=4, tradeoff_steps=2, crop_size=32)
"""A tiny budget for the end-to-end test: every stage runs, nothing is learnt."""


@dataclass(frozen=True)
class Stage:
    """One subcommand invocation and the folder or file it produces."""

    name: str
    argv: tuple[str, ...]
    output: Path
    resumable: bool = False


def plan(out: Path, budget: Budget) -> list[Stage]:
    """The demo's stages, in order, writing under ``out``."""
    rec, ing = out / "recordings", out / "ingested"
    calib = out / "calibration" / "camchain.yaml"
    pre, fine = out / "runs" / "pretrain", out / "runs" / "finetune"
    train_common = (
        "--device",
        "auto",
        "--crop-size",
        str(budget.crop_size),
        "--batch-size",
        str(budget.batch_size),
    )
    frames = str(budget.frames)
    stages = [
        Stage(
            "simulate-board",
            ("simulate", str(SAMPLES / "chessboard.yaml"), "--out", str(rec / "board")),
            rec / "board",
        ),
        Stage(
            "simulate-rain",
            (
                "simulate",
                str(SAMPLES / "rain.yaml"),
                "--out",
                str(rec / "rain"),
                "--frames",
                frames,
            ),
            rec / "rain",
        ),
        Stage(
            "simulate-dust",
            (
                "simulate",
                str(SAMPLES / "dust_swapped.yaml"),
                "--out",
                str(rec / "dust_swapped"),
                "--frames",
                frames,
            ),
            rec / "dust_swapped",
        ),
        Stage(
            "calibrate",
            (
                "calibrate",
                str(rec / "board"),
                "--board",
                "chessboard:9x6:0.06",
                "--model",
                "pinhole-equi",
                "--out",
                str(calib),
            ),
            calib.parent,
        ),
    ]
    for name in ("rain", "dust_swapped"):
        stages.append(
            Stage(
                f"ingest-{name}",
                ("capture-ingest", str(rec / name), "--out", str(ing), "--calib", str(calib)),
                ing / name,
                resumable=True,
            )
        )
    dataset = out / "dataset"
    stages += [
        Stage(
            "dataset-build",
            (
                "dataset-build",
                str(ing / "rain"),
                str(ing / "dust_swapped"),
                "--out",
                str(dataset),
                "--config",
                str(out / "dataset_config.yaml"),
            ),
            dataset,
        ),
        Stage(
            "pretrain",
            (
                "train",
                "--synthetic",
                str(dataset / "train" / "target"),
                "--out",
                str(pre),
                "--max-steps",
                str(budget.pretrain_steps),
                *train_common,
            ),
            pre,
        ),
        Stage(
            "finetune",
            (
                "train",
                str(dataset),
                "--init",
                str(pre / "checkpoints" / "best.pt"),
                "--out",
                str(fine),
                "--max-steps",
                str(budget.finetune_steps),
                *train_common,
            ),
            fine,
        ),
        Stage(
            "eval",
            (
                "eval",
                str(fine / "checkpoints" / "best.pt"),
                "--data",
                str(dataset),
                "--split",
                "test",
                "--out",
                str(out / "eval"),
            ),
            out / "eval",
        ),
        Stage(
            "tradeoff",
            (
                "tradeoff",
                str(dataset),
                "--out",
                str(out / "tradeoff"),
                "--budget",
                str(budget.tradeoff_steps),
                "--crop-size",
                str(budget.crop_size),
                "--batch-size",
                str(budget.batch_size),
            ),
            out / "tradeoff",
        ),
    ]
    return stages


def _marker(out: Path, stage: Stage) -> Path:
    return out / ".stages" / f"{stage.name}.json"


def run_stage(out: Path, stage: Stage, cli_main: Callable[[list[str]], int]) -> tuple[float, bool]:
    """Run one stage unless a finished marker with the same arguments exists.

    Returns:
        (seconds spent, whether the stage was reused).
    """
    marker = _marker(out, stage)
    if marker.is_file() and stage.output.exists():
        recorded = json.loads(marker.read_text(encoding="utf-8"))
        if recorded.get("argv") == list(stage.argv):
            return float(recorded.get("seconds", 0.0)), True
    if stage.output.exists() and not stage.resumable:
        shutil.rmtree(stage.output) if stage.output.is_dir() else stage.output.unlink()
    print(f"\n[{stage.name}] lenspair {' '.join(stage.argv)}", file=sys.stderr, flush=True)
    start = time.perf_counter()
    code = cli_main(list(stage.argv))
    seconds = time.perf_counter() - start
    if code != 0:
        raise DemoError(f"stage {stage.name} failed (exit code {code}); rerun to resume")
    atomic_write_json(marker, {"argv": list(stage.argv), "seconds": round(seconds, 2)})
    return seconds, False


def run_demo(out: Path, budget: Budget = Budget()) -> Path:
    """Run every stage under ``out`` and write the report; returns ``report.md``'s path."""
    from lenspair.cli import main as cli_main
    from lenspair.demo_report import write_report

    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    # Two short recordings make too few whole-recording groups for three
    # splits, so the demo splits by time segments (a sixth of a recording).
    segment = max(2, budget.frames // 6)
    atomic_write_text(
        out / "dataset_config.yaml",
        f"split:\n  group_by: segment\n  segment_frames: {segment}\n  segment_gap_frames: 1\n",
    )
    timings: dict[str, dict[str, float | bool]] = {}
    for stage in plan(out, budget):
        seconds, reused = run_stage(out, stage, cli_main)
        timings[stage.name] = {"seconds": round(seconds, 2), "reused": reused}
        log.info("%s: %s (%.1f s)", stage.name, "reused" if reused else "done", seconds)
    atomic_write_json(out / "timings.json", timings)
    return write_report(out, timings)
