"""Train and compare network variants under one budget: accuracy against inference time.

  lenspair tradeoff DS --out DIR [--budget STEPS_OR_SECONDS] [--device auto|cpu|cuda]
                    [--config train.yaml] [--crop-size N] [--batch-size N]
                    [--variants G,GE,GEA,GEA-w0.5,GEA-w2,GEA-b3] [--seeds 0,1,2]

Each variant (G, GE, GEA, GEA at width 0.5 and 2, GEA with 3 residual
blocks) is trained on DS for the same budget (--budget 60 = 60 steps; 90s,
5m = wall-clock time; early stopping off), scored on DS's test split (or the
held-out validation pairs) and timed at batch 1 on the data's frame size.
Every GEA checkpoint is scored and timed again at each precision the device
runs natively (bf16 with avx512_bf16/AMX, int8 with VNNI through ONNX Runtime
static quantisation calibrated on the training split, for the paper's GEA only;
fp16/bf16 on CUDA), and that row also gives its PSNR against the fp32 output.

Writes ONE table, DIR/tradeoff.md, .csv and .json (params, GFLOPs, CPU ms,
GPU ms on CUDA, PSNR, SSIM, metric convention, Pareto flags), the plot
DIR/tradeoff.png (PSNR and SSIM against CPU time, Pareto front marked),
DIR/tradeoff_config.yaml and one run folder per variant in DIR/runs/. A
rerun reuses a run trained on the same data with the same settings and seed;
one trained otherwise is trained again, and the log names the setting that
differs. A larger step --budget under the default --lr-decay is another
schedule, so it trains again; a larger time budget (which trains at a
constant rate) or --lr-decay 0 extends the run. The defaults (60 steps, 128 px
crops, batch 4, training precision chosen as train's auto: bf16 only where the
CPU runs it natively and faster; roughly 0.5-1 s per GEA step on two cores,
three times that for GEA-w2) are sized for a demonstration, not for
conclusions; use e.g. --budget 30m --crop-size 256 --batch-size 8 on a GPU
for a real comparison. Under a step budget the learning rate falls linearly
towards zero over the budget's second half (--lr-decay 0.5, pix2pix's schedule),
so that each network's accuracy settles by the end instead of being read off
a still-rising curve.

With several --seeds (default 0,1,2) every variant is trained once per seed
(DIR/seed<k>/ holds each seed's table and runs) and DIR/tradeoff_seeds.md
reports PSNR/SSIM as mean +/- spread (standard deviation over seeds), checks
convergence (over the last 20 % of the budget validation PSNR moved no more
than the seed spread), marks Pareto points only where a difference exceeds the
spread, and prints the paper's published rows beside ours, labelled.
--seeds 0 runs the single table above. One DIR holds one kind: a seeded rerun
moves a single-seed table and runs of one of its seeds into DIR/seed<k>/ and
reuses them; a single-seed run into a seeded DIR is refused.

  lenspair tradeoff DS --out tradeoff --budget 400 --seeds 0,1,2
"""

import argparse
import dataclasses
from pathlib import Path

from lenspair.commands.argtypes import (
    add_convention_option,
    add_device_option,
    fraction,
    input_path,
    out_folder,
    positive_int,
    split_name,
    timed_runs,
)
from lenspair.core.config import MAX_SEED
from lenspair.core.device import resolve_device
from lenspair.core.errors import ConfigError
from lenspair.core.fsutil import inside_refusal

