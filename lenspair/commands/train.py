"""Train the shallow GAN on real pairs, or pretrain it on synthetic drops.

  lenspair train DS --out RUN [--config train.yaml] [--init CKPT] [--resume]
                 [--device auto|cpu|cuda]
  lenspair train --synthetic IMAGES_DIR --out RUN [--drops ours|sharp] ...

Example: lenspair train DS --out runs/gea --max-steps 2000 --precision auto
         lenspair train DS --out runs/g --variant G       # the generator alone

--variant picks the paper's ablation network: G (generator), GE (+ enhancer)
or GEA (+ aggregation modules, the default); a --config file sets it as
model: {variant: G}, with model.width and model.num_blocks beside it.

DS is any paired layout lenspair reads: a dataset from dataset-build (trains
on train/, validates on val/), a folder with input/ + target/ (or lq/ + gt/),
or the Raindrop dataset of Qian et al.; without a validation split a
deterministic tenth of the training pairs is held out.

--synthetic renders drops on the fly on clean images (any folder of PNG/JPEG/TIFF,
or a dataset's target/ images): 'ours' (lens-like, defocused, some brightened)
or 'sharp' (Porav et al.'s in-focus drops), holding out a deterministic
validation subset; a fifth of the training items are left clear (input =
target, data.clear_share) so that the network learns to leave clear frames
alone. This is the paper's synthetic initialisation: fine-tune on
real pairs with --init RUN/checkpoints/best.pt (network weights only).

--init pretrained starts from the GEA weights that ship with lenspair (mono or
RGB, chosen by the data): pretrained on 'ours' drops over the natural
photographs that scikit-image and matplotlib ship; see their model card,
model/weights/MODEL_CARD.md in the repository (the package
lenspair.model.weights once installed). Example:

  lenspair train DS --init pretrained --out runs/gea

Defaults follow the paper: Adam lr 2e-4 (0.5, 0.999), batch 8, up to 200
epochs, early stopping on validation PSNR (patience 10), random 256 px crops
and flips, LSGAN + feature matching on the generator output, VGG19
perceptual + L2 on the enhanced output. --precision auto (the default) trains
at the precision measured fastest, never an emulated one: bf16 autocast on a
CPU with avx512_bf16 or AMX where a timing of under a second finds it faster
than fp32 (on an Intel Xeon without AMX it ran at 0.7x), fp32 otherwise
(emulated bf16 is ~2.6x slower), and fp32 on CUDA (on an H100 bf16/fp16
autocast ran slower: these networks are too small for tensor cores to repay
the casts; --precision bf16 or fp16 still runs on request, fp16 with a
GradScaler); the choice and its reason are printed once and written to
RUN/config.yaml (runtime). Without
VGG19 weights (train.vgg19_weights or LENSPAIR_VGG19_WEIGHTS) the perceptual
term is disabled, with a warning in the log and in config.yaml.

Run folder: RUN/config.yaml (resolved), RUN/checkpoints/{last,best}.pt,
RUN/metrics.csv, RUN/train.log, RUN/samples.png. last.pt is written after
every epoch and also within epochs (--checkpoint-every, default every 10
minutes of training), so a killed run loses minutes, not an epoch. --resume
continues exactly from the latest last.pt (a --config given with it changes
the keys it names, on top of the run's own, and may change budgets, not the
network); a run killed before its first checkpoint
starts over. Multi-GPU: torchrun --nproc_per_node N -m lenspair train ...

  lenspair train DS --out RUN --checkpoint-every 500     # every 500 steps
  lenspair train DS --out RUN --resume                   # after a crash or kill
"""

import argparse
import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lenspair.commands.argtypes import (
    add_device_option,
    input_path,
    out_folder,
    positive_int,
    random_seed,
)
from lenspair.core.config import config_path
from lenspair.core.device import resolve_device
from lenspair.core.durations import seconds, steps_or_seconds
from lenspair.core.errors import ConfigError
from lenspair.core.fsutil import inside_refusal
from lenspair.core.wording import counted

if TYPE_CHECKING:  # for annotations only: keeps `--help` light
    from lenspair.model.training.config import RunConfig


