"""The main job end to end on the bundled sample scenes (``lenspair demo``).

Stages, each one a ``lenspair`` subcommand run in-process with the same
arguments a user would type (printed as it runs, so the demo doubles as a
tutorial):

1. ``simulate`` a chessboard session and three anomaly recordings: light
   and heavy rain with cam1 obstructed, dust with the sides swapped (cam0
   obstructed);
2. ``calibrate`` from the board session;
3. ``capture-ingest`` each recording with that calibration;
4. ``dataset-build`` the ingested recordings into train/val/test;
5. ``train --synthetic``: pretraining on drops rendered over clean frames,
   starting from the GEA weights shipped with lenspair (``--init pretrained``);
6. ``train --init``: a short fine-tune on the real (here: simulated) pairs;
7. ``eval`` on the test split, 8. a small ``tradeoff``;
9. ``restore`` the heavy-rain recording (its obstructed camera) with the
   fine-tuned network, as a robot would clean its stream;

then ``report.md`` and ``report.html`` gather the figures. A stage whose
outputs are complete (a marker in ``OUT/.stages`` with the same arguments)
is reused on a rerun; an unfinished stage is cleaned and run again
(``capture-ingest`` and ``tradeoff`` resume by themselves):
:mod:`lenspair.demo_stages`.
"""

import os
import shlex
from dataclasses import dataclass
from pathlib import Path

from lenspair.cli import main as cli_main
from lenspair.core.folderlock import lock_file
from lenspair.core.fsutil import atomic_write_json, atomic_write_text
from lenspair.core.samples import sample_path
from lenspair.demo_report import write_report
from lenspair.demo_stages import Stage, run_stages
from lenspair.errors import DemoError
from lenspair.rectify.calib_types import MODELS
from lenspair.simulate.spec import load_scene

RECORDINGS = ("rain", "heavy_rain", "dust_swapped")
"""The anomaly recordings the demo simulates and ingests (``calib_samples/<name>.yaml``):
light rain on cam1 (easy pairs), heavy, changing rain on cam1 (medium and hard
pairs) and dust on cam0, the sides swapped."""


RESTORED_RECORDING = "heavy_rain"
"""The raw recording the last stage restores (its obstructed camera, from ``rig.yaml``)."""


@dataclass(frozen=True)
class Budget:
    """How much work the demo does; the defaults fit 15 minutes on 2 CPU cores.

    Budgets are steps, never seconds, so the same command makes the same
    data and the same amount of training on every machine while its time
    adapts (weights agree to the bit only at one precision and thread count:
    the CPU's sums run in another order). Training runs
    at ``--precision auto`` (:mod:`lenspair.model.precision`): bf16 autocast
    on a CPU with native bf16 (``avx512_bf16``/AMX), fp32 on one without,
    which avoids the 2.6x penalty of emulated bf16 measured on an AVX-512
    Xeon without ``avx512_bf16``.

    Attributes:
        frames: frames per anomaly recording.
        pretrain_steps: synthetic pretraining steps.
        finetune_steps: fine-tuning steps on the dataset.
        tradeoff_steps: training steps per variant in the tradeoff.
        crop_size: training crop side, pixels.
        batch_size: training batch.
        int8: the tradeoff's int8 row where the CPU has VNNI (about a minute).
        latency_runs: timed runs per latency figure of ``eval`` and ``tradeoff``
            (their defaults are 30 and 20). Ten give a steady median on a
            quiet machine; timing six variants at 540x360 is the tradeoff's
            largest cost after training (GEA-w2 alone took 651 ms a frame on
            the AVX2-only EPYC).
    """

    frames: int = 60
    # Measured on a 2-core AMD EPYC with oneDNN capped below bf16
    # (ONEDNN_MAX_CPU_ISA=AVX512_CORE_VNNI, so auto trains at fp32, as on a CPU
    # without native bf16): 11.1 min with 150 pretraining and 250 fine-tuning
    # steps; 8.6 min with 100 and 200 and validation run channels-last (README,
    # "Pipeline stages"). The AVX-512 Xeon without bf16 of issue 11 is slower:
    # 1.5x per fp32 training step (bench_training, batch 8, crop 256: 7.3 s
    # there, 4.81 s on that EPYC) and 1.8x per fp32 frame (253 against 138 ms),
    # which put the old budget near 16 min there and this one near 13 (an
    # estimate: no such CPU was at hand). Measured on a CPU without native
    # bf16, an AVX2-only AMD EPYC slower than that Xeon (GEA fp32 frame about
    # 200 ms): 14.7 min, 81 % of it training (docs/results/cpu_amd_epyc_avx2.md).
    # Pretraining starts from the shipped weights, and the tradeoff's accuracy
    # is noise at any budget the demo can afford (its times are what it shows),
    # so the cuts cost the demo little.
    pretrain_steps: int = 100
    finetune_steps: int = 200
    tradeoff_steps: int = 10
    crop_size: int = 128
    batch_size: int = 4
    int8: bool = True
    latency_runs: int = 10


QUICK = Budget(
    frames=12,
    pretrain_steps=4,
    finetune_steps=4,
    tradeoff_steps=2,
    crop_size=32,
    int8=False,
    latency_runs=3,
)
"""A tiny budget for the end-to-end test: every stage runs, nothing is learnt."""