DATASET_ARGUMENTS = ("dataset",)
"""Arguments naming datasets this command reads: ``lenspair.cli`` holds their locks meanwhile."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the arguments of ``tradeoff``."""
    parser.add_argument("dataset", type=input_path, help="paired dataset folder (DS)")
    parser.add_argument("--out", type=out_folder, required=True, help="output folder (DIR)")
    parser.add_argument(
        "--budget", default="60", help="per variant and seed: STEPS, or 90s / 5m / 1h (60 steps)"
    )
    add_device_option(parser)
    parser.add_argument(
        "--config",
        type=input_path,
        help="base run config (each variant sets the network's variant, width and blocks; "
        "model.channels and the other sections apply to every variant; crop, batch and "
        "learning-rate decay it leaves out take this command's defaults below)",
    )
    parser.add_argument(
        "--crop-size",
        type=positive_int,
        default=None,
        help="training crop (128, or the --config file's data.crop_size)",
    )
    parser.add_argument(
        "--batch-size",
        type=positive_int,
        default=None,
        help="training batch (4, or the --config file's train.batch_size)",
    )
    parser.add_argument(
        "--lr-decay",
        type=fraction,
        default=None,
        metavar="SHARE",
        help="share of a step budget, at its end, over which the learning rate falls "
        "linearly towards zero, so that each variant's accuracy settles by the end (0.5, "
        "pix2pix's schedule, or the --config file's train.lr_decay; 0: constant, as the "
        "paper; a time budget trains at constant rate)",
    )
    parser.add_argument("--variants", help="comma-separated subset of the variant names")
    add_convention_option(parser)
    parser.add_argument(
        "--split",
        default=None,
        type=split_name,
        help="evaluation split (test; where DS has none, the validation pairs held out of "
        "training)",
    )
    parser.add_argument(
        "--latency-runs",
        type=timed_runs,
        default=20,
        help="timed runs per figure (20; at least 1: the table is accuracy against time)",
    )
    parser.add_argument("--seeds", default="0,1,2", help="comma-separated training seeds (0,1,2)")
    parser.add_argument(
        "--no-int8", action="store_true", help="skip the int8 row (quantising takes a minute)"
    )


def _check_places(args: argparse.Namespace) -> None:
    """Refuse a --split of a paired folder, and an --out inside the folders pairs are read from.

    A paired folder has no splits (its held-out pairs are scored): a --split
    there, even one that does not exist, was ignored. An --out inside an image
    folder (or a split) put the plot among the pairs, and every later command
    refused the data over an unpaired file.
    """
    from lenspair.dataset.layouts import (  # the dataset package: numpy, OpenImageIO
        IMAGE_FOLDERS,
        detect_layout,
        split_folders,
    )

    dataset = Path(args.dataset)
    if not dataset.is_dir():
        raise ConfigError(f"{dataset}: no such folder")
    if detect_layout(dataset) is not None:
        if args.split is not None:
            raise ConfigError(
                f"--split {args.split}: {dataset} is a paired folder, whose held-out pairs are "
                "scored; leave --split out, or give the dataset root whose split it is"
            )
        paired = [dataset]
    else:
        paired = [dataset / name for name in split_folders(dataset)]
    why = "its plot would be read as an unpaired image"
    for folder in (pairs / name for pairs in paired for name in IMAGE_FOLDERS):
        if problem := inside_refusal(args.out, folder, "the image folder", why):
            raise ConfigError(problem)