def _every(text: str) -> tuple[int | None, float | None]:
    """Argparse type of --checkpoint-every: ``"500"`` -> (500, None); ``"90s"`` -> (None, 90.0)."""
    try:
        return steps_or_seconds(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _seconds(text: str) -> float:
    """Argparse type of --max-seconds: ``"600"``, ``"600s"`` or ``"10m"`` -> 600.0."""
    try:
        return seconds(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


SHIPPED_WEIGHTS = "pretrained"
"""``--init`` word for the shipped weights (``lenspair.model.training.pretrained``)."""


def _init_weights(text: str) -> Path | str:
    """``--init``: the word ``pretrained`` exactly as typed, else a checkpoint path.

    ``./pretrained`` is a file: a path equal to the word once normalised
    (``Path("./pretrained")``) must not select the shipped weights.
    """
    if text == SHIPPED_WEIGHTS:
        return text
    if not Path(text).exists():
        raise argparse.ArgumentTypeError(f"{text}: checkpoint not found")
    return Path(text)


DATASET_ARGUMENTS = ("dataset",)
"""Arguments naming datasets this command reads: ``lenspair.cli`` holds their locks meanwhile."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``train``."""
    parser.add_argument("dataset", nargs="?", type=input_path, help="paired dataset folder (DS)")
    parser.add_argument("--out", type=out_folder, required=True, help="run folder (RUN)")
    parser.add_argument(
        "--config", type=input_path, help="YAML with model/data/train/loss sections"
    )
    parser.add_argument(
        "--init",
        type=_init_weights,
        metavar="CKPT",
        help="start from these weights; 'pretrained': the GEA weights shipped with lenspair "
        "(a file of that name: ./pretrained)",
    )
    parser.add_argument("--resume", action="store_true", help="continue RUN where it stopped")
    add_device_option(parser)
    parser.add_argument(
        "--synthetic", type=input_path, metavar="IMAGES_DIR", help="pretrain on rendered drops"
    )
    parser.add_argument("--drops", choices=("ours", "sharp"), help="synthetic drops (ours)")
    group = parser.add_argument_group("overrides of the config file")
    group.add_argument(
        "--variant",
        choices=("G", "GE", "GEA"),
        help="model.variant: G (generator only), GE (+ enhancer) or GEA (+ aggregation "
        "modules; the paper's network, default)",
    )
    group.add_argument("--epochs", type=positive_int, help="train.epochs (200)")
    group.add_argument(
        "--max-steps",
        type=positive_int,
        help="train.max_steps: stop after this many steps (no limit)",
    )
    group.add_argument(
        "--max-seconds",
        type=_seconds,
        metavar="TIME",
        help="train.max_seconds: stop after this much training time: seconds, or 90s, 10m, "
        "1h (no limit)",
    )
    group.add_argument("--batch-size", type=positive_int, help="train.batch_size (8)")
    group.add_argument("--crop-size", type=positive_int, help="data.crop_size (256)")
    group.add_argument("--seed", type=random_seed, help="train.seed (0)")
    group.add_argument(
        "--precision",
        choices=("auto", "fp32", "bf16", "fp16"),
        help="train.precision (auto: bf16 on a CPU with avx512_bf16/AMX where it measures "
        "faster than fp32, else fp32; fp32 on CUDA)",
    )
    group.add_argument("--no-amp", action="store_true", help="train at fp32 (same as fp32)")
    group.add_argument("--vgg19-weights", type=input_path, help="train.vgg19_weights")
    group.add_argument(
        "--checkpoint-every",
        type=_every,
        metavar="STEPS|SECONDS",
        help="also write last.pt within epochs: a step count (e.g. 500) or a time (90s, 10m, "
        "1h); default every 10 minutes",
    )


def with_options(config: Any, args: argparse.Namespace) -> Any:
    """``config`` with the options of the command line that set keys (``--max-steps`` ...).

    Public: ``benchmarks.table2`` compares a run folder's config with what
    ``lenspair train ARGV`` would train through it.
    """
    train = {
        "epochs": args.epochs,
        "max_steps": args.max_steps,
        "max_seconds": args.max_seconds,
        "batch_size": args.batch_size,
        "seed": args.seed,
        # absolute, as a config file's are: the run's config.yaml keeps it, and a resume
        # from another folder finds the same file
        "vgg19_weights": None
        if args.vgg19_weights is None
        else config_path(args.vgg19_weights).resolve(),
        # --precision alone also lifts a stored amp: false (a run started with --no-amp,
        # resumed at bf16), and --no-amp alone a stored or configured precision; both
        # together are refused as contradicting each other
        "amp": False if args.no_amp else (True if args.precision else None),
        "precision": args.precision or ("fp32" if args.no_amp else None),
    }
    if args.checkpoint_every is not None:
        steps, seconds = args.checkpoint_every
        train["checkpoint_every_steps"] = steps
        train["checkpoint_every_seconds"] = seconds
    keep_none = (
        {"checkpoint_every_steps", "checkpoint_every_seconds"} if args.checkpoint_every else set()
    )
    data = {"crop_size": args.crop_size, "drops": args.drops}
    model = {"variant": args.variant}
    try:
        return dataclasses.replace(
            config,
            model=dataclasses.replace(
                config.model, **{k: v for k, v in model.items() if v is not None}
            ),
            train=dataclasses.replace(
                config.train, **{k: v for k, v in train.items() if v is not None or k in keep_none}
            ),
            data=dataclasses.replace(
                config.data, **{k: v for k, v in data.items() if v is not None}
            ),
        )
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


def interrupt_hint(args: argparse.Namespace) -> str | None:
    """What to do after Ctrl-C: ``--resume`` only once the run folder holds a run."""
    if not (Path(args.out) / "config.yaml").is_file():
        return "nothing was saved yet; rerun the same command to start again"
    return None


PAIRED_FOLDERS = ("input", "target", "lq", "gt", "data")
"""Sub-folders of a split (or paired folder) whose images a paired reader lists."""


def _check_out_apart(args: argparse.Namespace, train_split: str, val_split: str) -> None:
    """Refuse an --out whose samples.png the next run on this data would read as an image.

    A paired reader lists the files directly in a split's ``input/`` and
    ``target/`` (``lq``/``gt``, ``data``/``gt``): --out may not be one of
    those. ``--synthetic`` reads every image below a plain folder: --out may
    not lie inside it; below a dataset or a folder of ``target``/``gt``/
    ``clean`` folders, only those folders' own images: --out may not be one.
    Anything else in the data's tree (DS/runs/...) is fine.
    """
    # here, not at the top: keeps torch and OpenCV out of `lenspair train --help`
    from lenspair.dataset.layouts import detect_layout
    from lenspair.simulate.presets import CLEAN_FOLDER_NAMES, find_clean_images

    data = args.dataset if args.synthetic is None else args.synthetic
    roots = {Path(data).resolve()}
    if args.synthetic is None:
        roots |= {(Path(data) / split).resolve() for split in (train_split, val_split)}
    if args.out.resolve() in roots:  # config.yaml replaced the dataset's curation config
        raise ConfigError(
            f"--out {args.out}: the data trained on ({data}); a run writes config.yaml, "
            f"checkpoints/ and metrics.csv there, over the data's own: choose another "
            f"folder (such as {Path(data) / 'runs' / 'NAME'})"
        )
    why = "its samples.png would be read as an image next time"
    if args.synthetic is not None:
        images = find_clean_images(args.synthetic)
        if all(p.parent.name.lower() not in CLEAN_FOLDER_NAMES for p in images):
            problem = inside_refusal(args.out, args.synthetic, "the images read from", why)
            if problem is not None:
                raise ConfigError(problem)
            return
        folders = sorted({p.parent for p in images})
    else:
        splits = [args.dataset]
        if detect_layout(args.dataset) is None:
            splits = [args.dataset / train_split, args.dataset / val_split]
        folders = [split / name for split in splits for name in PAIRED_FOLDERS]
    out = args.out.resolve()
    for folder in folders:
        if folder.is_dir() and out == folder.resolve():
            raise ConfigError(
                f"--out {args.out}: a folder of the images read ({folder}); {why}, so choose "
                "another"
            )


def _unsaved_changes(said: Path, trained: "RunConfig") -> list[str]:
    """A warning when the run's ``config.yaml`` says settings its ``last.pt`` never trained with.

    ``config.yaml`` is written when a session starts: a ``--resume --config``
    session stopped before its first checkpoint leaves it saying settings that
    never trained, and a later plain ``--resume`` goes on with ``last.pt``'s.
    """
    # here, not at the top: keeps `--help` from importing torch
    from lenspair.model.training.config_loading import config_differences, load_run_config

    try:
        differences = config_differences(trained, load_run_config(said, stored=True))
    except (ConfigError, OSError):  # unreadable: rewritten by this session, as before
        return []
    if not differences:
        return []
    return [
        f"{said} said settings that never reached a checkpoint (a session stopped before "
        f"its first): {'; '.join(differences)}; this session goes on with last.pt's, as the "
        "new config.yaml says; give the --config again to apply them"
    ]


def run(args: argparse.Namespace) -> int:
    """Train one run; returns the exit code."""
    # Imported here, not at the top: keeps torch out of `lenspair train --help`.
    from lenspair.model.training.config_loading import load_run_config, with_file
    from lenspair.model.training.datasets import paired_training_data, synthetic_training_data
    from lenspair.model.training.distributed import distributed_from_env
    from lenspair.model.training.loop import fit, resolve_config, resume_config

    if (args.dataset is None) == (args.synthetic is None):
        raise ConfigError("give a dataset DS, or --synthetic IMAGES_DIR (not both)")
    if args.resume and args.init is not None:
        raise ConfigError("--resume continues a run; --init starts a new one: choose one")
    if args.drops is not None and args.synthetic is None:
        raise ConfigError("--drops applies to --synthetic pretraining only")
    device = resolve_device(args.device)
    if args.resume and not (args.out / "checkpoints" / "last.pt").is_file():
        if not (args.out / "config.yaml").is_file():
            raise ConfigError(f"--resume: {args.out} holds no run to resume")
        # Killed before its first checkpoint was complete (or last.pt removed):
        # resuming means starting this run over (fit replaces its partial
        # results once every check has passed), from where it started.
        stored = load_run_config(args.out / "config.yaml", stored=True)
        runtime = stored.runtime
        if runtime is not None and runtime.init is not None:
            if not Path(runtime.init).is_file():
                raise ConfigError(
                    f"--resume: {args.out} starts over (it has no last.pt) from --init "
                    f"{runtime.init}, which is gone; start it anew with another --init"
                )
            args.init = Path(runtime.init)
        args.resume, restart = False, True
    else:
        stored, restart = None, False
    # said by fit once every check has passed, into RUN/train.log and by rank 0 alone
    notes: list[str] = []
    if args.resume or restart:
        # a --config given with it sets the keys it names on top of the run's own
        # (train.patience alone did not put crop, batch and rate back to the defaults)
        if stored is None:
            stored = resume_config(args.out, None)
            notes.extend(_unsaved_changes(args.out / "config.yaml", stored))
        base = with_file(stored, args.config) if args.config else stored
        config = with_options(base, args)
        if args.resume:
            config = resume_config(args.out, config, notes)
    else:
        config = with_options(load_run_config(args.config, given=True), args)
    _check_out_apart(args, config.data.train_split, config.data.val_split)
    seed, channels = config.train.seed, config.model.channels
    if args.synthetic is not None:
        data = synthetic_training_data(args.synthetic, config.data, channels, seed, notes)
    else:
        data = paired_training_data(args.dataset, config.data, channels, seed, notes)
    config = resolve_config(config, data.channels)
    init = args.init
    if isinstance(init, str):  # the word, as typed: the shipped weights
        # here, not at the top: keeps `--help` from importing torch
        from lenspair.model.training.pretrained import pretrained_weights

        if Path(init).exists():
            notes.append(
                f"--init {init}: the weights shipped with lenspair, not the file "
                f"{Path(init).resolve()} here; give ./{init} to start from that file"
            )
        assert config.model.channels is not None
        init = pretrained_weights(config.model.channels)
    elif init is not None:  # recorded whole: "init: pretrained" would read as the word
        init = init.absolute()
    summary = fit(
        config,
        data.train,
        data.val,
        args.out,
        device,
        data_description=data.description,
        synthetic=data.synthetic,
        init=init,
        resume=args.resume,
        data_path=args.synthetic if args.synthetic is not None else args.dataset,
        restart=restart,
        notes=notes,
    )
    if not distributed_from_env().is_main:
        return 0  # under torchrun only rank 0 reports (the others hold no best PSNR)
    best = summary.run / "checkpoints" / "best.pt"
    validated = summary.best_epoch > 0 and best.is_file()
    if summary.steps == 0 and not validated:  # a budget under one step: exit 0 read as trained
        raise ConfigError(
            f"{summary.run}: {summary.stop_reason} before the first step: nothing was trained "
            "and no checkpoint written; give a larger budget (--max-seconds, --max-steps)"
        )
    # validated within an epoch the run did not finish: "0 epochs ... (epoch 1)" read as a slip
    during = "during " if summary.best_epoch > summary.epochs else ""
    print(
        f"{summary.run}: {summary.stop_reason}; {counted(summary.epochs, 'epoch')}, "
        f"{counted(summary.steps, 'step')}, "
        + (
            f"best validation PSNR {summary.best_psnr:.2f} dB ({during}epoch "
            f"{summary.best_epoch}); "
            if validated
            else ""
        )
        + f"perceptual loss {summary.perceptual}"
    )
    if validated:
        print(f"best checkpoint: {best}")
    else:  # resumed without its best.pt and stopped before validating again
        print(
            f"no best checkpoint: {best} was missing or could not be used when the run "
            "resumed (the warning above says why), and no validation ran since; resume with a "
            "larger budget to write it"
        )
    return 0