def board_arguments(scene: str = "chessboard.yaml") -> tuple[str, str, str, str]:
    """``--board`` and ``--model`` of ``lenspair calibrate`` for a sample board scene.

    Read from the scene spec through the shared board model, so that the
    demo calibrates with the board the simulator drew.
    """
    spec = load_scene(sample_path(scene))
    if spec.board is None:
        raise DemoError(f"{scene}: the sample scene has no board")
    model = next(name for name, lens in MODELS.items() if lens == spec.rig.cam0.distortion_model)
    return "--board", spec.board.target.spec(), "--model", model


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
            ("simulate", str(sample_path("chessboard.yaml")), "--out", str(rec / "board")),
            rec / "board",
        ),
        *(
            Stage(
                f"simulate-{name}",
                (
                    "simulate",
                    str(sample_path(f"{name}.yaml")),
                    "--out",
                    str(rec / name),
                    "--frames",
                    frames,
                ),
                rec / name,
            )
            for name in RECORDINGS
        ),
        Stage(
            "calibrate",
            ("calibrate", str(rec / "board"), *board_arguments(), "--out", str(calib)),
            calib.parent,
        ),
    ]
    for name in RECORDINGS:
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
                *(str(ing / name) for name in RECORDINGS),
                "--out",
                str(dataset),
                "--config",
                str(out / "dataset_config.yaml"),
                "--splits",
                "0.7,0.15,0.15",
            ),
            dataset,
        ),
        _train_stage(
            "pretrain",
            (
                "train",
                "--synthetic",
                str(dataset / "train" / "target"),
                "--init",
                "pretrained",
                "--out",
                str(pre),
                "--max-steps",
                str(budget.pretrain_steps),
                *train_common,
            ),
            pre,
        ),
        _train_stage(
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
                "--latency-runs",
                str(budget.latency_runs),
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
                "--seeds",
                "0",  # one seed fits the demo's time; `make tradeoff-seeds` repeats over seeds
                *(() if budget.int8 else ("--no-int8",)),
                "--latency-runs",
                str(budget.latency_runs),
            ),
            out / "tradeoff",
            # a stopped tradeoff keeps its finished variants: tradeoff reuses or resumes a
            # run only when what it learns is unchanged (lenspair.model.evaluation.tradeoff_reuse)
            resumable=True,
        ),
        Stage(
            "restore",
            (
                "restore",
                str(fine / "checkpoints" / "best.pt"),
                str(rec / RESTORED_RECORDING),
                "--out",
                str(out / "restored"),
                "--device",
                "auto",
            ),
            out / "restored",
        ),
    ]
    return stages


def _train_stage(name: str, argv: tuple[str, ...], output: Path) -> Stage:
    """A ``train`` stage that, stopped, continues with ``--resume`` (which refuses ``--init``)."""
    at = argv.index("--init")
    return Stage(
        name,
        argv,
        output,
        resume_argv=(*argv[:at], *argv[at + 2 :], "--resume"),
        resume_file=output / "checkpoints" / "last.pt",
    )


def check_out(out: Path) -> None:
    """Refuse an ``--out`` that holds files of its own and no earlier demo.

    The demo writes ``recordings/``, ``ingested/``, ``dataset/``, ``runs/``,
    ``eval/``, ... there and replaces any it runs again: given a project's
    own folder, it deleted the user's ``eval/`` and recordings without a word.

    Raises:
        DemoError: ``out`` is a non-empty folder without the demo's ``.stages/``.
    """
    if out.is_dir() and any(out.iterdir()) and not (out / ".stages").is_dir():
        raise DemoError(
            f"--out {out}: holds files and no earlier demo (no .stages/); the demo writes "
            "and replaces recordings/, ingested/, dataset/, runs/, eval/, ... there: give "
            "a new or empty folder"
        )


def run_demo(out: Path, budget: Budget = Budget()) -> Path:
    """Run every stage under ``out`` and write the report; returns ``report.md``'s path.

    The report's command quotes ``out`` as given (relative or absolute), so that
    it runs again from where it was typed. The whole run holds a lock on
    ``out/.stages/.lock``: two demos writing one folder resumed and replaced
    each other's stages.

    Raises:
        DemoError: ``out`` is not the demo's (:func:`check_out`), or another
            demo is writing to it.
    """
    given = shlex.quote(str(out))
    out = Path(out).resolve()
    check_out(out)
    # now, not with the first finished marker: a demo stopped in its first stage
    # left files and no .stages/, and check_out refused its rerun
    (out / ".stages").mkdir(parents=True, exist_ok=True)
    lock = lock_file(out / ".stages" / ".lock", "lenspair demo")
    if lock is None:
        raise DemoError(f"another demo is writing to {out}")
    try:
        return _run_locked(out, budget, given)
    finally:
        os.close(lock)


def _run_locked(out: Path, budget: Budget, given: str) -> Path:
    """:func:`run_demo` once it holds ``out``'s lock."""
    # Three short recordings make too few whole-recording groups for three
    # splits, so the demo splits by time segments; a twelfth of a recording
    # gives enough groups (36) for hashed splits near the asked fractions.
    segment = max(2, budget.frames // 12)
    atomic_write_text(
        out / "dataset_config.yaml",
        f"split:\n  group_by: segment\n  segment_frames: {segment}\n  segment_gap_frames: 1\n",
    )
    timings = run_stages(out, plan(out, budget), cli_main)
    atomic_write_json(out / "timings.json", timings)
    flags = "" if budget == Budget() else " --quick" if budget == QUICK else " (custom budget)"
    return write_report(out, timings, f"lenspair demo --out {given}{flags}")