def run(args: argparse.Namespace) -> int:
    """Run the comparison; returns the exit code."""
    # Imported here, not at the top: keeps torch out of `lenspair tradeoff --help`.
    from lenspair.model.evaluation.tradeoff import run_tradeoff
    from lenspair.model.evaluation.tradeoff_report import tradeoff_markdown  # as above
    from lenspair.model.evaluation.tradeoff_variants import (  # as above
        DEFAULT_LR_DECAY,
        DEFAULT_VARIANTS,
        parse_budget,
    )
    from lenspair.model.training.config import RunConfig  # as above
    from lenspair.model.training.config_loading import with_file  # as above

    budget = parse_budget(args.budget)
    variants = DEFAULT_VARIANTS
    if args.variants is not None:  # "" names none: not all of them
        wanted = [name.strip() for name in args.variants.split(",") if name.strip()]
        known = {v.name: v for v in DEFAULT_VARIANTS}
        unknown = [name for name in wanted if name not in known]
        if unknown:
            raise ConfigError(
                f"--variants: unknown {', '.join(unknown)}; valid: {', '.join(known)}"
            )
        if not wanted:
            raise ConfigError(f"--variants: no variant named in {args.variants!r}")
        if twice := sorted({name for name in wanted if wanted.count(name) > 1}):
            # each would be trained and scored again, one "dominating" its own copy
            raise ConfigError(f"--variants: {', '.join(twice)} named twice")
        variants = tuple(known[name] for name in wanted)
    if args.latency_runs < 1:
        raise ConfigError("--latency-runs must be >= 1")
    _check_places(args)  # after the options: their errors need no data
    # The demonstration's 128 px crops, batch 4 and decaying rate (not the paper's 256, 8 and
    # constant rate), unless the --config file names the setting or the option is given: a
    # config written to set, say, val_every must not switch the others to train's defaults.
    base = RunConfig()
    base = dataclasses.replace(
        base,
        data=dataclasses.replace(base.data, crop_size=128),
        train=dataclasses.replace(base.train, batch_size=4, lr_decay=DEFAULT_LR_DECAY),
    )
    if args.config is not None:
        base = with_file(base, args.config)
    try:
        base = dataclasses.replace(
            base,
            data=dataclasses.replace(base.data, crop_size=args.crop_size or base.data.crop_size),
            train=dataclasses.replace(
                base.train,
                batch_size=args.batch_size or base.train.batch_size,
                lr_decay=base.train.lr_decay if args.lr_decay is None else args.lr_decay,
            ),
        )
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    if budget.seconds is not None:
        # its length in steps is not known in advance: every variant trains at a constant
        # rate (variant_config), and the config and report say so
        if args.lr_decay:
            raise ConfigError(
                f"--lr-decay {args.lr_decay:g}: a time budget ({args.budget}) trains at a "
                "constant rate; give a step budget (--budget N) to decay it"
            )
        base = dataclasses.replace(base, train=dataclasses.replace(base.train, lr_decay=0.0))
    try:
        seeds = [int(part) for part in args.seeds.split(",") if part.strip()]
    except ValueError:
        raise ConfigError(
            f"--seeds: expected comma-separated integers, got {args.seeds!r}"
        ) from None
    if not seeds or len(set(seeds)) != len(seeds) or not 0 <= min(seeds) <= max(seeds) <= MAX_SEED:
        raise ConfigError(
            f"--seeds: expected distinct integers 0 .. {MAX_SEED}, got {args.seeds!r}"
        )
    device = resolve_device(args.device)
    if len(seeds) > 1:
        # here, not at the top: keeps `--help` from importing torch
        from lenspair.model.evaluation.tradeoff_seeds import run_seeded_tradeoff
        from lenspair.model.evaluation.tradeoff_seeds_report import seeded_markdown

        rows, meta = run_seeded_tradeoff(
            args.dataset, args.out, device, budget, base, seeds, variants,
            convention=args.convention, split=args.split, latency_runs=args.latency_runs,
            int8=not args.no_int8,
        )  # fmt: skip
        print(seeded_markdown(rows, meta))
        print(f"wrote {args.out / 'tradeoff_seeds.md'} and tradeoff_seeds.json")
        return 0
    # here, not at the top: keeps `--help` from importing torch
    from lenspair.model.evaluation.tradeoff_seeds import seeded_output_refusal

    if refusal := seeded_output_refusal(args.out):
        raise ConfigError(refusal)
    base = dataclasses.replace(base, train=dataclasses.replace(base.train, seed=seeds[0]))
    result = run_tradeoff(
        args.dataset,
        args.out,
        device,
        budget,
        base,
        variants,
        convention=args.convention,
        split=args.split,
        latency_runs=args.latency_runs,
        int8=not args.no_int8,
    )
    print(tradeoff_markdown(result.rows, result.meta))
    print(f"wrote {args.out / 'tradeoff.md'}, tradeoff.csv, tradeoff.json, tradeoff.png")
    return 0
